//! Ray marching, CPU (rayon, all cores) against GPU (whatever adapter there is; lavapipe on
//! CI and the development machines), for a few volume and image sizes, with and without
//! offset noise.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-march --bench render [-- quick]
//!
//! Times are end to end (uploads, pipeline, march, read-back, image assembly), best of 2.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::{Duration, Instant};

use glam::DVec3;
use nimbus_march::{render_cpu, render_gpu, MarchParams};

fn best_of_2<R>(mut f: impl FnMut() -> R) -> Duration {
    let start = Instant::now();
    f();
    let a = start.elapsed();
    let start = Instant::now();
    f();
    a.min(start.elapsed())
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let ctx = common::gpu();
    let cases: &[(i32, u32, u32)] = if quick { &[(32, 64, 48)] } else { &[(32, 64, 48), (64, 320, 240), (96, 640, 360)] };
    println!("{:>6} {:>9} {:>6} {:>10} {:>10} {:>8}", "volume", "image", "noise", "cpu ms", "gpu ms", "gpu/cpu");
    for &(n, w, h) in cases {
        let v = common::cloud(n, 3.0 * 32.0 / n as f32, DVec3::ZERO);
        let cache = common::cache_for(&v);
        for noise in [0.0, 0.1] {
            let mut p: MarchParams = common::params(common::camera(DVec3::ZERO, w, h));
            p.offset_noise = noise;
            p.step = 0.5 * common::VOXEL * 32.0 / n as f64;
            let cpu = best_of_2(|| render_cpu(&v, &cache, &p).unwrap());
            let gpu = ctx.map(|ctx| best_of_2(|| render_gpu(ctx, &v, &cache, &p).unwrap()));
            let ms = |d: Duration| d.as_secs_f64() * 1e3;
            let size = format!("{w}x{h}");
            match gpu {
                Some(g) => println!("{:>5}^3 {size:>9} {noise:>6} {:>10.1} {:>10.1} {:>8.2}", n, ms(cpu), ms(g), ms(g) / ms(cpu)),
                None => println!("{:>5}^3 {size:>9} {noise:>6} {:>10.1} {:>10} {:>8}", n, ms(cpu), "-", "-"),
            }
        }
    }
    if let Some(ctx) = ctx {
        println!("GPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads());
    }
}
