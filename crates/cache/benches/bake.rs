//! Cache baking, CPU (rayon, all cores) against GPU (whatever adapter there is; lavapipe on
//! CI and the development machines), single and multiple scattering separately, on a
//! Cloud1-class deck (339 x 361 x 42 density voxels, Z up; the paper's 339 x 42 x 361 with
//! its thin axis vertical) and a smoke plume (96 x 96 x 192), with the error of each against
//! a fine reference: Simpson step / 4 for single scattering, 4x the photons for multiple.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-cache --bench bake [-- quick]
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-cache --bench bake -- paths
//!
//! `paths` times only path-traced multiple scattering (`--paths 16`, Li_multiple on its own
//! lattice twice as coarse) on a plume scaled down to 48 x 48 x 96, small enough for
//! lavapipe, against 256 paths per voxel on the CPU.
//!
//! Times are end to end (plan, bins, uploads, kernels, read-back, volume assembly), median
//! of 3 (`quick`: one run, fewer photons); photon tracing is not included. References are
//! evaluated at 2000 voxels spread over the baked ones. The cache lattice is 1.2x coarser than the
//! density's, which makes the deck's cache 283 x 301 x 35, the paper's Table 3a size.

use std::time::{Duration, Instant};

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_gpu, gather_cell, li_multiple, li_multiple_paths, li_single, toward_eye, BakeStats, CacheParams, Gather, IlluminationCache, MultipleEstimator, PhotonBins, EMPTY_BALL_FRACTION, ShadowMode, LightLattice};
use nimbus_tracking::{DensityMedium, LightDepths};
use nimbus_volume::MajorantGrid;
use rayon::prelude::*;
use nimbus_optics::noise::fbm3;
use nimbus_optics::{Camera, Light, Medium, Rng};
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

/// A rising plume: a column widening with height, turbulent, fading at the top; `dims`
/// (x = y, z twice that) scales it.
fn plume(dims: IVec3) -> Volume<f32> {
    let centre = DVec3::new(dims.x as f64 / 2.0, dims.y as f64 / 2.0, 0.0) * VOXEL;
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
        environment: None,
        medium: Medium { extinction, albedo: Vec3::splat(0.9), g: 0.3 },
        lights: vec![Light::sun(Vec3::new(0.4, 0.3, -1.0).normalize(), Vec3::ONE).unwrap()],
        camera: Camera::default_for_bounds(lo, hi).unwrap(),
        step: 1.0,
        cache_scale: 1.2,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        single: true,
        multiple: false,
        gather: Gather::Neighbours { k: 64, max_radius: 12.0 * VOXEL },
        estimator: MultipleEstimator::Photons,
        seed: 0,
        min_transmittance: 1e-4,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    }
}

type Bake = (IlluminationCache, BakeStats);

/// Median time of `runs` runs, and the last run's result.
fn median_of(runs: usize, mut f: impl FnMut() -> Bake) -> (Duration, Bake) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let start = Instant::now();
        last = Some(f());
        times.push(start.elapsed());
    }
    times.sort();
    (times[runs / 2], last.unwrap())
}

/// Every n-th baked voxel, about `count` of them: where the references are evaluated (a
/// whole fine bake would take longer than everything else together).
fn sample_voxels(grid: &Volume<Vec3>, count: usize) -> Vec<IVec3> {
    let mut all = Vec::new();
    for brick in grid.bricks() {
        for offset in 0..BRICK_VOXELS {
            let ijk = brick.origin + brick_local(offset);
            if grid.is_active(ijk) {
                all.push(ijk);
            }
        }
    }
    let every = (all.len() / count).max(1);
    all.into_iter().step_by(every).collect()
}

/// Mean |a - reference| at `voxels` relative to the reference's mean there, and the largest
/// relative to its peak (red channel).
fn error(a: &Volume<Vec3>, voxels: &[IVec3], reference: &[Vec3]) -> (f64, f64) {
    let (mut sum_diff, mut sum_ref, mut worst, mut peak) = (0.0, 0.0, 0.0f64, 0.0f64);
    for (ijk, r) in voxels.iter().zip(reference) {
        let (r, v) = (r.x as f64, a.get(*ijk).x as f64);
        sum_diff += (v - r).abs();
        sum_ref += r;
        worst = worst.max((v - r).abs());
        peak = peak.max(r);
    }
    (sum_diff / sum_ref.max(1e-30), worst / peak.max(1e-30))
}

fn trace(v: &Volume<f32>, p: &CacheParams, photons: u64, seed: u64) -> PhotonMap {
    let tp = PhotonParams { medium: p.medium, lights: p.lights.clone(), photons, seed, ..PhotonParams::default() };
    trace_cpu(v, &tp).unwrap().0
}

/// Times `params` on each backend and prints a row per backend with its error against
/// `reference(world position, w_out)` at sampled voxels of the grid `grid` picks.
#[allow(clippy::too_many_arguments)]
fn rows(
    runs: usize,
    name: &str,
    part: &str,
    v: &Volume<f32>,
    map: &PhotonMap,
    params: &CacheParams,
    grid: fn(&IlluminationCache) -> &Volume<Vec3>,
    reference: &(dyn Fn(DVec3, Vec3) -> Vec3 + Sync),
) {
    let ctx = nimbus_gpu::test_context();
    let start = Instant::now();
    let mut results: Vec<(&str, Duration, Bake)> = vec![{
        let (t, b) = median_of(runs, || bake_cpu(v, map, params).unwrap());
        ("cpu", t, b)
    }];
    eprintln!("  {name} {part}: cpu done after {:.1} s", start.elapsed().as_secs_f64());
    if let Some(ctx) = ctx {
        let (t, b) = median_of(runs, || bake_gpu(ctx, v, map, params).unwrap());
        results.push(("gpu", t, b));
    }
    eprintln!("  {name} {part}: gpu done after {:.1} s", start.elapsed().as_secs_f64());
    let baked = grid(&results[0].2 .0);
    let voxels = sample_voxels(baked, 2000);
    let truth: Vec<Vec3> = voxels
        .par_iter()
        .map(|ijk| {
            let x = baked.transform().to_world(ijk.as_dvec3());
            reference(x, toward_eye(&params.camera, x))
        })
        .collect();
    eprintln!("  {name} {part}: reference done after {:.1} s", start.elapsed().as_secs_f64());
    let cpu_time = results[0].1.as_secs_f64();
    for (backend, t, (cache, stats)) in &results {
        let (mean, max) = error(grid(cache), &voxels, &truth);
        let t = t.as_secs_f64();
        println!("| {name} | {} | {part} | {backend} | {t:.3} | {:.2} | {mean:.2e} | {max:.2e} |", stats.baked, t / cpu_time);
    }
}

/// The `paths` table: path-traced Li_multiple on each backend, against many more paths.
fn paths_rows() {
    let v = plume(IVec3::new(48, 48, 96));
    let per_voxel = 16;
    let p = CacheParams {
        single: false,
        multiple: true,
        multiple_scale: Some(2.4),
        multiple_tolerance: None,
        estimator: MultipleEstimator::Paths { per_voxel },
        seed: 1,
        ..params(&v, 60.0)
    };
    let tracking = MajorantGrid::for_tracking(&v, p.medium.extinction);
    let medium = DensityMedium { motion: None, density: &v, majorant: &tracking, extinction: p.medium.extinction };
    let part = format!("multiple (paths {per_voxel}; ref 256 paths)");
    rows(3, "plume 48x48x96", &part, &v, &PhotonMap::default(), &p, |c| c.li_multiple.as_ref().unwrap(), &|x, w_out| {
        // Its own stream per voxel, from the position: independent of the bakes' (seed 1).
        let index = x.x.to_bits() ^ x.y.to_bits().rotate_left(21) ^ x.z.to_bits().rotate_left(42);
        let _ = w_out;
        li_multiple_paths(medium, &p.medium, &p.lights, &LightDepths::default(), Default::default(), &[x], &[], 256, nimbus_cache::PATH_MAX_DEPTH, p.camera.eye(), &mut Rng::new(99, index)).mean
    });
}

fn main() {
    if std::env::args().any(|a| a == "paths") {
        println!("| scene | voxels baked | part | backend | median s | vs cpu | mean err | max err / peak |");
        println!("|---|---|---|---|---|---|---|---|");
        paths_rows();
        if let Some(ctx) = nimbus_gpu::test_context() {
            println!("GPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads());
        }
        return;
    }
    let quick = std::env::args().any(|a| a == "quick");
    let (photons, runs): (u64, usize) = if quick { (25_000, 1) } else { (100_000, 3) };
    println!("| scene | voxels baked | part | backend | median s | vs cpu | mean err | max err / peak |");
    println!("|---|---|---|---|---|---|---|---|");
    let scenes: Vec<(&str, Volume<f32>, f32)> = vec![("cloud 339x361x42", cloud_deck(), 30.0), ("plume 96x96x192", plume(IVec3::new(96, 96, 192)), 60.0)];
    for (name, v, extinction) in scenes {
        let base = params(&v, extinction);
        let none = PhotonMap::default();
        let single = CacheParams { single: true, multiple: false, ..base.clone() };
        let majorant = MajorantGrid::build(&v);
        let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction };
        let fine_step = single.single_step(&v) / 4.0;
        rows(runs, name, "single (step 1 voxel; ref step/4)", &v, &none, &single, |c| c.li_single.as_ref().unwrap(), &|x, w_out| {
            li_single(medium, &single.medium, &single.lights, &LightDepths::default(), x, w_out, fine_step, single.min_transmittance)
        });

        let multiple = CacheParams { single: false, multiple: true, ..base.clone() };
        let start = Instant::now();
        let map = trace(&v, &multiple, photons, 1);
        let fine_map = trace(&v, &multiple, 4 * photons, 2);
        eprintln!("  {name}: photons traced in {:.1} s", start.elapsed().as_secs_f64());
        // 4x the photons and 4x the neighbours: balls of about the same size (the same blur)
        // with half the noise, so the error column is mostly the baked estimate's noise.
        let Gather::Neighbours { k, max_radius } = multiple.gather else { unreachable!() };
        let fine_gather = Gather::Neighbours { k: 4 * k, max_radius };
        let fine_bins = PhotonBins::new(&fine_map.positions, gather_cell(&fine_map, fine_gather));
        let empty_below = EMPTY_BALL_FRACTION * majorant.max() as f64;
        let part = format!("multiple ({}k photons, k 64; ref 4x photons, k 256)", photons / 1000);
        rows(runs, name, &part, &v, &map, &multiple, |c| c.li_multiple.as_ref().unwrap(), &|x, w_out| {
            li_multiple(&v, empty_below, &multiple.medium, &fine_map, &fine_bins, fine_gather, x, w_out, &mut Vec::new()).0
        });
    }
    if let Some(ctx) = nimbus_gpu::test_context() {
        println!("GPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads());
    }
}
