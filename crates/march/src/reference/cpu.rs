//! The reference path tracer on the CPU: rows in parallel with rayon, in f64.

use nimbus_optics::Rng;
use nimbus_tracking::{trace_path, DensityMedium, MediumRay, Shadowing, RATIO_ROULETTE};
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use super::{sample_stream, ReferenceParams, REFERENCE_DOMAIN};
use crate::{Image, MarchError, RayResult};

/// Pixel `index` of the reference image: `spp` jittered samples averaged.
fn reference_pixel(medium: DensityMedium, params: &ReferenceParams, index: u64) -> RayResult {
    let camera = &params.camera;
    let w = camera.width() as u64;
    let (px, py) = ((index % w) as f64, (index / w) as f64);
    let mut sum = RayResult::default();
    for sample in 0..params.spp {
        let mut rng = Rng::with_domain(params.seed, sample_stream(index, sample), REFERENCE_DOMAIN);
        let (jx, jy) = (rng.next_f64(), rng.next_f64());
        let (origin, dir) = camera.ray(px + jx, py + jy);
        let tr = MediumRay::new(medium, origin, dir, 0.0, f64::INFINITY).transmittance_ratio(&mut rng, RATIO_ROULETTE);
        let light = trace_path(medium, &params.medium, &params.lights, Shadowing::RatioTracked, origin, dir, params.max_depth, &mut rng);
        sum.single += light.single;
        sum.multiple += light.multiple;
        sum.transmittance += tr as f32;
    }
    let inv = 1.0 / params.spp as f32;
    RayResult { single: sum.single * inv, multiple: sum.multiple * inv, transmittance: sum.transmittance * inv, depth: f32::INFINITY }
}

/// Renders the reference on the CPU; `progress` hears each finished row's pixel count.
pub fn render_reference_cpu(
    density: &Volume<f32>,
    params: &ReferenceParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Image, MarchError> {
    params.validate()?;
    let majorant = MajorantGrid::for_tracking(density, params.medium.extinction);
    let medium = DensityMedium { density, majorant: &majorant, extinction: params.medium.extinction };
    let (w, h) = (params.camera.width() as u64, params.camera.height() as u64);
    let pixels: Vec<RayResult> = (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            let row_pixels: Vec<RayResult> = (row * w..(row + 1) * w).map(|i| reference_pixel(medium, params, i)).collect();
            progress(w);
            row_pixels
        })
        .collect();
    Ok(Image::from_rays(params.camera.width(), params.camera.height(), &pixels, params.background, params.aovs))
}
