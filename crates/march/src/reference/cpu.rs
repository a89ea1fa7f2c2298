//! The reference path tracer on the CPU: rows in parallel with rayon, in f64.

use glam::{DVec3, Vec3};
use nimbus_optics::Rng;
use nimbus_tracking::{DensityMedium, FreePath, MediumRay};
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use super::{sample_stream, ReferenceParams, RATIO_ROULETTE, REFERENCE_DOMAIN, ROULETTE_FROM_DEPTH};
use crate::{Image, MarchError, RayResult};

/// One path's light: single (first collision) and multiple (later ones).
#[derive(Clone, Copy, Default)]
struct PathLight {
    single: Vec3,
    multiple: Vec3,
}

/// Traces one path from `origin` along `dir` (unit, world).
fn trace_path(medium: DensityMedium, params: &ReferenceParams, origin: DVec3, dir: DVec3, rng: &mut Rng) -> PathLight {
    let phase = params.medium.phase();
    let albedo = params.medium.albedo;
    let mut light = PathLight::default();
    let (mut x, mut w) = (origin, dir);
    let mut beta = Vec3::ONE;
    for depth in 1..=params.max_depth {
        let FreePath::Interaction(t) = MediumRay::new(medium, x, w, 0.0, f64::INFINITY).sample_delta(rng) else {
            break;
        };
        x += w * t;
        beta *= albedo;
        let w_out = -w.as_vec3();
        let mut direct = Vec3::ZERO;
        for l in &params.lights {
            let incident = l.incident(x);
            if incident.irradiance == Vec3::ZERO {
                continue;
            }
            let shadow = MediumRay::new(medium, x, incident.to_light.as_dvec3(), 0.0, incident.distance);
            let tr = shadow.transmittance_ratio(rng, RATIO_ROULETTE) as f32;
            if tr > 0.0 {
                direct += incident.irradiance * (tr * phase.eval_dirs(-incident.to_light, w_out));
            }
        }
        if depth == 1 {
            light.single += beta * direct;
        } else {
            light.multiple += beta * direct;
        }
        if depth >= ROULETTE_FROM_DEPTH {
            let q = beta.max_element();
            if q <= 0.0 {
                break;
            }
            if q < 1.0 {
                if rng.next_f32() >= q {
                    break;
                }
                beta /= q;
            }
        }
        w = phase.sample(w.as_vec3(), rng.next_vec2()).as_dvec3().normalize();
    }
    light
}

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
        let light = trace_path(medium, params, origin, dir, &mut rng);
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
