//! The reference path tracer on the CPU: rows in parallel with rayon, in f64.

use nimbus_optics::Rng;
use nimbus_tracking::{trace_path, DensityMedium, EmissionField, MediumRay, MotionBlur, PathSources, PathStart, Shadowing, RATIO_ROULETTE};
use nimbus_volume::Volume;
use rayon::prelude::*;

use super::{sample_stream, ReferenceParams, REFERENCE_DOMAIN};
use crate::{Image, MarchError, MediumFields, RayResult};

/// Pixel `index` of the reference image: `spp` jittered samples averaged.
fn reference_pixel(medium: DensityMedium, params: &ReferenceParams, emission: Option<&EmissionField>, motion: Option<&MotionBlur>, index: u64) -> RayResult {
    let mut sum = RayResult::default();
    for sample in 0..params.spp {
        let s = reference_sample(medium, params, emission, motion, index, sample);
        sum.single += s.single;
        sum.multiple += s.multiple;
        sum.emission += s.emission;
        sum.transmittance += s.transmittance;
        sum.behind += s.behind;
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

/// Sample `sample` of pixel `index`: one jittered camera ray, its transmittance by ratio
/// tracking and one path, from the sample's own stream (so `vdbmarch --verify` can trace any
/// subset of pixels and samples and draw exactly what the full render would).
pub(crate) fn reference_sample(
    medium: DensityMedium,
    params: &ReferenceParams,
    emission: Option<&EmissionField>,
    motion: Option<&MotionBlur>,
    index: u64,
    sample: u32,
) -> RayResult {
    let camera = &params.camera;
    let w = camera.width() as u64;
    let (px, py) = ((index % w) as f64, (index / w) as f64);
    let map = crate::visible_map(params.visible_environment());
    let mut rng = Rng::with_domain(params.seed, sample_stream(index, sample), REFERENCE_DOMAIN);
    // With motion blur the whole sample, its camera ray and path, sees the medium at one
    // time in the shutter (from a stream of its own: the other draws stay as they are).
    let medium = match motion {
        Some(m) => DensityMedium { motion: Some(m.at(Rng::with_domain(params.seed, sample_stream(index, sample), crate::MOTION_DOMAIN).next_f64())), ..medium },
        None => medium,
    };
    let (jx, jy) = (rng.next_f64(), rng.next_f64());
    let (origin, dir) = camera.ray(px + jx, py + jy);
    let tr = MediumRay::new(medium, origin, dir, 0.0, f64::INFINITY).transmittance_ratio(&mut rng, RATIO_ROULETTE);
    let sources = PathSources { environment: params.environment.as_ref(), emission };
    let light = trace_path(medium, &params.medium, &params.lights, Shadowing::RatioTracked, origin, dir, PathStart::Camera, params.max_depth, &mut rng, sources);
    RayResult {
        single: light.single,
        multiple: light.multiple,
        transmittance: tr as f32,
        depth: f32::INFINITY,
        emission: light.emission,
        behind: map.map_or(glam::Vec3::ZERO, |env| env.radiance(dir.as_vec3()) * tr as f32),
    }
}

/// Renders the reference on the CPU; `progress` hears each finished row's pixel count.
pub fn render_reference_cpu(
    density: &Volume<f32>,
    params: &ReferenceParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Image, MarchError> {
    render_reference_cpu_with(density, params, MediumFields::default(), progress)
}

/// [`render_reference_cpu`] with what the medium holds beyond its density: emission
/// (`trace_path`'s collision estimator) and motion blur (each sample traces the medium at its
/// own time in the shutter, [`nimbus_tracking::Motion`], over the majorant dilated by how far
/// it moves).
pub fn render_reference_cpu_with(
    density: &Volume<f32>,
    params: &ReferenceParams,
    fields: MediumFields,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Image, MarchError> {
    let MediumFields { emission, motion, .. } = fields;
    params.validate()?;
    let majorant = super::reference_majorant(density, params, motion);
    let medium = DensityMedium { motion: None, density, majorant: &majorant, extinction: params.medium.extinction };
    let (w, h) = (params.camera.width() as u64, params.camera.height() as u64);
    let pixels: Vec<RayResult> = (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            let row_pixels: Vec<RayResult> = (row * w..(row + 1) * w).map(|i| reference_pixel(medium, params, emission, motion, i)).collect();
            progress(w);
            row_pixels
        })
        .collect();
    let background = crate::constant_background(params.background, params.visible_environment());
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
        let params = ReferenceParams {
            environment: None,
            environment_visible: false,
            medium: Medium { extinction: 3.0, albedo: Vec3::ZERO, g: 0.0 },
            lights: vec![],
            camera: slab_camera(),
            spp: 8192,
            max_depth: 16,
            background: Vec3::ZERO,
            seed: 3,
            aovs: false,
        };
        let image = render_reference_cpu_with(&slab, &params, MediumFields { emission: Some(&field), ..MediumFields::default() }, &|_| {}).unwrap();
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

    /// Single scattering of a uniform sky L = 1 at the centre of a thin slab (the emitting
    /// slab's: faces at z = -0.05 and 0.75 through its ramps, sides at +-2.45), seen from
    /// straight above: integral over depth t of sigma_s e^(-sigma_t t) times the sphere
    /// integral of p(-w, +z) T(x, w) dw, T along w to the slab's boundary, by quadrature.
    fn thin_slab_single(sigma_t: f64, albedo: f64, g: f64) -> f64 {
        let (z_top, z_bottom, side) = (0.75f64, -0.05f64, 2.45f64);
        let hg = |cos: f64| (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * cos).powf(1.5));
        let (nt, nmu, nphi) = (100, 800, 32);
        let mut total = 0.0;
        for i in 0..nt {
            let dt = (z_top - z_bottom) / nt as f64;
            let t = (i as f64 + 0.5) * dt;
            let z = z_top - t;
            let mut sphere = 0.0;
            for j in 0..nmu {
                let mu = -1.0 + (j as f64 + 0.5) * 2.0 / nmu as f64;
                let sin = (1.0 - mu * mu).sqrt();
                for k in 0..nphi {
                    let phi = (k as f64 + 0.5) * 2.0 * std::f64::consts::PI / nphi as f64;
                    let (wx, wy) = (sin * phi.cos(), sin * phi.sin());
                    let mut s = f64::INFINITY;
                    if mu > 0.0 {
                        s = s.min((z_top - z) / mu);
                    } else if mu < 0.0 {
                        s = s.min((z - z_bottom) / -mu);
                    }
                    if wx != 0.0 {
                        s = s.min(side / wx.abs());
                    }
                    if wy != 0.0 {
                        s = s.min(side / wy.abs());
                    }
                    // Light travels along -w and scatters toward the eye, +z.
                    sphere += hg(-mu) * (-sigma_t * s).exp();
                }
            }
            sphere *= (2.0 / nmu as f64) * (2.0 * std::f64::consts::PI / nphi as f64);
            total += albedo * sigma_t * (-sigma_t * t).exp() * sphere * dt;
        }
        total
    }

    #[test]
    fn a_thin_slab_under_a_uniform_sky_scatters_its_closed_form() {
        let (slab, _, _) = emitting_slab();
        for (g, seed) in [(0.0f32, 11u64), (0.6, 12)] {
            let sigma_t = 0.25;
            let params = ReferenceParams {
                medium: Medium { extinction: sigma_t, albedo: Vec3::new(0.9, 0.6, 0.3), g },
                lights: vec![],
                environment: Some(nimbus_optics::Environment::uniform(Vec3::ONE).unwrap()),
                environment_visible: false,
                camera: slab_camera(),
                spp: 16384,
                max_depth: 16,
                background: Vec3::ZERO,
                seed,
                aovs: true,
            };
            let image = render_reference_cpu(&slab, &params, &|_| {}).unwrap();
            let single = image.aovs.as_ref().unwrap().single.iter().fold(glam::DVec3::ZERO, |a, &v| a + v.as_dvec3()) / 36.0;
            let expect = thin_slab_single(sigma_t as f64, 1.0, g as f64);
            let rel = single / (glam::DVec3::new(0.9, 0.6, 0.3) * expect) - 1.0;
            eprintln!("thin slab, g {g}: single {single} against {expect} x albedo: {rel}");
            // 590k paths, 18% of them colliding: the mean's standard deviation is about
            // 0.3% (seed to seed); 1.2% is four of them.
            assert!(rel.abs().max_element() < 0.012, "g {g}: {single} vs {expect}: {rel}");
            // The total adds the higher orders: 25% more at g 0 (measured), as light arriving
            // near the horizon crosses up to 4.8 units of slab, optical depth 1.2.
            let total = image.mean_rgb().x as f64;
            assert!(total > single.x && total < single.x * 1.4, "g {g}: total {total} against single {}", single.x);
        }
    }
}
