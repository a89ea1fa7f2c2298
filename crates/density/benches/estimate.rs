//! The backends side by side: CPU (rayon, all cores) and GPU (whatever adapter there is;
//! lavapipe, i.e. the same CPU cores, on the development machines), every method, on the
//! Cloud1-class scene (500k particles, 339 x 42 x 361 voxels) and the smoke-like one (330k
//! particles with dense eddies in a 280 x 255 x 233 box; `Scene::smoke`). Time is the median of RUNS estimates (prepare + passes +
//! finish, in process; the whole `particles2vdb` command is timed by
//! scripts/bench_density.sh), error the relative L2 against the scene's analytic density over
//! every grid point, mass the grid's mass over the particles'.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-density --bench estimate [-- quick] [-- cpu|gpu] [-- SCENE...]
//!
//! Environment: NEIGHBOURS=N sets N* (default 32), RUNS=R the CPU runs per row (default 3),
//! GPU_RUNS=R the GPU's (default 1: on a software adapter one run takes tens of seconds).

use std::time::Instant;

use nimbus_density::analytic::{Scene, TrueGrid};
use nimbus_density::*;
use nimbus_gpu::{DeviceChoice, GpuContext};

/// CPU seconds this process has used (user + system), from /proc: on a shared machine the
/// wall clock alone says little.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "--bench").collect();
    let runs: usize = if args.iter().any(|a| a == "quick") { 1 } else { std::env::var("RUNS").ok().and_then(|r| r.parse().ok()).unwrap_or(3) };
    let gpu_runs: usize = if args.iter().any(|a| a == "quick") { 1 } else { std::env::var("GPU_RUNS").ok().and_then(|r| r.parse().ok()).unwrap_or(1) };
    let neighbours: u32 = std::env::var("NEIGHBOURS").ok().and_then(|n| n.parse().ok()).unwrap_or(32);
    let only_cpu = args.iter().any(|a| a == "cpu");
    let only_gpu = args.iter().any(|a| a == "gpu");
    let ctx: Option<GpuContext> = if only_cpu {
        None
    } else {
        match DeviceChoice::Gpu.resolve() {
            Ok(device) => device.gpu().cloned(),
            Err(e) => {
                eprintln!("no GPU backend in this table: {e}");
                None
            }
        }
    };
    let mut scenes: Vec<Scene> = args.iter().filter_map(|a| Scene::by_name(a)).collect();
    if scenes.is_empty() {
        scenes = vec![Scene::cloud1(), Scene::smoke()];
    }
    println!("{} threads; GPU: {}; N* = {neighbours}; median of {runs} CPU / {gpu_runs} GPU runs", rayon::current_num_threads(), ctx.as_ref().map_or("none".into(), |c| c.info.to_string()));
    for scene in scenes {
        let particles = scene.particles(1);
        let base = DensityParams {
            neighbours,
            resolution: Resolution::VoxelSize(scene.voxel_size),
            bounds: scene.bounds,
            ..Default::default()
        };
        let grid = plan_grid(&particles, &base).unwrap();
        let truth = TrueGrid::new(&scene, grid);
        let total_mass = particles.total_mass(1.0);
        println!(
            "\n{}: {} particles, grid {}x{}x{} (voxel {}), h0 auto {:.3} ({:.2} voxels)",
            scene.name, particles.len(), grid.dims.x, grid.dims.y, grid.dims.z, grid.voxel_size, grid.h0, grid.h0 / grid.voxel_size
        );
        println!(
            "  {:<6} {:<4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>7} {:>12}",
            "method", "dev", "median s", "cpu s", "prepare", "passes", "finish", "rel L2", "mass", "used mean"
        );
        for method in Method::ALL {
            let params = DensityParams { method, ..base.clone() };
            let backends: Vec<(&str, Option<&GpuContext>)> = [("cpu", None), ("gpu", ctx.as_ref())]
                .into_iter()
                .filter(|(name, c)| (*name == "cpu" && !only_gpu) || (*name == "gpu" && c.is_some()))
                .collect();
            for (name, gpu) in backends {
                let mut walls = Vec::new();
                let mut cpus = Vec::new();
                let mut last = None;
                for _ in 0..if gpu.is_some() { gpu_runs } else { runs } {
                    let (c0, t0) = (cpu_seconds(), Instant::now());
                    let out = match gpu {
                        Some(ctx) => estimate_gpu(ctx, &particles, &params),
                        None => estimate_cpu(&particles, &params),
                    }
                    .unwrap();
                    walls.push(t0.elapsed().as_secs_f64());
                    cpus.push(cpu_seconds() - c0);
                    last = Some(out);
                }
                let out = last.unwrap();
                let t = &out.stats.timings;
                println!(
                    "  {:<6} {:<4} {:>9.3} {:>9.2} {:>9.3} {:>9.3} {:>9.3} {:>8.4} {:>7.4} {:>12.1}",
                    method.name(),
                    name,
                    median(walls),
                    median(cpus),
                    t.prepare.as_secs_f64(),
                    t.estimate.as_secs_f64(),
                    t.finish.as_secs_f64(),
                    truth.rel_l2(&out.density),
                    out.stats.grid_mass / total_mass,
                    out.stats.used_mean
                );
            }
        }
    }
}
