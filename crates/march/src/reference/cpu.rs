//! The reference path tracer on the CPU: rows in parallel with rayon, in f64.

use nimbus_optics::Rng;
use nimbus_tracking::{trace_path, DensityMedium, EmissionField, MediumRay, PathSources, PathStart, Shadowing, RATIO_ROULETTE};
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use super::{sample_stream, ReferenceParams, REFERENCE_DOMAIN};
use crate::{Image, MarchError, RayResult};

/// Pixel `index` of the reference image: `spp` jittered samples averaged.
fn reference_pixel(medium: DensityMedium, params: &ReferenceParams, emission: Option<&EmissionField>, index: u64) -> RayResult {
    let camera = &params.camera;
    let w = camera.width() as u64;
    let (px, py) = ((index % w) as f64, (index / w) as f64);
    let mut sum = RayResult::default();
    let map = crate::visible_map(params.environment.as_ref().filter(|_| params.environment_visible));
    for sample in 0..params.spp {
        let mut rng = Rng::with_domain(params.seed, sample_stream(index, sample), REFERENCE_DOMAIN);
        let (jx, jy) = (rng.next_f64(), rng.next_f64());
        let (origin, dir) = camera.ray(px + jx, py + jy);
        let tr = MediumRay::new(medium, origin, dir, 0.0, f64::INFINITY).transmittance_ratio(&mut rng, RATIO_ROULETTE);
        let sources = PathSources { environment: params.environment.as_ref(), emission };
        let light = trace_path(medium, &params.medium, &params.lights, Shadowing::RatioTracked, origin, dir, PathStart::Camera, params.max_depth, &mut rng, sources);
        sum.single += light.single;
        sum.multiple += light.multiple;
        sum.emission += light.emission;
        sum.transmittance += tr as f32;
        if let Some(env) = map {
            sum.behind += env.radiance(dir.as_vec3()) * tr as f32;
        }
    }
    let inv = 1.0 / params.spp as f32;
    RayResult {
        single: sum.single * inv,
        multiple: sum.multiple * inv,
        transmittance: sum.transmittance * inv,
        depth: f32::INFINITY,
        emission: sum.emission * inv,
        behind: sum.behind * inv,
    }
}

/// Renders the reference on the CPU; `progress` hears each finished row's pixel count.
pub fn render_reference_cpu(
    density: &Volume<f32>,
    params: &ReferenceParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Image, MarchError> {
    render_reference_cpu_emitting(density, params, None, progress)
}

/// [`render_reference_cpu`] with the medium's emission (`trace_path`'s collision estimator).
pub fn render_reference_cpu_emitting(
    density: &Volume<f32>,
    params: &ReferenceParams,
    emission: Option<&EmissionField>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Image, MarchError> {
    params.validate()?;
    let majorant = MajorantGrid::for_tracking(density, params.medium.extinction);
    let medium = DensityMedium { density, majorant: &majorant, extinction: params.medium.extinction };
    let (w, h) = (params.camera.width() as u64, params.camera.height() as u64);
    let pixels: Vec<RayResult> = (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            let row_pixels: Vec<RayResult> = (row * w..(row + 1) * w).map(|i| reference_pixel(medium, params, emission, i)).collect();
            progress(w);
            row_pixels
        })
        .collect();
    let background = crate::constant_background(params.background, params.environment.as_ref().filter(|_| params.environment_visible));
    Ok(Image::from_rays(params.camera.width(), params.camera.height(), &pixels, background, params.aovs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::tests::{emitting_slab, slab_camera};
    use glam::Vec3;
    use nimbus_optics::Medium;

    #[test]
    fn the_reference_renders_an_emitting_slab_to_its_closed_form() {
        let (slab, emission, expect) = emitting_slab();
        let field = EmissionField { grid: Some(&slab), temperature: None, params: &emission };
        let params = ReferenceParams { environment: None, environment_visible: false,
            medium: Medium { extinction: 3.0, albedo: Vec3::ZERO, g: 0.0 },
            lights: vec![],
            camera: slab_camera(),
            spp: 8192,
            max_depth: 16,
            background: Vec3::ZERO,
            seed: 3,
            aovs: false,
        };
        let image = render_reference_cpu_emitting(&slab, &params, Some(&field), &|_| {}).unwrap();
        let mean = image.mean_rgb();
        // Each path's first collision adds S c / sigma (e / sigma_t is constant in the slab)
        // with probability 1 - T = 0.909: over 36 x 8192 paths the mean's relative standard
        // deviation is sqrt(T / ((1 - T) N)) = 0.058%; 0.3% is five of them.
        let rel = ((mean - expect) / expect).abs().max_element();
        eprintln!("reference slab: mean {mean} against {expect}: {rel:.2e}");
        assert!(rel < 3e-3, "{mean} vs {expect}");
        // Without emission, the same paths see nothing.
        let dark = render_reference_cpu(&slab, &params, &|_| {}).unwrap();
        assert_eq!(dark.mean_rgb(), Vec3::ZERO);
    }
}
