//! End-to-end emission (issue #19): an emitting, absorbing slab through vdbcache and
//! vdbmarch, piped as a user's shell pipes them, against its closed form; the fire grids'
//! recognition and `--no-emission`.


use glam::{DVec3, IVec3};
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};
use nimbus_volume::{Transform, Volume};

mod common;

use common::{exr_attribute, pipe_ok, rgba_of};

/// Unit value on voxels of 0.1 at z = 0..=7 (a density integral of exactly 8 voxels, 0.8,
/// through the trilinear face ramps), x and y in -24..=24.
fn slab() -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0);
    for x in -24..=24 {
        for y in -24..=24 {
            for z in 0..=7 {
                v.set(IVec3::new(x, y, z), 1.0);
            }
        }
    }
    v
}

/// A VDB with `density` and an emission-like grid `name` of the same shape, as bytes.
fn slab_vdb(name: &str, value: f32) -> Vec<u8> {
    let mut file = VdbFile::new();
    let density = slab();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume(name, &density.map(0.0, |v| v * value), GridClass::FogVolume).unwrap();
    file.to_bytes(&WriteOptions::default()).unwrap()
}

/// The camera: face-on from above, a 2-degree lens, so every ray crosses the slab within
/// 0.02% of its thickness.
const CAMERA: &[&str] = &["--eye", "0,0,3", "--look-at", "0,0,0.35", "--up", "0,1,0", "--fov", "2", "--width", "6", "--height", "6"];
/// Absorption only: albedo 0, extinction 3 (so sigma_a = 3).
const MEDIUM: &[&str] = &["--extinction", "3", "--albedo", "0"];




/// The worst relative error of the pixels' RGB against `expect`.
fn worst(pixels: &[[f32; 4]], expect: [f64; 3]) -> f64 {
    pixels.iter().flat_map(|p| (0..3).map(move |k| ((p[k] as f64 - expect[k]) / expect[k]).abs())).fold(0.0, f64::max)
}

/// S c / sigma_a (1 - exp(-sigma_a d)) with S = 2, c = (1, 0.5, 0.25), sigma_a = 3, d = 0.8.
fn closed_form() -> [f64; 3] {
    let l = 2.0 / 3.0 * (1.0 - (-3.0f64 * 0.8).exp());
    [l, 0.5 * l, 0.25 * l]
}

const EMIT: &[&str] = &["--emission-grid", "glow", "--emission-strength", "2", "--emission-color", "1,0.5,0.25"];

#[test]
fn an_emitting_absorbing_slab_renders_to_its_closed_form() {
    let vdb = slab_vdb("glow", 1.0);
    // vdbcache copies the emission grid through to vdbmarch.
    let cache = pipe_ok("vdbcache", &[CAMERA, MEDIUM].concat(), &vdb).stdout;
    let march = pipe_ok("vdbmarch", &[EMIT, &["-v", "--device", "cpu"]].concat(), &cache);
    let err = worst(&rgba_of(&march.stdout), closed_form());
    eprintln!("march: worst relative error {err:.2e}");
    // The step is a third of a voxel's diagonal (0.577 voxels): the march's emission
    // telescopes to (S c / sigma)(1 - T_march), so what remains is its transmittance error
    // over the faces' one-voxel ramps, measured 1e-4 to 1e-3; 0.5% leaves room.
    assert!(err < 5e-3, "march: {err}");
    let log = String::from_utf8_lossy(&march.stderr);
    assert!(log.contains("emission: grid=glow,strength=2,color=1,0.5,0.25"), "{log}");
    // The EXR records it, as the chain records its parameters.
    assert_eq!(exr_attribute(&march.stdout, "nimbus:emission").as_deref(), Some("grid=glow,strength=2,color=1,0.5,0.25"));

    // The reference path tracer: 36 pixels x 1024 paths, each first collision adding
    // S c / sigma with probability 0.909: the mean's relative standard deviation 0.16%.
    let reference = pipe_ok("vdbmarch", &[EMIT, MEDIUM, CAMERA, &["--reference", "--spp", "1024", "--device", "cpu"]].concat(), &vdb);
    let pixels = rgba_of(&reference.stdout);
    let n = pixels.len() as f32;
    let mean: Vec<f32> = (0..3).map(|k| pixels.iter().map(|p| p[k]).sum::<f32>() / n).collect();
    let rel = (0..3).map(|k| ((mean[k] as f64 - closed_form()[k]) / closed_form()[k]).abs()).fold(0.0, f64::max);
    eprintln!("reference: mean {mean:?} against {:?}: {rel:.2e}", closed_form());
    assert!(rel < 0.01, "reference: {rel}");

    // The GPU march (emission.wgsl) to its closed form too, and to the CPU's pixels.
    let gpu = pipe_ok("vdbmarch", &[EMIT, &["--device", "gpu"]].concat(), &cache);
    let (gpu_pixels, cpu_pixels) = (rgba_of(&gpu.stdout), rgba_of(&march.stdout));
    let gpu_err = worst(&gpu_pixels, closed_form());
    let apart = gpu_pixels.iter().zip(&cpu_pixels).flat_map(|(g, c)| (0..3).map(move |k| ((g[k] - c[k]) / c[k]).abs())).fold(0.0f32, f32::max);
    eprintln!("GPU march: worst relative error {gpu_err:.2e}, {apart:.2e} from the CPU's pixels");
    assert!(gpu_err < 5e-3 && apart < 1e-4, "GPU march: {gpu_err}, {apart} from the CPU");
}

#[test]
fn fire_grids_are_recognised_and_no_emission_turns_them_off() {
    // Blender's normalised temperature (max about 3): a blackbody at 1000 K a unit.
    let vdb = slab_vdb("temperature", 2.0);
    let cache = pipe_ok("vdbcache", &[CAMERA, MEDIUM].concat(), &vdb).stdout;
    let fire = pipe_ok("vdbmarch", &["-v", "--device", "cpu"], &cache);
    let log = String::from_utf8_lossy(&fire.stderr);
    assert!(log.contains("emission: recognised grid 'temperature'") && log.contains("1000 K per unit"), "{log}");
    // 2000 K inside at blackbody intensity 1: luminance sigma T^4 / pi * 1e-6 = 0.2888 a unit
    // length. T follows the faces' one-voxel ramps (T = 2000 g, g the trilinear profile), so
    // e / sigma_t ~ g^3 is not constant there: the closed form is integrated numerically
    // over the profile, L = integral e(z) exp(-3 integral g) dz.
    let pixels = rgba_of(&fire.stdout);
    let p = pixels[14];
    let luminance = |p: &[f32; 4]| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
    let lum = pixels.iter().map(luminance).sum::<f64>() / pixels.len() as f64;
    let spread = pixels.iter().map(|p| (luminance(p) / lum - 1.0).abs()).fold(0.0, f64::max);
    eprintln!("blackbody slab: pixels within {spread:.2e} of their mean");
    let profile = |z: f64| (z / 0.1 + 1.0).clamp(0.0, 1.0).min((8.0 - z / 0.1).clamp(0.0, 1.0));
    let (mut expect, mut depth, n) = (0.0, 0.0, 200_000);
    let dz = 1.0 / n as f64;
    for i in 0..n {
        let z = -0.1 + (i as f64 + 0.5) * dz;
        let g = profile(z);
        expect += 5.670373e-8 * (2000.0 * g).powi(4) / std::f64::consts::PI * 1e-6 * (-3.0 * (depth + 0.5 * g * dz)).exp() * dz;
        depth += g * dz;
    }
    eprintln!("blackbody slab: luminance {lum} against {expect}; rgb {p:?}");
    // The march's samples take T^4 at points of the ramps, not its mean over a step, each
    // pixel's lattice at its own random offset: pixels spread by a few percent at the
    // default step (a third of the voxel diagonal), their mean closer.
    assert!((lum / expect - 1.0).abs() < 0.01, "{lum} vs {expect}");
    assert!(p[0] > p[1] && p[1] > p[2], "a 2000 K blackbody is orange: {p:?}");

    assert_eq!(exr_attribute(&fire.stdout, "nimbus:emission").as_deref(), Some("temperature=temperature,scale=1000,blackbody=1"));
    let off = pipe_ok("vdbmarch", &["--no-emission", "--device", "cpu"], &cache);
    assert_eq!(exr_attribute(&off.stdout, "nimbus:emission").as_deref(), Some("none"));
    assert!(rgba_of(&off.stdout).iter().all(|p| p[0] == 0.0 && p[1] == 0.0 && p[2] == 0.0));

    // Houdini's or Blender's flame without a temperature grid: the emission grid term.
    let flame = pipe_ok("vdbmarch", &["-v", "--device", "cpu"], &pipe_ok("vdbcache", &[CAMERA, MEDIUM].concat(), &slab_vdb("flame", 1.0)).stdout);
    let log = String::from_utf8_lossy(&flame.stderr);
    assert!(log.contains("emission: recognised grid 'flame'"), "{log}");
    assert!(rgba_of(&flame.stdout)[14][0] > 0.0);
}

/// The slab with `density` and the grids `(name, value)` of its shape.
fn slab_with(grids: &[(&str, f32)]) -> Vec<u8> {
    let mut file = VdbFile::new();
    let density = slab();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    for &(name, value) in grids {
        file.insert_volume(name, &density.map(0.0, |v| v * value), GridClass::FogVolume).unwrap();
    }
    file.to_bytes(&WriteOptions::default()).unwrap()
}

/// A Blender Mantaflow fire renders from its flame, as Blender's domain does: temperature
/// 1.5 + 1.5 flame (units of 1000 K) where flame > 0.01, the file's `temperature` (the heat)
/// unused; so flame 0.5 renders as a 2250 K blackbody, exactly as a normalised temperature
/// grid of 2.25. With Houdini's `vel` beside them, the temperature grid is the fire.
#[test]
fn a_blender_fire_renders_from_its_flame() {
    let march = |vdb: &[u8]| pipe_ok("vdbmarch", &["-v", "--device", "cpu"], &pipe_ok("vdbcache", &[CAMERA, MEDIUM].concat(), vdb).stdout);
    let blender = march(&slab_with(&[("flame", 0.5), ("temperature", 2.0)]));
    let log = String::from_utf8_lossy(&blender.stderr);
    assert!(log.contains("recognised a Blender Mantaflow fire") && log.contains("(1500 to 3000 K)"), "{log}");
    let same = march(&slab_with(&[("temperature", 2.25)]));
    assert_eq!(rgba_of(&blender.stdout), rgba_of(&same.stdout), "flame 0.5 is not a 2250 K blackbody");
    assert_eq!(exr_attribute(&blender.stdout, "nimbus:emission").as_deref(), Some("temperature=flame->temperature,scale=1000,blackbody=1"));
    let houdini = march(&slab_with(&[("flame", 0.5), ("temperature", 2.0), ("vel", 0.0)]));
    assert!(String::from_utf8_lossy(&houdini.stderr).contains("recognised grid 'temperature'"));
    let heat = march(&slab_with(&[("temperature", 2.0)]));
    assert_eq!(rgba_of(&houdini.stdout), rgba_of(&heat.stdout));
}

/// A cube of 12^3 voxels of 0.1 whose central 4^3 voxels glow, as a VDB: `density` and
/// `glow`.
fn glowing_cube_vdb() -> Vec<u8> {
    let mut density = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0);
    let mut glow = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0);
    for x in 0..12 {
        for y in 0..12 {
            for z in 0..12 {
                density.set(IVec3::new(x, y, z), 1.0);
                if [x, y, z].iter().all(|c| (4..8).contains(c)) {
                    glow.set(IVec3::new(x, y, z), 1.0);
                }
            }
        }
    }
    let mut file = VdbFile::new();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume("glow", &glow, GridClass::FogVolume).unwrap();
    file.to_bytes(&WriteOptions::default()).unwrap()
}

/// The scattering medium around the glow (optical depth 0.5 a voxel, 6 across, albedo 0.9),
/// lit by nothing else (a sun of irradiance 0), seen from -Y. Not thicker a voxel: the cache's
/// trilinear lattice cannot hold light that varies within a voxel (at optical depth 2 a voxel
/// the chain's sun-lit single scattering alone came out 3.4 times the reference's).
const GLOWING: &[&str] = &[
    "--extinction", "5", "--albedo", "0.9", "--sun", "dir=0,0,-1,irradiance=0",
    "--eye", "0.55,-3,0.55", "--look-at", "0.55,0.55,0.55", "--up", "0,0,1", "--fov", "30", "--width", "24", "--height", "24",
];

fn mean_rgb(exr: &[u8]) -> [f64; 3] {
    let pixels = rgba_of(exr);
    let n = pixels.len() as f64;
    [0, 1, 2].map(|k| pixels.iter().map(|p| p[k] as f64).sum::<f64>() / n)
}

/// A fire lights its own smoke through the chain: vdbcache's paths gather the glow's light
/// the medium scatters, vdbmarch adds the glow itself along camera rays, and the image's mean
/// is the reference path tracer's (which gathers both at every collision). Without the
/// scattered emission in the cache the chain is far darker, so the test can fail; and the
/// cache records what its Li holds, which vdbmarch says.
#[test]
fn a_glowing_cube_lights_its_own_smoke_through_the_chain() {
    let vdb = glowing_cube_vdb();
    let emit: &[&str] = &["--emission-grid", "glow", "--emission-strength", "20"];
    // The preset's paths alone (no top-up to the image's noise): the bounds below were
    // measured at them, and the GPU's lavapipe keeps to the test's time.
    let first_pass: &[&str] = &["--path-tolerance", "0"];
    let cache = pipe_ok("vdbcache", &[GLOWING, emit, first_pass].concat(), &vdb);
    assert!(VdbFile::from_bytes(&cache.stdout, "cache").unwrap().metadata().get("nimbus:emission").and_then(|v| v.as_str()) == Some("grid=glow,strength=20,color=1,1,1"));
    let march = pipe_ok("vdbmarch", &[emit, &["-v"]].concat(), &cache.stdout);
    let log = String::from_utf8_lossy(&march.stderr);
    assert!(log.contains("its light scattered by the medium is in the cache"), "{log}");
    let chain = mean_rgb(&march.stdout);

    let dark_cache = pipe_ok("vdbcache", &[GLOWING, &["--no-emission"], first_pass].concat(), &vdb).stdout;
    let dark = pipe_ok("vdbmarch", &[emit, &["-v"]].concat(), &dark_cache);
    assert!(String::from_utf8_lossy(&dark.stderr).contains("is not in the cache"));
    let unscattered = mean_rgb(&dark.stdout);

    // 576 pixels x 2048 paths: the mean's seeds spread by about 0.7% (1.4% at 512, measured).
    let reference = mean_rgb(&pipe_ok("vdbmarch", &[GLOWING, emit, &["--reference", "--spp", "2048"]].concat(), &vdb).stdout);
    let ratio = chain[0] / reference[0];
    eprintln!("glowing cube: chain {chain:?}, without scattered emission {unscattered:?}, reference {reference:?}: chain / reference {ratio:.4}");
    assert!((ratio - 1.0).abs() < 0.03, "chain / reference {ratio}");
    // The glow lies behind optical depth 2 from the camera: most of what it sees is the
    // glow's light scattered (the cache without it gave a tenth of the reference).
    assert!(unscattered[0] < 0.3 * reference[0], "the scattered emission is a large share: {unscattered:?} against {reference:?}");

    // The GPU cache's paths gather the same emission as the CPU's on the same lattice (the
    // same streams: means within 1%), and the GPU march adds the same glow. On the first,
    // unrefined lattice (two voxels): the defaults refine it to 0.53 voxels here, 4.4M paths,
    // 9 s on the CPU and minutes on lavapipe, and the refinement is one code for both
    // backends (nimbus_cache::budget).
    let lattice: &[&str] = &["--multiple-scale", "2"];
    let cpu_cache = pipe_ok("vdbcache", &[GLOWING, emit, first_pass, lattice].concat(), &vdb).stdout;
    let cpu_chain = mean_rgb(&pipe_ok("vdbmarch", emit, &cpu_cache).stdout);
    let gpu_cache = pipe_ok("vdbcache", &[GLOWING, emit, first_pass, lattice, &["--device", "gpu"]].concat(), &vdb).stdout;
    let gpu_chain = mean_rgb(&pipe_ok("vdbmarch", &[emit, &["--device", "gpu"]].concat(), &gpu_cache).stdout);
    let apart = gpu_chain[0] / cpu_chain[0] - 1.0;
    eprintln!("glowing cube on the GPU, Li_multiple at two voxels: chain {gpu_chain:?} ({apart:+.2e} from the CPU's {cpu_chain:?})");
    assert!(apart.abs() < 0.01, "GPU chain {gpu_chain:?} against the CPU's {cpu_chain:?}");
    assert!(gpu_chain[0] > 1.5 * unscattered[0], "the GPU's paths gather the glow: {gpu_chain:?} against {unscattered:?} without it");
}

/// vdbphoton with an emitting volume and no light (a sun of irradiance 0): the photons leave
/// the glow, stored from their first interaction on, and carry its power. Optical depth 200 a
/// voxel and one interaction a path: almost every photon is stored once, with albedo 0.5 x
/// its share of 4 pi integral e dV = 4 pi x 20 x 64 voxels x 0.001.
#[test]
fn vdbphoton_traces_photons_from_an_emitting_volume_without_lights() {
    let vdb = glowing_cube_vdb();
    let args: &[&str] = &[
        "--extinction", "2000", "--albedo", "0.5", "--sun", "dir=0,0,-1,irradiance=0", "--photons", "20000", "--max-interactions", "1",
        "--emission-grid", "glow", "--emission-strength", "20",
    ];
    let out = pipe_ok("vdbphoton", args, &vdb);
    let file = VdbFile::from_bytes(&out.stdout, "photons").unwrap();
    let meta = file.metadata();
    assert_eq!(meta.get("nimbus:emission").and_then(|v| v.as_str()), Some("grid=glow,strength=20,color=1,1,1"));
    let points = file.read_points("photons").unwrap();
    assert_eq!(points.positions.len(), 20_000);
    let record = meta.get("nimbus:vdbphoton").and_then(|v| v.as_str()).unwrap().to_string();
    let emitted: f64 = record.split(',').find_map(|kv| kv.strip_prefix("emitted=")).unwrap().parse().unwrap();
    let total: f64 = points.vec3("power").unwrap().iter().map(|p| p.x as f64).sum::<f64>() * emitted / 20_000.0;
    let expected = 0.5 * 4.0 * std::f64::consts::PI * 20.0 * 64.0 * 1e-3;
    eprintln!("photons from the glow: power {total} against {expected}");
    assert!((total / expected - 1.0).abs() < 0.02, "{total} against {expected}");

    // The GPU photon tracer: the same photons from the glow, the same power.
    let gpu = VdbFile::from_bytes(&pipe_ok("vdbphoton", &[args, &["--device", "gpu"]].concat(), &vdb).stdout, "photons").unwrap();
    let gpu_record = gpu.metadata().get("nimbus:vdbphoton").and_then(|v| v.as_str()).unwrap().to_string();
    let gpu_emitted: f64 = gpu_record.split(',').find_map(|kv| kv.strip_prefix("emitted=")).unwrap().parse().unwrap();
    let gpu_points = gpu.read_points("photons").unwrap();
    assert_eq!(gpu_points.positions.len(), 20_000);
    let gpu_total: f64 = gpu_points.vec3("power").unwrap().iter().map(|p| p.x as f64).sum::<f64>() * gpu_emitted / 20_000.0;
    eprintln!("GPU photons from the glow: power {gpu_total} against {expected}");
    assert!((gpu_total / total - 1.0).abs() < 1e-3, "GPU {gpu_total} against the CPU's {total}");
}

/// Emission-absorption along a camera ray, deterministically: `e = S c flame(x)` where the
/// density is positive, `sigma_t = density(x)` (extinction 1, albedo 0), midpoint steps of
/// `dt` world units, both grids read trilinearly in their own index spaces (OpenVDB's
/// BoxSampler, design.md section 2). Written here from the design's meaning, not from the
/// march's code.
fn emission_absorption(density: &Volume<f32>, flame: &Volume<f32>, s: f64, color: [f64; 3], eye: DVec3, dir: DVec3, t_max: f64, dt: f64) -> [f64; 3] {
    let (mut l, mut depth) = ([0.0; 3], 0.0);
    let mut t = 0.5 * dt;
    while t < t_max {
        let x = eye + dir * t;
        let rho = density.sample_world(x).max(0.0) as f64;
        if rho > 0.0 {
            let tr = (-(depth + 0.5 * rho * dt)).exp();
            let e = s * flame.sample_world(x) as f64;
            for k in 0..3 {
                l[k] += tr * e * color[k] * dt;
            }
            depth += rho * dt;
        }
        t += dt;
    }
    l
}

/// A Mantaflow fire file (data/fire.vdb: `density`, `flame` and Mantaflow's `temperature`),
/// rendered with explicit emission flags, no lights and albedo 0 through the chain as a user
/// pipes it: the explicit flags win over the recognition of the fire, and the image is the
/// deterministic emission-absorption march of those flags (issue #30: it rendered at 0.36 of
/// that mean).
#[test]
fn explicit_emission_flags_win_over_a_recognised_fire() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fire.vdb");
    let vdb = std::fs::read(&path).unwrap();
    let file = VdbFile::open(&path).unwrap();
    let density = file.read_float("density").unwrap();
    let flame = file.read_float("flame").unwrap();
    // Framed on the flame, which fills most of a 32 x 48 image.
    let (lo, hi) = flame.world_bounds().unwrap();
    let centre = 0.5 * (lo + hi);
    let distance = 4.0 * (hi - lo).max_element();
    let eye = centre - DVec3::new(0.0, distance, 0.0);
    let (w, h) = (32u32, 48u32);
    let fov = (2.0 * (0.55 * (hi.z - lo.z) * w as f64 / h as f64 / distance).atan()).to_degrees();
    let eye_s = format!("{},{},{}", eye.x, eye.y, eye.z);
    let look_s = format!("{},{},{}", centre.x, centre.y, centre.z);
    let (ws, hs, fovs) = (w.to_string(), h.to_string(), fov.to_string());
    let camera: &[&str] = &["--eye", &eye_s, "--look-at", &look_s, "--up", "0,0,1", "--fov", &fovs, "--width", &ws, "--height", &hs];
    let flags: &[&str] = &["--emission-grid", "flame", "--emission-strength", "5", "--emission-color", "1,0.5,0.2"];
    let no_light: &[&str] = &["--albedo", "0", "--sky", "0,0,0"];

    // The flags on vdbcache alone (issue #47: they travel in the cache's record to vdbmarch,
    // whose own recognition of the Mantaflow fire must not override them).
    let cache = pipe_ok("vdbcache", &[camera, no_light, flags, &["--device", "cpu"]].concat(), &vdb);
    let march = pipe_ok("vdbmarch", &["-v", "--device", "cpu", "--spp", "16"], &cache.stdout);
    let log = String::from_utf8_lossy(&march.stderr);
    assert!(!log.contains("recognised"), "explicit flags lost to the recognition: {log}");
    assert!(log.contains("emission: grid=flame,strength=5,color=1,0.5,0.2 (the input's record)"), "-v names the record as the source: {log}");
    assert_eq!(exr_attribute(&march.stdout, "nimbus:emission").as_deref(), Some("grid=flame,strength=5,color=1,0.5,0.2"));
    let pixels = rgba_of(&march.stdout);

    // The same camera's rays through pixel centres of a 4 x 4 grid per pixel.
    let forward = (centre - eye).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let up = right.cross(forward);
    let tan_x = (0.5 * fov).to_radians().tan();
    let tan_y = tan_x * h as f64 / w as f64;
    let t_max = 2.0 * distance;
    let dt = 0.05 * density.transform().voxel_size().min_element();
    let mut expect = vec![[0.0f64; 3]; (w * h) as usize];
    for py in 0..h {
        for px in 0..w {
            let expect = &mut expect[(py * w + px) as usize];
            for sy in 0..4 {
                for sx in 0..4 {
                    let u = (px as f64 + (sx as f64 + 0.5) / 4.0) / w as f64 * 2.0 - 1.0;
                    let v = 1.0 - (py as f64 + (sy as f64 + 0.5) / 4.0) / h as f64 * 2.0;
                    let dir = (forward + right * (u * tan_x) + up * (v * tan_y)).normalize();
                    let l = emission_absorption(&density, &flame, 5.0, [1.0, 0.5, 0.2], eye, dir, t_max, dt);
                    for k in 0..3 {
                        expect[k] += l[k] / 16.0;
                    }
                }
            }
        }
    }
    // Scored as nimbus-bench scores: 2x2 blocks, over blocks the reference sees glowing.
    let block = |img: &dyn Fn(usize) -> [f64; 3], bx: u32, by: u32| {
        let mut sum = [0.0; 3];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let p = img(((2 * by + dy) * w + 2 * bx + dx) as usize);
            (0..3).for_each(|k| sum[k] += 0.25 * p[k]);
        }
        sum
    };
    let peak = expect.iter().map(|p| p[0]).fold(0.0, f64::max);
    let (mut err2, mut sum_ref, mut sum_march, mut covered, mut n) = (0.0, 0.0, 0.0, 0.0, 0usize);
    for by in 0..h / 2 {
        for bx in 0..w / 2 {
            let want = block(&|i| expect[i], bx, by);
            let got = block(&|i| pixels[i].map(f64::from)[..3].try_into().unwrap(), bx, by);
            sum_march += got.iter().sum::<f64>();
            sum_ref += want.iter().sum::<f64>();
            if want[0] > 0.01 * peak {
                err2 += (0..3).map(|k| (got[k] - want[k]).powi(2)).sum::<f64>();
                covered += want.iter().sum::<f64>();
                n += 3;
            }
        }
    }
    let mean_ratio = sum_march / sum_ref;
    let rel_rmse = (err2 / n as f64).sqrt() / (covered / n as f64);
    eprintln!("explicit flags on a Mantaflow fire: mean ratio {mean_ratio:.4}, relative RMSE {rel_rmse:.4}");
    assert!((mean_ratio - 1.0).abs() < 0.01, "mean ratio {mean_ratio}");
    assert!(rel_rmse < 0.05, "relative RMSE {rel_rmse}");
}
