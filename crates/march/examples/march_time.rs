//! The CPU march alone on one cache file (`render_cpu`, its layout build included), at
//! vdbmarch's defaults (step `default_step`, 1 spp, the camera, medium and seed
//! the cache records): a 1 x 1 render (the layout build and little else), then WIDTH x
//! HEIGHT, RUNS times each, minimum and median wall time to stderr.
//!
//!     cargo run --release -p nimbus-march --example march_time -- CACHE.vdb [RUNS [WIDTH HEIGHT]] [aovs]
//!
//! RUNS defaults to 3, the size to 1024 x 576; `aovs` keeps the single and multiple layers
//! apart (vdbmarch --aovs). Environment: MAX_STEP_FACTOR (vdbmarch --max-step-factor,
//! default 2), STEP_SCALE (the step as a multiple of the default, default 1).
//!
//! Unlike `cargo bench --bench scenes -- speed` (medians of alternating runs against the
//! plain march), one render is small enough for callgrind, whose instruction counts are
//! what a loaded machine can compare: the march alone is what runs inside `band_fma` (the
//! AVX2+FMA tile loop; `render_band` where the CPU lacks them).
//!
//!     RAYON_NUM_THREADS=1 valgrind --tool=callgrind --toggle-collect='*band_fma*' \
//!         target/release/examples/march_time out/bench/cloud1.vdb 1 256 144

use std::path::PathBuf;
use std::time::Instant;

use nimbus_cache::IlluminationCache;
use nimbus_cli::{read_density, read_vdb, read_vec3_grid, Input, PipelineMeta};
use nimbus_march::{render_cpu, MarchParams};
use nimbus_optics::Camera;

fn main() {
    let aovs = std::env::args().any(|a| a == "aovs");
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "aovs").collect();
    let Some(path) = args.first() else {
        eprintln!("usage: march_time CACHE.vdb [RUNS [WIDTH HEIGHT]] [aovs]");
        std::process::exit(2);
    };
    let number = |i: usize, default: u32| args.get(i).map_or(default, |s| s.parse().unwrap_or_else(|_| panic!("not a number: {s}")));
    let env = |name: &str, default: f64| std::env::var(name).map_or(default, |s| s.parse().unwrap_or_else(|_| panic!("{name}: not a number: {s}")));
    let (runs, width, height) = (number(1, 3).max(1), number(2, 1024), number(3, 576));

    let start = Instant::now();
    let file = read_vdb(&Input::Path(PathBuf::from(path))).unwrap_or_else(|e| panic!("{path}: {e}"));
    let opened = start.elapsed();
    let (_, density) = read_density(&file, None).unwrap_or_else(|e| panic!("{path}: {e}"));
    let grid = |name| read_vec3_grid(&file, name).unwrap_or_else(|e| panic!("{path}: {e}"));
    let cache = IlluminationCache { li_single: grid("Li_single"), li_multiple: grid("Li_multiple"), ..Default::default() };
    eprintln!("open {:.3} s, grids {:.3} s", opened.as_secs_f64(), (start.elapsed() - opened).as_secs_f64());

    let meta = PipelineMeta::of(&file);
    let camera = meta.camera().ok().flatten().expect("the cache records its camera");
    let medium = meta.medium().ok().flatten().expect("the cache records its medium");
    let base = MarchParams {
        step: nimbus_march::default_step(density.transform()) * env("STEP_SCALE", 1.0),
        max_step_factor: env("MAX_STEP_FACTOR", MarchParams::DEFAULT_MAX_STEP_FACTOR as f64) as u32,
        seed: meta.seed().unwrap_or(0),
        aovs,
        ..MarchParams::new(medium, camera.clone(), density.transform())
    };
    for (w, h) in [(1, 1), (width, height)] {
        let camera = Camera::new(camera.eye(), camera.look_at(), camera.up(), camera.fov_deg(), w, h).unwrap();
        let params = MarchParams { camera, ..base.clone() };
        let mut times: Vec<f64> = (0..runs)
            .map(|_| {
                let start = Instant::now();
                std::hint::black_box(render_cpu(&density, &cache, &params).unwrap());
                start.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        eprintln!("{w}x{h}: min {:.3} median {:.3} s", times[0], times[times.len() / 2]);
    }
}
