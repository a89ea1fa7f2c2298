//! `shaders/optics.wgsl` run in a compute shader (any adapter, lavapipe included) against the
//! Rust implementations: the rng bit for bit, HG sampling and evaluation to 1e-5, and the
//! light, medium and camera helpers to f32 rounding.
//!
//! Skips loudly when the machine has no adapter at all (CI has lavapipe, so there it runs).

use glam::{DVec3, Vec2, Vec3};
use nimbus_gpu::{storage_entry, params_entry, GpuContext};
use nimbus_optics::{Camera, GpuCamera, GpuLight, GpuMedium, HenyeyGreenstein, Light, Medium, Rng, OPTICS_WGSL};

fn gpu() -> Option<&'static GpuContext> {
    nimbus_gpu::test_context()
}

const N: u32 = 4096;
const WORDS: u32 = 10; // more than two Philox blocks per item: exercises the refill
const SEED: u64 = 0x0123_4567_89ab_cdef;
const GS: [f32; 8] = [-0.999, -0.9, -0.5, 0.0, 0.3, 0.5, 0.99, 0.999];

/// Item i: its rng words, its HG sample (u drawn from domain 7), HG eval at a given cosine,
/// and light/medium/camera values at a given point.
const KERNEL: &str = r#"
const N: u32 = 4096u;
const WORDS: u32 = 10u;
const SEED: vec2<u32> = vec2<u32>(0x89abcdefu, 0x01234567u);
const GS = array<f32, 8>(-0.999, -0.9, -0.5, 0.0, 0.3, 0.5, 0.99, 0.999);

// inputs[i]: (w_in.xyz, cos for hg_eval); points[i]: (world point.xyz, density)
@group(0) @binding(0) var<storage, read> inputs: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> words: array<u32>;
// per item: (w_out, pdf), (u, eval, sigma_t), (sigma_s, 0), (to_light, distance), (irradiance, 0), (camera dir, 0)
@group(0) @binding(3) var<storage, read_write> floats: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> medium: Medium;
@group(0) @binding(5) var<storage, read> light: Light;
@group(0) @binding(6) var<storage, read> camera: Camera;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= N) {
        return;
    }
    let index = vec2<u32>(i, i % 5u);
    var rng = rng_new(SEED, index, i % 3u);
    for (var k = 0u; k < WORDS; k = k + 1u) {
        words[i * WORDS + k] = rng_next_u32(&rng);
    }
    var gs = GS;
    let g = gs[i % 8u];
    var hg_rng = rng_new(SEED, index, 7u);
    let u = rng_next_vec2(&hg_rng);
    let s = hg_sample(g, inputs[i].xyz, u);
    let p = points[i];
    let inc = light_incident(light, p.xyz);
    let base = i * 6u;
    floats[base] = vec4<f32>(s.w_out, s.pdf);
    floats[base + 1u] = vec4<f32>(u, hg_eval(g, inputs[i].w), medium_sigma_t(medium, p.w));
    floats[base + 2u] = vec4<f32>(medium_sigma_s(medium, p.w), 0.0);
    floats[base + 3u] = vec4<f32>(inc.to_light, inc.distance);
    floats[base + 4u] = vec4<f32>(inc.irradiance, 0.0);
    floats[base + 5u] = vec4<f32>(camera_ray(camera, p.xy * vec2<f32>(0.1, 0.05)), 0.0);
}
"#;

/// SplitMix64 for test inputs.
struct TestRng(u64);
impl TestRng {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn close3(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

fn rel(a: f32, b: f32) -> f32 {
    (a - b).abs() / b.abs().max(1e-30)
}

#[test]
fn wgsl_optics_match_the_cpu() {
    let Some(ctx) = gpu() else { return };

    let mut t = TestRng(99);
    let inputs: Vec<[f32; 4]> = (0..N)
        .map(|i| {
            let w = match i % 16 {
                0 => Vec3::Z,
                1 => Vec3::NEG_Z,
                2 => Vec3::X,
                _ => nimbus_optics::sample_uniform_sphere(Vec2::new(t.next(), t.next())),
            };
            [w.x, w.y, w.z, 2.0 * t.next() - 1.0]
        })
        .collect();
    let points: Vec<[f32; 4]> = (0..N).map(|_| [10.0 * t.next() - 5.0, 10.0 * t.next() - 5.0, 10.0 * t.next() - 5.0, 3.0 * t.next()]).collect();

    let medium = Medium::new(1.7, Vec3::new(0.9, 0.5, 0.25), 0.3).unwrap();
    let light = Light::point(DVec3::new(1.0, 2.0, 3.0), Vec3::new(10.0, 20.0, 30.0)).unwrap();
    let camera = Camera::new(DVec3::new(0.5, -8.0, 1.0), DVec3::ZERO, DVec3::Z, 50.0, 96, 54).unwrap();
    let origin = DVec3::ZERO;

    let layout = ctx
        .bind_group_layout(
            "optics test",
            &[storage_entry(0, true), storage_entry(1, true), storage_entry(2, false), storage_entry(3, false), params_entry(4), params_entry(5), params_entry(6)],
        )
        .unwrap();
    let source = format!("{OPTICS_WGSL}\n{KERNEL}");
    let pipeline = ctx.compute_pipeline("optics test", &source, "main", &[&layout]).unwrap();
    let buffers = [
        ctx.storage_buffer("inputs", &inputs).unwrap(),
        ctx.storage_buffer("points", &points).unwrap(),
        ctx.storage_buffer_zeroed("words", (N * WORDS * 4) as u64).unwrap(),
        ctx.storage_buffer_zeroed("floats", (N * 6 * 16) as u64).unwrap(),
        ctx.params_buffer("medium", &GpuMedium::from(&medium)).unwrap(),
        ctx.params_buffer("light", &GpuLight::new(&light, origin)).unwrap(),
        ctx.params_buffer("camera", &GpuCamera::new(&camera, origin)).unwrap(),
    ];
    let group = ctx.buffer_bind_group("optics test", &layout, &buffers.iter().collect::<Vec<_>>()).unwrap();
    ctx.dispatch("optics test", &pipeline, &[&group], [N / 64, 1, 1]).unwrap();
    let words: Vec<u32> = ctx.read_buffer(&buffers[2]).unwrap();
    let floats: Vec<[f32; 4]> = ctx.read_buffer(&buffers[3]).unwrap();

    let (mut worst_dir, mut worst_pdf, mut worst_eval) = (0.0f32, 0.0f32, 0.0f32);
    for i in 0..N {
        let index = i as u64 | ((i % 5) as u64) << 32;
        // rng: bit-exact.
        let mut rng = Rng::with_domain(SEED, index, i % 3);
        for k in 0..WORDS {
            assert_eq!(words[(i * WORDS + k) as usize], rng.next_u32(), "item {i} word {k}");
        }
        let mut hg_rng = Rng::with_domain(SEED, index, 7);
        let u = hg_rng.next_vec2();
        let f = &floats[(i * 6) as usize..(i * 6 + 6) as usize];
        assert_eq!((f[1][0], f[1][1]), (u.x, u.y), "item {i}: unit floats differ");

        // HG sample and eval: 1e-5 (absolute on directions, relative on densities).
        let hg = HenyeyGreenstein::new(GS[(i % 8) as usize]);
        let w_in = Vec3::new(inputs[i as usize][0], inputs[i as usize][1], inputs[i as usize][2]);
        let (w_out, pdf) = hg.sample_with_pdf(w_in, u);
        let gpu_w = Vec3::new(f[0][0], f[0][1], f[0][2]);
        worst_dir = worst_dir.max((gpu_w - w_out).abs().max_element());
        worst_pdf = worst_pdf.max(rel(f[0][3], pdf));
        worst_eval = worst_eval.max(rel(f[1][2], hg.eval(inputs[i as usize][3])));
        assert!(close3(gpu_w, w_out, 1e-5), "item {i} g {}: w_out {gpu_w} vs {w_out}", hg.g);
        assert!(rel(f[0][3], pdf) < 1e-5, "item {i} g {}: pdf {} vs {pdf}", hg.g, f[0][3]);
        assert!(rel(f[1][2], hg.eval(inputs[i as usize][3])) < 1e-5, "item {i} g {}: eval", hg.g);

        // Medium, light, camera: f32 rounding.
        let p = points[i as usize];
        assert!(rel(f[1][3], medium.sigma_t(p[3])) < 1e-6, "sigma_t");
        assert!(close3(Vec3::new(f[2][0], f[2][1], f[2][2]), medium.sigma_s(p[3]), 1e-6), "sigma_s");
        let inc = light.incident(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        assert!(close3(Vec3::new(f[3][0], f[3][1], f[3][2]), inc.to_light, 1e-5), "to_light");
        assert!(rel(f[3][3], inc.distance as f32) < 1e-5, "distance");
        let e = Vec3::new(f[4][0], f[4][1], f[4][2]);
        assert!((e - inc.irradiance).abs().max_element() <= 1e-5 * inc.irradiance.max_element(), "irradiance {e} vs {}", inc.irradiance);
        let (_, dir) = camera.ray(p[0] as f64 * 0.1, p[1] as f64 * 0.05);
        assert!(close3(Vec3::new(f[5][0], f[5][1], f[5][2]), dir.as_vec3(), 1e-5), "camera ray");
    }
    eprintln!("largest GPU-CPU differences: w_out {worst_dir:e}, pdf (relative) {worst_pdf:e}, eval (relative) {worst_eval:e}");

    // Sun: direction and irradiance pass straight through.
    let sun = Light::sun(Vec3::new(0.3, 0.4, -1.0), Vec3::new(1.0, 2.0, 3.0)).unwrap();
    let g = GpuLight::new(&sun, origin);
    let Light::Sun { dir, .. } = sun else { unreachable!() };
    assert_eq!((g.vector, g.kind, g.power), (dir.to_array(), nimbus_optics::LIGHT_SUN, [1.0, 2.0, 3.0]));
}
