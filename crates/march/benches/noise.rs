//! The offset noise's cost and error on the demo's scenes (issue #30): the CPU march
//! (`render_cpu`, its layout build and the noise bake included) at 960 x 540, vdbmarch's
//! defaults (step a third of a voxel diagonal, `default_spp`, seed and camera from the
//! cache), amplitude one voxel and the default scale (four voxels, 3 octaves), on the
//! caches `scripts/bench_noise.sh` makes with `scripts/demo.sh`'s flags:
//!
//!     scripts/bench_noise.sh        (makes out/bench/noise/{cloud,plume}.vdb, then runs this)
//!     cargo bench --locked -p nimbus-march --bench noise [-- nodes=4,8 runs=5 only=cloud size=960x540 exact=0 evals=displaced,offsets]
//!
//! Rows: the march without noise, with the baked noise at each lattice (nodes per noise
//! scale) read at each sample (`NoiseEval::Baked`), with the displaced medium baked on the
//! density's lattice (`NoiseEval::Displaced`, the default) (a lattice of offsets finer than
//! half a voxel is not baked but evaluated per sample, so at the default scale nodes=16 is
//! the exact march) and with the exact per-sample fBm;
//! medians of `runs` alternating runs (the exact march once: it takes tens of times as
//! long), and the ratio to the march without noise. Error: the relative RMSE of each image
//! against the exact-noise image over the pixels it covers (alpha > 1%), relative to their
//! mean radiance, and the largest per-pixel difference in alpha. `exact=0` leaves the exact
//! march and the errors out (times alone); `size=WxH` renders at another size (the error
//! figures in docs/benchmarks.md are at 240x135, where the exact march takes a minute).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::{Vec3, Vec4};
use nimbus_cache::IlluminationCache;
use nimbus_cli::{read_density, read_vdb, read_vec3_grid, Input, PipelineMeta};
use nimbus_march::{default_spp, render_cpu, Image, MarchParams, NoiseEval};
use nimbus_optics::Camera;

/// Relative RMSE of `image` against `reference` over covered pixels, and the largest alpha
/// difference.
fn errors(image: &Image, reference: &Image) -> (f64, f32) {
    let (mut sq, mut sum, mut n, mut alpha) = (0.0f64, 0.0f64, 0usize, 0.0f32);
    for (p, r) in image.rgba.iter().zip(&reference.rgba) {
        alpha = alpha.max((p.w - r.w).abs());
        if r.w > 0.01 {
            let d: Vec4 = *p - *r;
            sq += d.truncate().length_squared() as f64 / 3.0;
            sum += r.truncate().element_sum() as f64 / 3.0;
            n += 1;
        }
    }
    ((sq / n as f64).sqrt() / (sum / n as f64), alpha)
}

fn main() {
    let arg = |name: &str| std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).map(str::to_owned));
    let nodes: Vec<u32> = arg("nodes").map_or(vec![4, 8], |s| s.split(',').map(|n| n.parse().expect("nodes=N,N,...")).collect());
    let runs: usize = arg("runs").map_or(5, |s| s.parse().expect("runs=N"));
    let only = arg("only");
    // Which noisy marches: the displaced medium baked (the default), the offsets read per sample.
    let evals: Vec<String> = arg("evals").map_or(vec!["displaced".into(), "offsets".into()], |s| s.split(',').map(str::to_owned).collect());
    let (width, height): (u32, u32) = arg("size").map_or((960, 540), |s| {
        let (w, h) = s.split_once('x').expect("size=WxH");
        (w.parse().expect("size=WxH"), h.parse().expect("size=WxH"))
    });
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../out/bench/noise");
    println!("| scene | march | median s | runs s | vs no noise | rel. RMSE vs exact | max alpha diff |");
    println!("|---|---|---|---|---|---|---|");
    for name in ["cloud", "plume"] {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let path = root.join(format!("{name}.vdb"));
        let fail = |e: nimbus_cli::Failure| -> ! { panic!("{}: {e} (run scripts/bench_noise.sh first)", path.display()) };
        let file = read_vdb(&Input::Path(path.clone())).unwrap_or_else(|e| fail(e));
        let (_, density) = read_density(&file, None).unwrap_or_else(|e| fail(e));
        let grid = |g| read_vec3_grid(&file, g).unwrap_or_else(|e| fail(e));
        let cache = IlluminationCache { li_single: grid("Li_single"), li_multiple: grid("Li_multiple"), ..Default::default() };
        let meta = PipelineMeta::of(&file);
        let c = meta.camera().ok().flatten().expect("the cache records its camera");
        let camera = Camera::new(c.eye(), c.look_at(), c.up(), c.fov_deg(), width, height).unwrap();
        let voxel = density.transform().voxel_size();
        let plain = MarchParams {
            environment: None,
            environment_visible: false,
            medium: meta.medium().ok().flatten().expect("the cache records its medium"),
            spp: default_spp(&camera, &density),
            camera,
            step: voxel.length() / 3.0,
            max_step_factor: MarchParams::DEFAULT_MAX_STEP_FACTOR,
            background: Vec3::ZERO,
            offset_noise: 0.0,
            noise_scale: 4.0 * voxel.max_element(),
            noise_octaves: 3,
            noise_eval: NoiseEval::DEFAULT,
            min_transmittance: 1e-4,
            seed: meta.seed().unwrap_or(0),
            aovs: false,
        };
        let noisy = |eval: NoiseEval| MarchParams { offset_noise: voxel.max_element(), noise_eval: eval, ..plain.clone() };
        let render = |p: &MarchParams| {
            let start = Instant::now();
            let image = render_cpu(&density, &cache, p).unwrap();
            (start.elapsed(), image)
        };
        // `exact=0`: times alone (the exact march takes tens of times as long).
        let exact = (arg("exact").as_deref() != Some("0")).then(|| {
            eprintln!("{name}: {width}x{height}, {} spp, exact noise once ...", plain.spp);
            render(&noisy(NoiseEval::Exact))
        });
        // Alternating, so a busy machine slows every variant alike.
        let mut variants: Vec<(String, MarchParams)> = vec![("no noise".into(), plain.clone())];
        if evals.iter().any(|e| e == "displaced") {
            variants.push(("displaced medium baked (default)".into(), noisy(NoiseEval::Displaced)));
        }
        if evals.iter().any(|e| e == "offsets") {
            for &n in &nodes {
                variants.push((format!("offsets baked, {n} nodes per scale, read per sample"), noisy(NoiseEval::Baked { nodes: n })));
            }
        }
        let mut times: Vec<Vec<Duration>> = vec![vec![]; variants.len()];
        let mut images: Vec<Option<Image>> = vec![None; variants.len()];
        for _ in 0..runs {
            for (i, (_, p)) in variants.iter().enumerate() {
                let (t, image) = render(p);
                eprintln!("{name}: {}: {:.2} s", variants[i].0, t.as_secs_f64());
                times[i].push(t);
                images[i] = Some(image);
            }
        }
        let median = |v: &[Duration]| {
            let mut v = v.to_vec();
            v.sort();
            v[v.len() / 2].as_secs_f64()
        };
        let base = median(&times[0]);
        for (i, (label, _)) in variants.iter().enumerate() {
            let m = median(&times[i]);
            let error = match &exact {
                Some((_, exact)) => {
                    let (rmse, alpha) = errors(images[i].as_ref().unwrap(), exact);
                    format!("{rmse:.4} | {alpha:.4}")
                }
                None => "- | -".into(),
            };
            let all = times[i].iter().map(|t| format!("{:.2}", t.as_secs_f64())).collect::<Vec<_>>().join(" ");
            println!("| {name} | {label} | {m:.3} | {all} | {:.2}x | {error} |", m / base);
        }
        if let Some((time, _)) = exact {
            println!("| {name} | exact (fBm per sample) | {:.3} | 1 run | {:.1}x | 0 | 0 |", time.as_secs_f64(), time.as_secs_f64() / base);
        }
    }
    println!("\nCPU: {} rayon threads", rayon::current_num_threads());
}
