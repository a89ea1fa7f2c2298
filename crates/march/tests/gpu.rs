//! The GPU backend against the CPU backend (design.md section 1), and the WGSL noise
//! against nimbus_optics::noise. Runs on any adapter, lavapipe included; with no adapter at
//! all each test says so loudly and passes.

mod common;

use common::{cache_for, camera, cloud, gpu, params};
use glam::{DVec3, Vec3};
use nimbus_gpu::{storage_entry, GpuContext};
use nimbus_march::{render_cpu, render_cpu_with, render_gpu, render_gpu_with, CacheLookup, EmissionField, GpuMarchOptions, Image, MarchParams, MediumFields, NoiseEval, NOISE_WGSL};
use nimbus_optics::noise::{fbm3_vec, perlin3};

/// Worst relative difference over lit pixels (scattered light above 1e-3 of the brightest pixel) of
/// RGB, single and multiple; worst absolute difference of alpha and transmittance; how many
/// depths differ by more than 1e-4 relative (a lattice sample whose transmittance sits at
/// the 0.99 threshold within rounding can pick its neighbour).
struct Diff {
    rgb: f32,
    single: f32,
    multiple: f32,
    alpha: f32,
    transmittance: f32,
    depth_mismatches: usize,
    lit: usize,
}

fn rel(a: Vec3, b: Vec3, floor: f32) -> f32 {
    ((a - b).abs() / b.abs().max(Vec3::splat(floor))).max_element()
}

fn diff(cpu: &Image, gpu: &Image) -> Diff {
    assert_eq!((cpu.width, cpu.height), (gpu.width, gpu.height));
    assert_eq!(gpu.nonfinite, 0);
    let lum = |p: Vec3| p.element_sum();
    let max = cpu.rgba.iter().map(|p| lum(p.truncate())).fold(0.0, f32::max);
    let floor = 1e-3 * max / 3.0;
    let (ca, ga) = (cpu.aovs.as_ref().unwrap(), gpu.aovs.as_ref().unwrap());
    let mut d = Diff { rgb: 0.0, single: 0.0, multiple: 0.0, alpha: 0.0, transmittance: 0.0, depth_mismatches: 0, lit: 0 };
    for i in 0..cpu.rgba.len() {
        let (c, g) = (cpu.rgba[i], gpu.rgba[i]);
        d.alpha = d.alpha.max((c.w - g.w).abs());
        d.transmittance = d.transmittance.max((ca.transmittance[i] - ga.transmittance[i]).abs());
        let (cd, gd) = (ca.depth[i], ga.depth[i]);
        if (cd - gd).abs() > 1e-4 * cd.abs().max(1.0) {
            d.depth_mismatches += 1;
        }
        if lum(ca.single[i] + ca.multiple[i]) > 1e-3 * max {
            d.lit += 1;
            d.rgb = d.rgb.max(rel(g.truncate(), c.truncate(), floor));
            d.single = d.single.max(rel(ga.single[i], ca.single[i], floor));
            d.multiple = d.multiple.max(rel(ga.multiple[i], ca.multiple[i], floor));
        }
    }
    d
}

fn report(name: &str, d: &Diff) {
    eprintln!(
        "{name}: {} lit pixels; max rel diff rgb {:.2e} single {:.2e} multiple {:.2e}; max abs diff alpha {:.2e} T {:.2e}; depth mismatches {}",
        d.lit, d.rgb, d.single, d.multiple, d.alpha, d.transmittance, d.depth_mismatches
    );
}

fn assert_close(name: &str, d: &Diff, pixels: usize) {
    report(name, d);
    assert!(d.lit > pixels / 4, "{name}: the scene should light a good part of the image ({} lit)", d.lit);
    assert!(d.rgb <= 1e-4 && d.single <= 1e-4 && d.multiple <= 1e-4, "{name}: rgb {} single {} multiple {}", d.rgb, d.single, d.multiple);
    assert!(d.alpha <= 1e-5 && d.transmittance <= 1e-5, "{name}: alpha {} T {}", d.alpha, d.transmittance);
    assert!(d.depth_mismatches <= pixels / 200, "{name}: {} depth mismatches", d.depth_mismatches);
}

const EXACT: GpuMarchOptions =
    GpuMarchOptions { cache_lookup: CacheLookup::Exact, max_tile_pixels: GpuMarchOptions::DEFAULT_MAX_TILE_PIXELS };

fn scene(centre: DVec3) -> (nimbus_volume::Volume<f32>, nimbus_cache::IlluminationCache, MarchParams) {
    let v = cloud(32, 3.0, centre);
    let cache = cache_for(&v);
    (v, cache, params(camera(centre, 64, 48)))
}

/// Both backends' images of the 64 x 48 scene, held to agree (exact GPU cache lookups).
fn both_agree(ctx: &GpuContext, name: &str, v: &nimbus_volume::Volume<f32>, cache: &nimbus_cache::IlluminationCache, p: &MarchParams) -> Image {
    let cpu = render_cpu(v, cache, p).unwrap();
    let gpu = render_gpu_with(ctx, v, cache, p, MediumFields::default(), &EXACT).unwrap();
    assert_close(name, &diff(&cpu, &gpu), 64 * 48);
    cpu
}

#[test]
fn images_agree_without_noise() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, p) = scene(DVec3::ZERO);
    both_agree(ctx, "no noise, 1 spp", &v, &cache, &p);
}

#[test]
fn images_agree_on_vdbcache_lattices() {
    // Li_single on the density's own points and Li_multiple on every fourth: the CPU
    // resamples both onto its density lattice, the GPU looks each up on its own.
    let Some(ctx) = gpu() else { return };
    let (v, _, p) = scene(DVec3::ZERO);
    both_agree(ctx, "cache scales 1 and 4, 1 spp", &v, &common::cache_on_density_lattice(&v, 1.0, 4.0), &p);
}

#[test]
fn images_agree_with_longer_steps_in_thin_cells() {
    // Factors 1 to 4 across the cloud: the GPU reads the CPU's per-cell factors and takes
    // the same groups of lattice steps.
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    p.max_step_factor = 4;
    p.spp = 2;
    let factors: Vec<u32> = nimbus_volume::MajorantGrid::build(&v).values().iter().filter(|&&m| m > 0.0).map(|&m| p.step_factor(m)).collect();
    assert!((1..=4).all(|f| factors.contains(&f)), "factors 1 to 4 occur");
    both_agree(ctx, "step factors up to 4, 2 spp", &v, &cache, &p);
}

#[test]
fn images_agree_with_offset_noise_and_jittered_samples() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    p.offset_noise = 0.15;
    p.spp = 3;
    // The baked field read at each sample (what the GPU marches) and the fBm at every
    // sample, each on both backends.
    p.noise_eval = NoiseEval::Baked { nodes: 4 };
    let baked = both_agree(ctx, "offset noise baked, 3 spp", &v, &cache, &p);
    let exact = both_agree(ctx, "offset noise exact, 3 spp", &v, &cache, &MarchParams { noise_eval: NoiseEval::Exact, ..p.clone() });
    // The noise really moved the samples, and the baked field moved them nearly as the
    // exact one does.
    let plain = render_cpu(&v, &cache, &MarchParams { offset_noise: 0.0, ..p.clone() }).unwrap();
    let (moved, apart) = (diff(&plain, &exact), diff(&baked, &exact));
    report("baked against exact", &apart);
    assert!(moved.rgb > 1e-2);
    assert!(apart.rgb < 0.25 * moved.rgb, "baked {} vs exact, noise moved {}", apart.rgb, moved.rgb);
    // The default, NoiseEval::Displaced, which the GPU marches as the above (the CPU's
    // displaced medium is held to the exact noise in the crate's offsets.rs).
    let gpu = render_gpu_with(ctx, &v, &cache, &MarchParams { noise_eval: NoiseEval::DEFAULT, ..p.clone() }, MediumFields::default(), &EXACT).unwrap();
    assert_close("offset noise, the default on the GPU", &diff(&baked, &gpu), 64 * 48);
}

#[test]
fn images_agree_far_from_the_origin() {
    // Positions relative to the eye and split noise positions keep f32 precise at 1e4.
    let Some(ctx) = gpu() else { return };
    let centre = DVec3::new(1.0e4, -2.5e3, 300.0);
    let (v, cache, mut p) = scene(centre);
    p.offset_noise = 0.1;
    // The offsets read at each sample, which both backends march.
    p.noise_eval = NoiseEval::Baked { nodes: 4 };
    let cpu = render_cpu(&v, &cache, &p).unwrap();
    let gpu = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
    let d = diff(&cpu, &gpu);
    report("far from the origin, offset noise", &d);
    // The CPU's own f64 world positions at 1e4 lose ~1e-12 relative; the GPU's eye-relative
    // f32 ones ~1e-7 of the ray length: a little more slack than near the origin.
    assert!(d.rgb <= 1e-3 && d.alpha <= 1e-4, "rgb {} alpha {}", d.rgb, d.alpha);
}

#[test]
fn early_termination_and_missing_cache_grids_agree() {
    let Some(ctx) = gpu() else { return };
    let (v, mut cache, mut p) = scene(DVec3::ZERO);
    p.medium.extinction = 8.0;
    p.min_transmittance = 0.02;
    cache.li_multiple = None;
    let cpu = render_cpu(&v, &cache, &p).unwrap();
    let gpu = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
    let d = diff(&cpu, &gpu);
    assert_close("dense, early termination, no Li_multiple", &d, 64 * 48);
    assert!(gpu.aovs.as_ref().unwrap().multiple.iter().all(|m| *m == Vec3::ZERO));
    assert!(gpu.aovs.as_ref().unwrap().transmittance.contains(&0.0), "some rays should stop early");
}

#[test]
fn hardware_filtered_cache_lookups_stay_close() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, p) = scene(DVec3::ZERO);
    let cpu = render_cpu(&v, &cache, &p).unwrap();
    let gpu = render_gpu(ctx, &v, &cache, &p).unwrap();
    let d = diff(&cpu, &gpu);
    report(&format!("filtered cache (hardware filtering: {})", ctx.float32_filterable()), &d);
    // Filter weights quantised to 1/256 of a texel: Li within ~1/256 of its local range,
    // which here is a fraction of its value. Density is still exact, so alpha is too.
    assert!(d.rgb <= 5e-3, "rgb {}", d.rgb);
    assert!(d.alpha <= 1e-5, "alpha {}", d.alpha);
}

#[test]
fn tiled_dispatches_equal_one_dispatch() {
    // Tiles of 1000 pixels start mid-row; every pixel keeps its own random stream.
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    p.spp = 2;
    let whole = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
    let tiled = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &GpuMarchOptions { max_tile_pixels: 1000, ..EXACT }).unwrap();
    assert_eq!(whole, tiled);
}

#[test]
fn an_empty_scene_is_the_background() {
    let Some(ctx) = gpu() else { return };
    let v = nimbus_volume::Volume::new(nimbus_volume::Transform::uniform(0.1, DVec3::ZERO), 0.0f32);
    let p = params(camera(DVec3::ZERO, 16, 8));
    let image = render_gpu(ctx, &v, &Default::default(), &p).unwrap();
    assert!(image.rgba.iter().all(|c| c.truncate() == p.background && c.w == 0.0));
    assert_eq!(image, render_cpu(&v, &Default::default(), &p).unwrap());
}

/// An environment map behind the volume: each sample's T L_env(dir) through
/// environment.wgsl on the GPU, as the CPU adds it (the same sample directions and
/// transmittance), and the uniform sky as the constant background.
#[test]
fn an_environment_behind_the_volume_renders_alike() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    let texels = (0..32 * 16).map(|i| if i % 32 == 9 && i / 32 == 5 { Vec3::new(9.0, 8.0, 7.0) } else { Vec3::new(0.1 + 0.02 * (i % 32) as f32, 0.3, 0.5 + 0.03 * (i / 32) as f32) }).collect();
    let map = nimbus_optics::EnvironmentMap::new(32, 16, texels).unwrap();
    p.spp = 4;
    for environment in [nimbus_optics::Environment::map(map, "test.exr", 2.0, 40.0).unwrap(), nimbus_optics::Environment::uniform(Vec3::new(0.2, 0.3, 0.6)).unwrap()] {
        p.environment = Some(environment);
        p.environment_visible = true;
        let cpu = render_cpu(&v, &cache, &p).unwrap();
        let gpu = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
        let worst = cpu.rgba.iter().zip(&gpu.rgba).map(|(c, g)| ((c.truncate() - g.truncate()).abs() / c.truncate().abs().max(Vec3::splat(1e-3))).max_element()).fold(0.0f32, f32::max);
        let clear = cpu.rgba.iter().filter(|c| c.w < 0.01).count();
        eprintln!("behind the volume: worst relative pixel difference {worst:.2e}, {clear} clear pixels");
        assert!(clear > 50, "the camera does not see past the cloud");
        assert!(worst < 2e-3, "{worst}");
    }
}

/// Runs `noise.wgsl` on the GPU: per point, perlin3 (seed 5), fbm3_vec (4 octaves, seed 9)
/// and the lattice hash of the point's cell.
fn gpu_noise(ctx: &GpuContext, points: &[[f32; 4]]) -> Vec<[f32; 4]> {
    let source = format!(
        "{NOISE_WGSL}
        @group(0) @binding(0) var<storage, read> points: array<vec4<f32>>;
        @group(0) @binding(1) var<storage, read_write> out: array<vec4<f32>>;
        @compute @workgroup_size(64)
        fn main(@builtin(global_invocation_id) id: vec3<u32>) {{
            let i = id.x;
            if (i >= arrayLength(&points)) {{ return; }}
            let p = points[i].xyz;
            let fl = floor(p);
            let cell = vec3<u32>(vec3<i32>(fl));
            out[2u * i] = vec4<f32>(noise_perlin3(p, 5u), bitcast<f32>(noise_lattice_hash(cell, 5u)), 0.0, 0.0);
            out[2u * i + 1u] = vec4<f32>(noise_fbm3_vec_split(cell, p - fl, 4u, 9u), 0.0);
        }}"
    );
    let layout = ctx.bind_group_layout("noise", &[storage_entry(0, true), storage_entry(1, false)]).unwrap();
    let pipeline = ctx.compute_pipeline("noise", &source, "main", &[&layout]).unwrap();
    let input = ctx.storage_buffer("points", points).unwrap();
    let output = ctx.storage_buffer_zeroed("noise", points.len() as u64 * 32).unwrap();
    let group = ctx.buffer_bind_group("noise", &layout, &[&input, &output]).unwrap();
    ctx.dispatch_1d("noise", &pipeline, &[&group], points.len() as u64, 64).unwrap();
    ctx.read_buffer(&output).unwrap()
}

/// The CPU's hash, restated (nimbus_optics::noise keeps it private): the GPU must match it
/// bit for bit.
fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

#[test]
fn wgsl_noise_matches_the_cpu() {
    let Some(ctx) = gpu() else { return };
    // Points on a jittered grid over negative and positive cells.
    let points: Vec<[f32; 4]> = (0..4096)
        .map(|i| {
            let f = i as f32;
            [(f * 0.137).rem_euclid(13.0) - 6.5, (f * 0.0731).rem_euclid(9.0) - 4.0, (f * 0.311).rem_euclid(17.0) - 8.25, 0.0]
        })
        .collect();
    let out = gpu_noise(ctx, &points);
    let (mut worst_perlin, mut worst_fbm) = (0.0f32, 0.0f32);
    for (i, p) in points.iter().enumerate() {
        let pd = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let cell = pd.floor();
        let (x, y, z) = (cell.x as i64 as u32, cell.y as i64 as u32, cell.z as i64 as u32);
        let hash = pcg(x ^ pcg(y ^ pcg(z ^ pcg(5))));
        assert_eq!(out[2 * i][1].to_bits(), hash, "lattice hash at {pd}");
        worst_perlin = worst_perlin.max((out[2 * i][0] - perlin3(pd, 5)).abs());
        let g = Vec3::new(out[2 * i + 1][0], out[2 * i + 1][1], out[2 * i + 1][2]);
        worst_fbm = worst_fbm.max((g - fbm3_vec(pd, 4, 9)).abs().max_element());
    }
    eprintln!("noise.wgsl vs CPU over {} points: hashes bit-exact, max |perlin| diff {worst_perlin:e}, max |fbm3_vec| diff {worst_fbm:e}", points.len());
    assert!(worst_perlin < 2e-6 && worst_fbm < 2e-6, "perlin {worst_perlin}, fbm {worst_fbm}");
}

#[test]
fn marches_longer_than_a_software_adapter_takes_are_refused() {
    // llvmpipe (lavapipe) silently ends a loop after 65535 iterations per invocation: a
    // 100k-step ray came back as background. Within the limit the ray is whole; past it a
    // software adapter refuses with a clear error instead of a wrong image.
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    p.camera = nimbus_optics::Camera::new(DVec3::new(0.0, -5.0, 0.0), DVec3::ZERO, DVec3::Z, 1.0, 1, 1).unwrap();
    p.step = 3.2 / 4_000.0;
    let cpu = render_cpu(&v, &cache, &p).unwrap();
    let gpu = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
    assert!((cpu.rgba[0] - gpu.rgba[0]).abs().max_element() <= 1e-3 * cpu.rgba[0].max_element(), "{} vs {}", cpu.rgba[0], gpu.rgba[0]);
    p.step = 3.2 / 100_000.0;
    match render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT) {
        Err(e) if ctx.info.is_software => assert!(e.to_string().contains("--device cpu"), "{e}"),
        Err(e) => panic!("a hardware adapter should take it: {e}"),
        Ok(image) => {
            assert!(!ctx.info.is_software, "a software adapter should refuse");
            let cpu = render_cpu(&v, &cache, &p).unwrap();
            assert!((cpu.rgba[0] - image.rgba[0]).abs().max_element() <= 1e-3 * cpu.rgba[0].max_element());
        }
    }
}

/// The medium's emission (emission.wgsl): both terms, the emission grid on its own lattice
/// and the blackbody from a temperature grid, added along the camera ray as the CPU adds
/// them; agreement to f32 rounding of the same samples.
///
/// Except where a sample falls on the density's support: the medium emits only where its
/// density is above 0 (design.md section 5), and as the density falls to 0 a sample's
/// e (1 - exp(-sigma_t dt)) / sigma_t tends to e dt, not to 0, so a position that rounds
/// into the support on one backend and out of it on the other moves its pixel by one
/// sample. Measured on the CPU alone: moving the eye by 1e-5 of its distance moved one
/// pixel's emission 3%, by 1e-6 none beyond 2e-4; a CI machine's lavapipe met one such
/// sample (a 1.2% pixel). So a few pixels may differ, each by at most one sample's emission.
#[test]
fn emission_along_camera_rays_renders_alike() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    let (flame, temperature, emission) = common::fire(DVec3::ZERO);
    p.spp = 2;
    p.offset_noise = 0.05;
    for (name, emission) in [
        ("both terms", emission.clone()),
        ("grid term", nimbus_optics::Emission { temperature_grid: None, ..emission.clone() }),
        ("blackbody at B 1", nimbus_optics::Emission { grid: None, blackbody_intensity: 1.0, ..emission.clone() }),
    ] {
        let field = EmissionField { grid: Some(&flame), temperature: Some(&temperature), params: &emission };
        let cpu = render_cpu_with(&v, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }).unwrap();
        let gpu = render_gpu_with(ctx, &v, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }, &EXACT).unwrap();
        let (ce, ge) = (&cpu.aovs.as_ref().unwrap().emission, &gpu.aovs.as_ref().unwrap().emission);
        let brightest = ce.iter().map(|e| e.max_element()).fold(0.0, f32::max);
        let emitting = ce.iter().filter(|e| e.max_element() > 1e-3 * brightest).count();
        // One sample's emission at most: e dt / spp, with e bounded over the values its
        // trilinear lookups can take (each term's grid between its node extremes).
        let node_max = |v: &nimbus_volume::Volume<f32>| v.bricks().flat_map(|b| b.values.iter().copied()).fold(0.0f32, f32::max);
        let grid_max = if emission.grid.is_some() { node_max(&flame) } else { 0.0 };
        let t_max = if emission.temperature_grid.is_some() { node_max(&temperature) } else { 0.0 };
        let blackbody_max = (0..=1000).map(|k| emission.emitted(0.0, t_max * k as f32 / 1000.0).max_element()).fold(0.0f32, f32::max);
        let one_sample = (emission.emitted(grid_max, 0.0).max_element() + blackbody_max) * (p.step / p.spp as f64) as f32;
        let (mut worst, mut flips, mut worst_flip) = (0.0f32, 0, 0.0f32);
        for (i, (c, g)) in ce.iter().zip(ge).enumerate() {
            let d = rel(*g, *c, 1e-3 * brightest).max(rel(gpu.rgba[i].truncate(), cpu.rgba[i].truncate(), 1e-3 * brightest));
            if d < 2e-4 {
                worst = worst.max(d);
            } else {
                flips += 1;
                worst_flip = worst_flip.max((*g - *c).abs().max_element());
            }
        }
        eprintln!("emission, {name}: {emitting} emitting pixels, brightest {brightest:.3e}; worst relative difference {worst:.2e}; {flips} pixels beyond 2e-4, by at most {worst_flip:.2e} (one sample: {one_sample:.2e})");
        assert!(emitting > 64 * 48 / 4, "{name}: the fire should fill a good part of the image ({emitting})");
        if !(flips <= 3 && worst_flip <= one_sample) {
            // Seen twice while the binary's tests shared the device side by side (127 pixels
            // by up to 3.5e-4; on CI 115 by up to 1.3e-3, the GPU's render changing 184 pixels
            // when repeated), never alone; tests now hold the device one at a time
            // (nimbus_gpu::test_context). Should it recur: render both again and say which
            // backend failed to repeat itself.
            let changed = |a: &Image, b: &Image| a.rgba.iter().zip(&b.rgba).filter(|(x, y)| x != y).count();
            let cpu_again = render_cpu_with(&v, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }).unwrap();
            let gpu_again = render_gpu_with(ctx, &v, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }, &EXACT).unwrap();
            panic!(
                "{name}: {flips} pixels differ, by up to {worst_flip} (one sample {one_sample}); rendered again, the CPU changed {} pixels and the GPU {}",
                changed(&cpu, &cpu_again),
                changed(&gpu, &gpu_again)
            );
        }
        // Without emission the GPU adds none.
        if name == "both terms" {
            let dark = render_gpu_with(ctx, &v, &cache, &p, MediumFields::default(), &EXACT).unwrap();
            assert!(dark.aovs.as_ref().unwrap().emission.iter().all(|e| *e == Vec3::ZERO));
        }
    }
}

/// Motion blur on both backends: each sample's time from the same stream, the lookups at
/// x - t v(x) with a velocity grid that varies (a swirl on its own lattice), over the same
/// dilated majorant, with emission and the cache: agreement to f32 rounding.
#[test]
fn motion_blur_renders_alike() {
    let Some(ctx) = gpu() else { return };
    let (v, cache, mut p) = scene(DVec3::ZERO);
    let (flame, temperature, emission) = common::fire(DVec3::ZERO);
    let field = EmissionField { grid: Some(&flame), temperature: Some(&temperature), params: &emission };
    let mut velocity = nimbus_volume::Volume::new(nimbus_volume::Transform::uniform(0.12, DVec3::new(0.03, 0.0, -0.05)), Vec3::new(0.5, 0.0, 0.0));
    for x in -14..14 {
        for y in -14..14 {
            for z in -14..14 {
                let c = glam::IVec3::new(x, y, z).as_vec3();
                velocity.set(glam::IVec3::new(x, y, z), Vec3::new(-c.y, c.x, 0.3 * c.z) * 0.15 + Vec3::new(0.5, 0.0, 0.0));
            }
        }
    }
    let blur = nimbus_march::MotionBlur { velocity: &velocity, shutter: 0.2 };
    p.spp = 4;
    let cpu = nimbus_march::render_cpu_with(&v, &cache, &p, MediumFields { emission: Some(&field), motion: Some(&blur), ..MediumFields::default() }).unwrap();
    let gpu = nimbus_march::render_gpu_with(ctx, &v, &cache, &p, MediumFields { emission: Some(&field), motion: Some(&blur), ..MediumFields::default() }, &EXACT).unwrap();
    let sharp = nimbus_march::render_cpu_with(&v, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }).unwrap();
    let brightest = cpu.rgba.iter().map(|c| c.truncate().max_element()).fold(0.0, f32::max);
    let worst = cpu.rgba.iter().zip(&gpu.rgba).map(|(c, g)| rel(g.truncate(), c.truncate(), 1e-3 * brightest)).fold(0.0f32, f32::max);
    let moved = cpu.rgba.iter().zip(&sharp.rgba).map(|(c, s)| rel(s.truncate(), c.truncate(), 1e-3 * brightest)).fold(0.0f32, f32::max);
    eprintln!("motion blur: worst relative difference GPU - CPU {worst:.2e}; blurred against sharp {moved:.2e}");
    assert!(moved > 0.1, "the blur changes the image ({moved})");
    assert!(worst < 5e-4, "{worst}");
}

