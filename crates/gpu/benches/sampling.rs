//! Sampling throughput: `Volume::sample_index` on all cores (rayon) against the WGSL exact
//! and hardware-filtered samplers, on a 300x40x360 volume at 4M random points.
//!
//!     cargo bench -p nimbus-gpu --bench sampling [-- POINTS]
//!
//! GPU figures are end to end (upload the points, dispatch, read the samples back), which is
//! what a stage pays; the best of a few runs after a warm-up.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::{Duration, Instant};

use common::Rng;
use glam::{DVec3, IVec3, Vec3};
use nimbus_gpu::{DeviceChoice, GpuVolume, GpuVolumeOptions, PointSampler, SampleMode};
use nimbus_volume::{brick_local, Transform, Volume, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

const DIMS: IVec3 = IVec3::new(300, 40, 360);
const RUNS: usize = 3;

fn best_of<R>(mut f: impl FnMut() -> R) -> (Duration, R) {
    let mut best = None;
    for _ in 0..RUNS {
        let start = Instant::now();
        let r = f();
        let t = start.elapsed();
        if best.as_ref().is_none_or(|(b, _)| t < *b) {
            best = Some((t, r));
        }
    }
    best.unwrap()
}

/// A smooth cloud-like field over the whole box, every voxel inside it active.
fn bench_volume() -> Volume<f32> {
    let bricks = (DIMS + BRICK_DIM - 1) / BRICK_DIM;
    let origins: Vec<IVec3> = (0..bricks.element_product())
        .map(|n| IVec3::new(n % bricks.x, (n / bricks.x) % bricks.y, n / (bricks.x * bricks.y)) * BRICK_DIM)
        .collect();
    Volume::from_brick_fn(Transform::uniform(0.01, DVec3::ZERO), 0.0, &origins, |origin, values| {
        let mut mask = [0u64; 8];
        for (offset, value) in values.iter_mut().enumerate().take(BRICK_VOXELS) {
            let ijk = origin + brick_local(offset);
            if ijk.cmplt(DIMS).all() {
                let p = ijk.as_vec3() * 0.07;
                *value = (p.x.sin() * p.y.cos() + (p.z * 0.7).sin()).max(0.0);
                mask[offset >> 6] |= 1 << (offset & 63);
            }
        }
        mask
    })
}

fn main() {
    let count: usize = std::env::args().skip(1).find_map(|a| a.parse().ok()).unwrap_or(4 << 20);
    let volume = bench_volume();
    let mut rng = Rng::new(7);
    let points: Vec<Vec3> = (0..count).map(|_| rng.point_in(Vec3::splat(-2.0), DIMS.as_vec3() + 2.0)).collect();

    let mut rows: Vec<(String, Duration)> = Vec::new();
    let (t, cpu) = best_of(|| points.par_iter().map(|p| volume.sample_index(p.as_dvec3())).collect::<Vec<f32>>());
    rows.push((format!("cpu sample_index (rayon, {} threads)", rayon::current_num_threads()), t));

    let mut header = format!("volume {}x{}x{} voxels, {} bricks; {count} random points", DIMS.x, DIMS.y, DIMS.z, volume.brick_count());
    match DeviceChoice::Gpu.resolve() {
        Err(e) => eprintln!("no GPU rows: {e}"),
        Ok(device) => {
            let ctx = device.gpu().expect("gpu resolves to a GPU");
            let start = Instant::now();
            let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).expect("upload");
            ctx.wait().expect("upload");
            let stats = gpu_volume.stats();
            header += &format!(
                "\nGPU: {}; upload {:.0} ms, atlas {}x{}x{} texels + table, {:.1} MiB",
                ctx.info,
                start.elapsed().as_secs_f64() * 1e3,
                stats.atlas_texels.x,
                stats.atlas_texels.y,
                stats.atlas_texels.z,
                stats.bytes as f64 / (1 << 20) as f64
            );
            let sampler = PointSampler::new(ctx).expect("pipelines");
            for (mode, name) in [(SampleMode::Exact, "gpu exact (8 textureLoads)"), (SampleMode::Filtered, "gpu filtered (hardware)")] {
                let sample = || sampler.sample::<f32>(ctx, &gpu_volume, &points, mode).expect("sampling");
                sample(); // warm-up: first-use costs of the pipeline and the buffers
                let (t, gpu) = best_of(sample);
                let diff = cpu.iter().zip(&gpu).map(|(c, g)| (c - g).abs()).fold(0.0f32, f32::max);
                rows.push((format!("{name}, max |gpu - cpu| {diff:.1e}"), t));
            }
        }
    }

    println!("{header}\n");
    println!("{:<60} {:>10} {:>14}", "method", "time (ms)", "samples/s");
    for (name, t) in rows {
        println!("{name:<60} {:>10.1} {:>14.3e}", t.as_secs_f64() * 1e3, count as f64 / t.as_secs_f64());
    }
}
