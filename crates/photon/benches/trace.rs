//! Photon tracing, CPU (rayon, all cores) against GPU (whatever adapter there is; lavapipe
//! on CI and on the development machines), for a few volume sizes and photon counts, every
//! distance mode.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-photon --bench trace [-- quick]
//!
//! Times are end to end (set-up, upload, tracing, read-back, sorting), best of 2 runs.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::{Duration, Instant};

use glam::Vec3;
use nimbus_optics::Medium;
use nimbus_photon::{trace_cpu, trace_gpu, DistanceSampling, PhotonParams};

fn best_of_2<R>(mut f: impl FnMut() -> R) -> (Duration, R) {
    let start = Instant::now();
    let first = f();
    let a = start.elapsed();
    let start = Instant::now();
    let second = f();
    let b = start.elapsed();
    if a <= b { (a, first) } else { (b, second) }
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let ctx = common::gpu();
    let cases: &[(i32, u64)] = if quick { &[(32, 5_000)] } else { &[(32, 5_000), (64, 50_000), (96, 200_000)] };
    println!("{:>6} {:>8} {:>12} {:>10} {:>10} {:>8}", "volume", "photons", "mode", "cpu ms", "gpu ms", "gpu/cpu");
    for &(n, photons) in cases {
        let v = common::cloud(n, 4.0 * 32.0 / n as f32);
        for mode in [DistanceSampling::Simpson, DistanceSampling::Exponential, DistanceSampling::Delta] {
            let p = PhotonParams {
                distance: mode,
                photons,
                seed: 1,
                medium: Medium { extinction: 1.0, albedo: Vec3::splat(0.9), g: 0.3 },
                ..PhotonParams::default()
            };
            let (cpu, _) = best_of_2(|| trace_cpu(&v, &p).unwrap());
            let gpu = ctx.map(|ctx| best_of_2(|| trace_gpu(ctx, &v, &p).unwrap()).0);
            let ms = |d: Duration| d.as_secs_f64() * 1e3;
            match gpu {
                Some(g) => println!(
                    "{:>5}^3 {photons:>8} {:>12} {:>10.1} {:>10.1} {:>8.2}",
                    n,
                    mode.name(),
                    ms(cpu),
                    ms(g),
                    ms(g) / ms(cpu)
                ),
                None => println!("{:>5}^3 {photons:>8} {:>12} {:>10.1} {:>10} {:>8}", n, mode.name(), ms(cpu), "-", "-"),
            }
        }
    }
    if let Some(ctx) = ctx {
        println!("GPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads());
    }
}
