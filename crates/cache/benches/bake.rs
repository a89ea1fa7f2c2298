//! Cache baking, CPU (rayon, all cores) against GPU (whatever adapter there is; lavapipe on
//! CI and the development machines), single and multiple scattering separately, on a
//! Cloud1-class deck (339 x 361 x 42 density voxels, Z up; the paper's 339 x 42 x 361 with
//! its thin axis vertical) and a smoke plume (96 x 96 x 192), with the error of each against
//! a fine reference: Simpson step / 4 for single scattering, 4x the photons for multiple.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-cache --bench bake [-- quick]
//!
//! Times are end to end (plan, bins, uploads, kernels, read-back, volume assembly), median
//! of 3; photon tracing is not included. The cache lattice is 1.2x coarser than the
//! density's, which makes the deck's cache 283 x 301 x 35, the paper's Table 3a size.

use std::time::{Duration, Instant};

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_gpu, BakeStats, CacheParams, Gather, IlluminationCache};
use nimbus_optics::noise::fbm3;
use nimbus_optics::{Camera, Light, Medium};
use nimbus_photon::{trace_cpu, PhotonMap, PhotonParams};
use nimbus_volume::{brick_local, Transform, Volume, BRICK_DIM, BRICK_VOXELS};

const VOXEL: f64 = 0.05;

/// A volume over the index box [0, dims) filled in parallel from `f(world position)`.
fn analytic(dims: IVec3, f: impl Fn(DVec3) -> f32 + Sync) -> Volume<f32> {
    let transform = Transform::uniform(VOXEL, DVec3::ZERO);
    let mut origins = Vec::new();
    for x in (0..dims.x).step_by(BRICK_DIM as usize) {
        for y in (0..dims.y).step_by(BRICK_DIM as usize) {
            for z in (0..dims.z).step_by(BRICK_DIM as usize) {
                origins.push(IVec3::new(x, y, z));
            }
        }
    }
    Volume::from_brick_fn(transform, 0.0, &origins, |origin, values| {
        let mut mask = [0u64; 8];
        for (offset, value) in values.iter_mut().enumerate() {
            let ijk = origin + brick_local(offset);
            if ijk.cmplt(dims).all() {
                let d = f(transform.to_world(ijk.as_dvec3()));
                if d > 0.0 {
                    *value = d;
                    mask[offset >> 6] |= 1 << (offset & 63);
                }
            }
        }
        mask
    })
}

/// Cumulus-like deck: fBm thresholded for partial coverage, thinning toward base and top.
fn cloud_deck() -> Volume<f32> {
    let dims = IVec3::new(339, 361, 42);
    let height = dims.z as f64 * VOXEL;
    analytic(dims, |p| {
        let h = p.z / height;
        let profile = (4.0 * h * (1.0 - h)).clamp(0.0, 1.0) as f32;
        let n = fbm3(p * 0.9, 4, 7);
        ((n + 0.1) * 2.5 * profile).clamp(0.0, 1.0) - 0.02
    })
}

/// A rising plume: a column widening with height, turbulent, fading at the top.
fn plume() -> Volume<f32> {
    let dims = IVec3::new(96, 96, 192);
    let centre = DVec3::new(48.0, 48.0, 0.0) * VOXEL;
    let height = dims.z as f64 * VOXEL;
    analytic(dims, |p| {
        let h = p.z / height;
        let radius = (0.08 + 0.3 * h) * height * 0.25;
        let swirl = DVec3::new(fbm3(p * 1.5, 3, 3) as f64, fbm3(p * 1.5, 3, 5) as f64, 0.0) * 0.3;
        let r = ((p - centre + swirl) * DVec3::new(1.0, 1.0, 0.0)).length();
        let core = (1.0 - r / radius).clamp(0.0, 1.0) * (1.0 - h).clamp(0.0, 1.0);
        (core as f32 * (1.0 + 0.6 * fbm3(p * 3.0, 3, 9))).max(0.0) - 0.01
    })
}

fn params(v: &Volume<f32>, extinction: f32) -> CacheParams {
    let (lo, hi) = v.world_bounds().unwrap();
    CacheParams {
        medium: Medium { extinction, albedo: Vec3::splat(0.9), g: 0.3 },
        lights: vec![Light::sun(Vec3::new(0.4, 0.3, -1.0).normalize(), Vec3::ONE).unwrap()],
        camera: Camera::default_for_bounds(lo, hi).unwrap(),
        step: 1.0,
        cache_scale: 1.2,
        single: true,
        multiple: false,
        gather: Gather::Neighbours { k: 64, max_radius: 12.0 * VOXEL },
        min_transmittance: 1e-4,
    }
}

type Bake = (IlluminationCache, BakeStats);

fn median_of_3(mut f: impl FnMut() -> Bake) -> (Duration, Bake) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let start = Instant::now();
        last = Some(f());
        times.push(start.elapsed());
    }
    times.sort();
    (times[1], last.unwrap())
}

/// Mean |a - reference| over the reference's voxels relative to the reference's mean, and
/// the largest relative to its peak (red channel).
fn error(a: &Volume<Vec3>, reference: &Volume<Vec3>) -> (f64, f64) {
    let (mut sum_diff, mut sum_ref, mut worst, mut peak) = (0.0, 0.0, 0.0f64, 0.0f64);
    for brick in reference.bricks() {
        for offset in 0..BRICK_VOXELS {
            let ijk = brick.origin + brick_local(offset);
            if reference.is_active(ijk) {
                let (r, v) = (brick.values[offset].x as f64, a.get(ijk).x as f64);
                sum_diff += (v - r).abs();
                sum_ref += r;
                worst = worst.max((v - r).abs());
                peak = peak.max(r);
            }
        }
    }
    (sum_diff / sum_ref.max(1e-30), worst / peak.max(1e-30))
}

fn trace(v: &Volume<f32>, p: &CacheParams, photons: u64, seed: u64) -> PhotonMap {
    let tp = PhotonParams { medium: p.medium, lights: p.lights.clone(), photons, seed, ..PhotonParams::default() };
    trace_cpu(v, &tp).unwrap().0
}

/// Times `params` on each backend and prints a row per backend with its error against
/// `reference` (read from the baked cache by `grid`).
fn rows(
    name: &str,
    part: &str,
    v: &Volume<f32>,
    map: &PhotonMap,
    params: &CacheParams,
    reference: &Volume<Vec3>,
    grid: fn(&IlluminationCache) -> &Volume<Vec3>,
) {
    let ctx = nimbus_gpu::test_context();
    let mut results: Vec<(&str, Duration, Bake)> = vec![{
        let (t, b) = median_of_3(|| bake_cpu(v, map, params).unwrap());
        ("cpu", t, b)
    }];
    if let Some(ctx) = ctx {
        let (t, b) = median_of_3(|| bake_gpu(ctx, v, map, params).unwrap());
        results.push(("gpu", t, b));
    }
    let cpu_time = results[0].1.as_secs_f64();
    for (backend, t, (cache, stats)) in &results {
        let (mean, max) = error(grid(cache), reference);
        let t = t.as_secs_f64();
        println!("| {name} | {} | {part} | {backend} | {t:.3} | {:.2} | {mean:.2e} | {max:.2e} |", stats.baked, t / cpu_time);
    }
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let photons: u64 = if quick { 50_000 } else { 200_000 };
    println!("| scene | voxels baked | part | backend | median s | vs cpu | mean err | max err / peak |");
    println!("|---|---|---|---|---|---|---|---|");
    let scenes: Vec<(&str, Volume<f32>, f32)> = vec![("cloud 339x361x42", cloud_deck(), 30.0), ("plume 96x96x192", plume(), 60.0)];
    for (name, v, extinction) in scenes {
        let base = params(&v, extinction);
        let none = PhotonMap::default();
        let single = CacheParams { single: true, multiple: false, ..base.clone() };
        let fine = CacheParams { step: single.step / 4.0, ..single.clone() };
        let reference = bake_cpu(&v, &none, &fine).unwrap().0.li_single.unwrap();
        rows(name, "single (step 1 voxel; ref step/4)", &v, &none, &single, &reference, |c| c.li_single.as_ref().unwrap());

        let multiple = CacheParams { single: false, multiple: true, ..base.clone() };
        let map = trace(&v, &multiple, photons, 1);
        let reference = bake_cpu(&v, &trace(&v, &multiple, 4 * photons, 2), &multiple).unwrap().0.li_multiple.unwrap();
        let part = format!("multiple ({}k photons, k 64; ref 4x photons)", photons / 1000);
        rows(name, &part, &v, &map, &multiple, &reference, |c| c.li_multiple.as_ref().unwrap());
    }
    if let Some(ctx) = nimbus_gpu::test_context() {
        println!("GPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads());
    }
}
