//! The CPU backend: pixels in parallel with rayon.

use glam::{DVec3, Vec3};
use nimbus_cache::IlluminationCache;
use nimbus_optics::noise::fbm3_vec;
use nimbus_optics::Rng;
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use crate::{assemble, Image, MarchError, MarchParams};

/// Random-number domain of camera samples.
pub(crate) const MARCH_DOMAIN: u32 = 0x4d41_5243; // "MARC"

/// What one camera ray gathered.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayResult {
    pub single: Vec3,
    pub multiple: Vec3,
    pub transmittance: f32,
    /// Distance to the first sample where opacity passed 1%, or infinity.
    pub depth: f32,
}

/// Marches one camera ray. `xi` in [0,1) places the step lattice.
pub fn march_ray(
    density: &Volume<f32>,
    majorant: &MajorantGrid,
    cache: &IlluminationCache,
    params: &MarchParams,
    origin: DVec3,
    dir: DVec3,
    xi: f64,
) -> RayResult {
    let transform = density.transform();
    let (o, d) = (transform.to_index(origin), transform.dir_to_index(dir));
    let dt = params.step;
    let extinction = params.medium.extinction;
    let albedo = params.medium.albedo;
    let jitter = params.offset_noise > 0.0;
    let mut r = RayResult { transmittance: 1.0, depth: f32::INFINITY, ..RayResult::default() };
    let mut tr = 1.0f64;
    for seg in majorant.walk(o, d, 0.0, f64::INFINITY) {
        if seg.majorant.is_nan() || seg.majorant <= 0.0 || seg.t_end.is_infinite() {
            continue;
        }
        let mut k = (seg.t_start / dt - xi).ceil();
        loop {
            let t = (k + xi) * dt;
            if t >= seg.t_end {
                break;
            }
            k += 1.0;
            let mut x = origin + dir * t;
            if jitter {
                x += fbm3_vec(x / params.noise_scale, params.noise_octaves, params.seed as u32).as_dvec3() * params.offset_noise;
            }
            let sigma_t = extinction as f64 * density.sample_world(x).max(0.0) as f64;
            if sigma_t <= 0.0 {
                continue;
            }
            let step_transmittance = (-sigma_t * dt).exp();
            let weight = (tr * (1.0 - step_transmittance)) as f32;
            if let Some(li) = &cache.li_single {
                r.single += weight * albedo * li.sample_world(x);
            }
            if let Some(li) = &cache.li_multiple {
                r.multiple += weight * albedo * li.sample_world(x);
            }
            tr *= step_transmittance;
            if r.depth.is_infinite() && tr < 0.99 {
                r.depth = t as f32;
            }
            if tr < params.min_transmittance {
                r.transmittance = 0.0;
                return r;
            }
        }
    }
    r.transmittance = tr as f32;
    r
}

/// The majorant grid both backends march. Offset noise samples the density up to its
/// displacement away from the ray being walked, so each cell must also bound the cells within
/// that distance (index space, per axis) or the march would skip segments whose displaced
/// samples see density: the grid is dilated by it. The fBm's components stay within about
/// [-1, 1]; twice the amplitude is a generous bound.
pub(crate) fn march_majorant(density: &Volume<f32>, params: &MarchParams) -> MajorantGrid {
    let grid = MajorantGrid::build(density);
    if params.offset_noise <= 0.0 {
        return grid;
    }
    let m = density.transform().world_to_index().matrix3;
    // Index axis j moves by at most sum_i |m[i][j]| times a world displacement's largest component.
    let rows = glam::DVec3::new(m.row(0).abs().element_sum(), m.row(1).abs().element_sum(), m.row(2).abs().element_sum());
    grid.dilated(rows * (2.0 * params.offset_noise))
}

/// Where in the pixel sample `s` of `spp` looks, from two uniform numbers: jittered within
/// its cell of an n x n grid over the pixel (n = floor(sqrt(spp))), anywhere for the samples
/// past n^2. A pixel's sub-pixel detail (the plume's wisps at 128x72) then averages out as
/// about spp^-0.75 rather than spp^-0.5: with 4 purely random samples the bench's plume came
/// out worse than with the one centre sample. `shaders/march.wgsl` mirrors it.
pub(crate) fn pixel_jitter(s: u32, spp: u32, u: f64, v: f64) -> (f64, f64) {
    let n = spp.isqrt();
    if s < n * n {
        (((s % n) as f64 + u) / n as f64, ((s / n) as f64 + v) / n as f64)
    } else {
        (u, v)
    }
}

/// Renders the image on the CPU.
pub fn render_cpu(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams) -> Result<Image, MarchError> {
    params.validate()?;
    let majorant = march_majorant(density, params);
    let camera = &params.camera;
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let spp = params.spp;
    let pixels: Vec<RayResult> = (0..w * h)
        .into_par_iter()
        .map(|index| {
            let (px, py) = ((index % w) as f64, (index / w) as f64);
            let mut rng = Rng::with_domain(params.seed, index as u64, MARCH_DOMAIN);
            let mut sum = RayResult::default();
            let mut depth = f32::INFINITY;
            for s in 0..spp {
                // One sample at the pixel centre when spp = 1, so a 1-spp image is not noisy
                // in its edges; stratified over the pixel otherwise.
                let (jx, jy) = if spp == 1 { (0.5, 0.5) } else { pixel_jitter(s, spp, rng.next_f64(), rng.next_f64()) };
                let xi = rng.next_f64();
                let (origin, dir) = camera.ray(px + jx, py + jy);
                let r = march_ray(density, &majorant, cache, params, origin, dir, xi);
                sum.single += r.single;
                sum.multiple += r.multiple;
                sum.transmittance += r.transmittance;
                depth = depth.min(r.depth);
            }
            let inv = 1.0 / spp as f32;
            RayResult { single: sum.single * inv, multiple: sum.multiple * inv, transmittance: sum.transmittance * inv, depth }
        })
        .collect();
    Ok(assemble(params, &pixels))
}

#[cfg(test)]
mod tests {
    use super::pixel_jitter;

    #[test]
    fn samples_take_one_cell_each_of_the_largest_square_grid() {
        for spp in [2u32, 4, 5, 9, 16, 17] {
            let n = spp.isqrt();
            let mut seen = vec![0; (n * n) as usize];
            for s in 0..spp {
                for (u, v) in [(0.0, 0.0), (0.999, 0.5), (0.3, 0.999)] {
                    let (x, y) = pixel_jitter(s, spp, u, v);
                    assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y), "spp {spp}, sample {s}: ({x}, {y})");
                    if s < n * n {
                        let cell = ((y * n as f64) as u32 * n + (x * n as f64) as u32) as usize;
                        assert_eq!(cell, s as usize, "spp {spp}: sample {s} left its cell");
                    } else {
                        assert_eq!((x, y), (u, v), "past n^2 a sample may fall anywhere");
                    }
                }
                if s < n * n {
                    seen[s as usize] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "spp {spp}: every cell once");
        }
    }
}
