//! vdbmarch on the benchmark scenes (issue 6's table): 1024 x 576 and 2048 x 1152, spp 1 and
//! 4, CPU (rayon, all cores) and GPU (whatever adapter there is; lavapipe here), on the
//! Cloud1-class and smoke-like caches that `scripts/bench-scenes.sh` makes with the release
//! tools, plus a 4096 x 2304 row as a size stress.
//!
//!     scripts/bench-scenes.sh && cargo bench -p nimbus-march --bench scenes [-- quick] [-- stress] [-- only=smoke]
//!     cargo bench -p nimbus-march --bench scenes -- speed
//!
//! `speed` times the CPU march alone on the Cloud1-class caches at 1024 x 576, 1 spp: the
//! plain march (`march_ray` per pixel over the sparse volumes, the engine before the
//! march's own layout), the layout's march with a fixed step (`--max-step-factor 1`, the
//! same images) and with the default step control; medians of 5 alternating runs and
//! their ratios to the plain march. Besides `cloud1.vdb` it takes `cloud1-new.vdb` when
//! present: vdbcache's newer layout (Li_single at the density's resolution, Li_multiple 4x
//! coarser), made by
//!
//!     particles2vdb data/cloud.ply --voxel-size 1 | vdbcache --extinction 30 --albedo 0.95 --g 0.6 \
//!         --sun dir=0.5,0.3,-0.8,irradiance=4 --eye 170,-300,160 --look-at 170,180,10 --width 1024 \
//!         --height 576 --cache-scale 1 --multiple-scale 4 --paths 1 -o out/bench/cloud1-new.vdb
//!
//! Times are the march alone (the cache is loaded once; GPU times include uploads and
//! read-back), median of 3 runs (1 run where one takes over 10 s). Error: each image is
//! box-filtered down to 1024 x 576 and compared with a reference marched on the CPU at
//! 1024 x 576, 4 spp and half the default step: RMSE over pixels the reference sees as
//! covered (alpha > 1%), relative to their mean radiance. (This measures the march's own
//! discretisation; the chain's error against the path-traced ground truth is `make
//! bench`'s nimbus-bench.)

#[path = "../tests/common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::{Vec3, Vec4};
use nimbus_cache::IlluminationCache;
use nimbus_cli::{read_density, read_vdb, read_vec3_grid, Input, PipelineMeta};
use nimbus_march::{render_cpu, render_gpu, Image, MarchParams};
use nimbus_optics::Camera;
use nimbus_volume::Volume;

struct Scene {
    name: &'static str,
    density: Volume<f32>,
    cache: IlluminationCache,
    base: MarchParams,
}

fn load(name: &'static str, path: &Path) -> Scene {
    let fail = |e: nimbus_cli::Failure| -> ! { panic!("{}: {e} (run scripts/bench-scenes.sh first)", path.display()) };
    let file = read_vdb(&Input::Path(path.to_path_buf())).unwrap_or_else(|e| fail(e));
    let (_, density) = read_density(&file, None).unwrap_or_else(|e| fail(e));
    let cache = IlluminationCache {
        li_single: read_vec3_grid(&file, "Li_single").unwrap_or_else(|e| fail(e)),
        li_multiple: read_vec3_grid(&file, "Li_multiple").unwrap_or_else(|e| fail(e)),
        ..Default::default()
    };
    let meta = PipelineMeta::of(&file);
    let camera = meta.camera().ok().flatten().expect("the cache records its camera");
    let voxel = density.transform().voxel_size();
    let medium = meta.medium().ok().flatten().expect("the cache records its medium");
    // vdbmarch's defaults.
    let base = MarchParams { step: voxel.length() / 3.0, seed: meta.seed().unwrap_or(0), ..MarchParams::new(medium, camera, density.transform()) };
    Scene { name, density, cache, base }
}

fn sized(p: &MarchParams, width: u32, height: u32) -> MarchParams {
    let c = &p.camera;
    let camera = Camera::new(c.eye(), c.look_at(), c.up(), c.fov_deg(), width, height).unwrap();
    MarchParams { camera, ..p.clone() }
}

/// Box-filters `image` down by an integer factor.
fn downsample(image: &Image, factor: u32) -> Vec<Vec4> {
    let (w, h) = (image.width / factor, image.height / factor);
    let mut out = vec![Vec4::ZERO; (w * h) as usize];
    for y in 0..image.height {
        for x in 0..image.width {
            out[((y / factor) * w + x / factor) as usize] += image.rgba[(y * image.width + x) as usize];
        }
    }
    let inv = 1.0 / (factor * factor) as f32;
    out.iter_mut().for_each(|p| *p *= inv);
    out
}

/// Relative RMSE of `image` against `reference` over covered pixels.
fn relative_rmse(image: &[Vec4], reference: &[Vec4]) -> f64 {
    let (mut sq, mut sum, mut n) = (0.0f64, 0.0f64, 0usize);
    for (p, r) in image.iter().zip(reference) {
        if r.w > 0.01 {
            let d = (p.truncate() - r.truncate()) / 3.0;
            sq += (d.x as f64).powi(2) + (d.y as f64).powi(2) + (d.z as f64).powi(2);
            sum += r.truncate().element_sum() as f64 / 3.0;
            n += 1;
        }
    }
    if n == 0 {
        return f64::NAN;
    }
    (3.0 * sq / n as f64).sqrt() / (sum / n as f64)
}

/// Median time of up to 3 runs (1 if the first takes over 10 s), and the last image.
fn timed(mut f: impl FnMut() -> Image) -> (Duration, Image) {
    let start = Instant::now();
    let mut image = f();
    let mut times = vec![start.elapsed()];
    if times[0] < Duration::from_secs(10) {
        for _ in 0..2 {
            let start = Instant::now();
            image = f();
            times.push(start.elapsed());
        }
    }
    times.sort();
    (times[times.len() / 2], image)
}

/// The plain march over the image, 1 spp at pixel centres (its own lattice offsets: only
/// its time is compared).
fn plain_march(scene: &Scene, params: &MarchParams) -> Duration {
    use rayon::prelude::*;
    let majorant = nimbus_volume::MajorantGrid::build(&scene.density);
    let c = &params.camera;
    let (w, h) = (c.width() as usize, c.height() as usize);
    let start = Instant::now();
    let pixels: Vec<nimbus_march::RayResult> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (origin, dir) = c.ray((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            let xi = ((i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 11) as f64 / (1u64 << 53) as f64;
            nimbus_march::march_ray(&scene.density, &majorant, &scene.cache, params, origin, dir, xi, 0.5)
        })
        .collect();
    std::hint::black_box(pixels);
    start.elapsed()
}

fn speed(scenes: &[Scene]) {
    println!("| scene | march | median s | runs | vs plain |");
    println!("|---|---|---|---|---|");
    let median = |mut v: Vec<Duration>| {
        v.sort();
        v[v.len() / 2]
    };
    for scene in scenes {
        let params = sized(&scene.base, 1024, 576);
        let fixed = MarchParams { max_step_factor: 1, ..params.clone() };
        let layout = |p: &MarchParams| {
            let start = Instant::now();
            std::hint::black_box(render_cpu(&scene.density, &scene.cache, p).unwrap());
            start.elapsed()
        };
        let (mut plain, mut exact, mut controlled) = (vec![], vec![], vec![]);
        // Alternating, so a busy machine slows all three alike.
        for _ in 0..5 {
            plain.push(plain_march(scene, &fixed));
            exact.push(layout(&fixed));
            controlled.push(layout(&params));
        }
        let base = median(plain.clone()).as_secs_f64();
        for (name, times) in [("plain (march_ray)", plain), ("layout, fixed step", exact), ("layout, step control (default)", controlled)] {
            let m = median(times.clone()).as_secs_f64();
            let runs = times.iter().map(|t| format!("{:.2}", t.as_secs_f64())).collect::<Vec<_>>().join(" ");
            println!("| {} | {name} | {m:.3} | {runs} | {:.2}x |", scene.name, base / m);
        }
    }
    println!("\nCPU: {} rayon threads", rayon::current_num_threads());
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../out/bench");
    if std::env::args().any(|a| a == "speed") {
        let mut scenes = vec![load("cloud1", &root.join("cloud1.vdb"))];
        if root.join("cloud1-new.vdb").exists() {
            scenes.push(load("cloud1-new", &root.join("cloud1-new.vdb")));
        }
        return speed(&scenes);
    }
    // `-- only=smoke` (or cloud1) runs one scene.
    let only = std::env::args().find_map(|a| a.strip_prefix("only=").map(str::to_owned));
    let wanted = |name: &str| only.as_deref().is_none_or(|o| o == name);
    let mut scenes = Vec::new();
    if wanted("cloud1") {
        scenes.push(load("cloud1", &root.join("cloud1.vdb")));
    }
    if !quick && wanted("smoke") {
        scenes.push(load("smoke", &root.join("smoke.vdb")));
    }
    let ctx = common::gpu();
    let mut sizes = vec![(1024, 576), (2048, 1152)];
    if std::env::args().any(|a| a == "stress") {
        sizes.push((4096, 2304));
    }
    println!("| scene | voxels | image | spp | backend | march s | rel. RMSE | mean ratio |");
    println!("|---|---|---|---|---|---|---|---|");
    for scene in &scenes {
        let (lo, hi) = scene.density.active_index_bbox().expect("non-empty density");
        let dims = hi - lo + 1;
        let voxels = format!("{}x{}x{}", dims.x, dims.y, dims.z);
        let fine = MarchParams { spp: 4, step: scene.base.step / 2.0, ..sized(&scene.base, 1024, 576) };
        let start = Instant::now();
        let reference = render_cpu(&scene.density, &scene.cache, &fine).unwrap();
        eprintln!("{}: reference (1024x576, 4 spp, step/2) in {:.1} s", scene.name, start.elapsed().as_secs_f64());
        // Mean over pixels of R + G + B, as `mean` below.
        let ref_mean = reference.mean_rgb().element_sum() as f64;
        for &(w, h) in &sizes {
            for spp in if (w, h) == (4096, 2304) { vec![1] } else { vec![1, 4] } {
                let params = MarchParams { spp, ..sized(&scene.base, w, h) };
                let mut backends: Vec<(&str, Box<dyn Fn() -> Image>)> =
                    vec![("cpu", Box::new(|| render_cpu(&scene.density, &scene.cache, &params).unwrap()))];
                if let Some(ctx) = ctx {
                    backends.push(("gpu", Box::new(|| render_gpu(ctx, &scene.density, &scene.cache, &params).unwrap())));
                }
                for (backend, render) in backends {
                    let (time, image) = timed(render);
                    let small = downsample(&image, w / 1024);
                    let err = relative_rmse(&small, &reference.rgba);
                    let mean = small.iter().map(|p| p.truncate()).sum::<Vec3>().element_sum() as f64 / small.len() as f64;
                    println!(
                        "| {} | {voxels} | {w}x{h} | {spp} | {backend} | {:.3} | {:.4} | {:.4} |",
                        scene.name,
                        time.as_secs_f64(),
                        err,
                        mean / ref_mean
                    );
                }
            }
        }
    }
    match ctx {
        Some(ctx) => println!("\nGPU: {}; CPU: {} rayon threads", ctx.info, rayon::current_num_threads()),
        None => println!("\nno GPU adapter: CPU rows only"),
    }
}
