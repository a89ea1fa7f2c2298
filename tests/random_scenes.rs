//! End-to-end on scenes drawn at random (issue #47; `nimbus_bench::random`, what
//! `scripts/bench_random.sh` runs at full size): a few fixed seeds, small, through the chain at
//! its defaults (`vdbcache | vdbmarch`) against the path-traced reference (`vdbmarch
//! --reference`). The bound is loose, for the reference's noise at a few hundred paths a
//! pixel on a tiny image, but a chain that gets the medium wrong (its albedo 0.7 times the
//! scene's) must fail it: the test checks that too, so the bound can catch something.

use std::path::Path;
use std::process::Command;

mod common;

use common::{bin, read_rgba, run};
use nimbus_bench::random::{self, Options};
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};

/// The first seeds of the counter 1, 2, ... whose chain bakes in seconds at this size (3 took
/// 42 CPU s: Li_single refined to a quarter voxel), not picked for their scenes: a layer and
/// two lumps, sky, suns behind the camera and overhead, tau per voxel 0.06 to 10.
const SEEDS: [u64; 3] = [1, 2, 4];
/// Relative RMSE (2x2 blocks, covered pixels) the chain must stay under, against a reference
/// whose own noise here is a few per cent.
const BOUND: f64 = 0.12;
const REFERENCE_SPP: &str = "256";

/// Relative RMSE of `image` against `reference` after 2x2 block means, over the blocks the
/// reference covers (alpha > 0.01), as nimbus-compare scores; and the covered blocks.
fn relative_rmse(image: &[[f32; 4]], reference: &[[f32; 4]], width: usize, height: usize) -> (f64, usize) {
    let block = |img: &[[f32; 4]], x: usize, y: usize| {
        let mut s = [0.0f64; 4];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let p = img[(2 * y + dy) * width + 2 * x + dx];
            for c in 0..4 {
                s[c] += 0.25 * p[c] as f64;
            }
        }
        s
    };
    let (mut sq, mut level, mut n) = (0.0, 0.0, 0usize);
    for y in 0..height / 2 {
        for x in 0..width / 2 {
            let (a, r) = (block(image, x, y), block(reference, x, y));
            if r[3] > 0.01 {
                sq += (0..3).map(|c| (a[c] - r[c]).powi(2)).sum::<f64>() / 3.0;
                level += (r[0] + r[1] + r[2]) / 3.0;
                n += 1;
            }
        }
    }
    ((sq / n.max(1) as f64).sqrt() / (level / n.max(1) as f64), n)
}

/// The scene's flags with `--albedo` scaled by `factor`.
fn scale_albedo(medium: &[String], factor: f64) -> Vec<String> {
    let mut out = medium.to_vec();
    if let Some(i) = out.iter().position(|w| w == "--albedo") {
        out[i + 1] = out[i + 1].split(',').map(|a| format!("{}", a.parse::<f64>().unwrap() * factor)).collect::<Vec<_>>().join(",");
    }
    out
}

/// The emission flags of the scene's first line, which vdbmarch is also given (they travel
/// through the cache's record as well; given again they mean the same).
fn emission_flags(medium: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for (i, w) in medium.iter().enumerate() {
        if w.starts_with("--emission-") {
            out.push(w.clone());
            out.push(medium[i + 1].clone());
        }
    }
    out
}

fn chain(dir: &Path, name: &str, scene: &Path, medium: &[String], camera: &[String], emission: &[String]) -> Vec<[f32; 4]> {
    let (cache, image) = (dir.join(format!("{name}.vdb")), dir.join(format!("{name}.exr")));
    run(Command::new(bin("vdbcache")).arg(scene).args(medium).args(camera).arg("-q").arg("-o").arg(&cache));
    run(Command::new(bin("vdbmarch")).arg(&cache).args(emission).arg("-q").arg("-o").arg(&image));
    read_rgba(&image)
}

#[test]
fn random_scenes_match_the_reference_and_a_wrong_albedo_does_not() {
    let dir = common::scratch("random", "scenes");
    // A tenth of the drawn voxels and 32x24 pixels at most: seconds a seed.
    let options = Options { max_pixels: 32 * 24, voxel_scale: 0.1 };
    for seed in SEEDS {
        let r = random::scene(seed, options).unwrap();
        let what = r.draw.describe();
        eprintln!("{what}");
        let scene = dir.join(format!("{seed}.vdb"));
        let mut file = VdbFile::new();
        file.insert_volume("density", &r.scene.density, GridClass::FogVolume).unwrap();
        if let Some(e) = &r.emission {
            file.insert_volume(random::EMISSION_GRID, e, GridClass::FogVolume).unwrap();
        }
        file.write(&scene, &WriteOptions::default()).unwrap();
        let emission = emission_flags(&r.scene.medium);
        let image = chain(&dir, &format!("{seed}-chain"), &scene, &r.scene.medium, &r.scene.camera, &emission);
        let reference = dir.join(format!("{seed}-reference.exr"));
        run(Command::new(bin("vdbmarch")).arg(dir.join(format!("{seed}-chain.vdb"))).args(&emission).args(["--reference", "--spp", REFERENCE_SPP, "--seed", "101", "-q", "-o"]).arg(&reference));
        let reference = read_rgba(&reference);
        let (w, h) = (r.draw.width as usize, r.draw.height as usize);
        assert_eq!(image.len(), w * h, "{what}: the image has the drawn size");
        assert!(image.iter().chain(&reference).all(|p| p.iter().all(|v| v.is_finite() && *v >= 0.0)), "{what}: non-finite or negative pixels");
        let (err, covered) = relative_rmse(&image, &reference, w, h);
        eprintln!("  chain against the reference: {:.2}% over {covered} blocks", 100.0 * err);
        assert!(covered >= 4, "{what}: the volume covers {covered} 2x2 blocks");
        assert!(err < BOUND, "{what}: the chain is {:.2}% off the reference (bound {:.0}%)", 100.0 * err, 100.0 * BOUND);

        // The same chain with the wrong albedo: the bound must catch it.
        let wrong = chain(&dir, &format!("{seed}-wrong"), &scene, &scale_albedo(&r.scene.medium, 0.7), &r.scene.camera, &emission);
        let (wrong_err, _) = relative_rmse(&wrong, &reference, w, h);
        eprintln!("  with albedo x 0.7: {:.2}%", 100.0 * wrong_err);
        assert!(wrong_err > BOUND, "{what}: a chain with albedo x 0.7 is only {:.2}% off: the bound catches nothing", 100.0 * wrong_err);
    }
}

/// A generated thin shell lit from behind (seed 20261207009 of the date counter, failing
/// the bench's 0.5% on single scattering by 1.85% with Li_single refined to a quarter
/// voxel): vdbcache finds that no lattice would do and says so, and vdbmarch then traces
/// single scattering's shadow rays at its samples by itself (issue #47), as `--single
/// direct` does, which the cache's lattice does not.
#[test]
fn a_rim_no_lattice_serves_is_marched_by_shadow_rays() {
    let dir = common::scratch("random", "rim");
    let r = random::scene(20261207009, Options { max_pixels: 40 * 24, voxel_scale: 0.3 }).unwrap();
    eprintln!("{}", r.draw.describe());
    let scene = dir.join("rim.vdb");
    let mut file = VdbFile::new();
    file.insert_volume("density", &r.scene.density, GridClass::FogVolume).unwrap();
    file.write(&scene, &WriteOptions::default()).unwrap();
    let cache = dir.join("rim-cache.vdb");
    let bake = run(Command::new(bin("vdbcache")).arg(&scene).args(&r.scene.medium).args(&r.scene.camera).args(["--no-multiple", "-o"]).arg(&cache));
    let said = String::from_utf8_lossy(&bake.stderr);
    assert!(said.contains("vdbmarch will trace single scattering's shadow rays"), "{said}");
    let march = |flags: &[&str], name: &str| {
        let image = dir.join(name);
        let out = run(Command::new(bin("vdbmarch")).arg(&cache).args(flags).args(["--device", "cpu", "-v", "-o"]).arg(&image));
        (std::fs::read(&image).unwrap(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (auto, log) = march(&[], "auto.exr");
    assert!(log.contains("single scattering: shadow rays toward the lights at every sample"), "{log}");
    let (direct, _) = march(&["--single", "direct"], "direct.exr");
    let (_, log) = march(&["--single", "cache"], "cache.exr");
    assert!(!log.contains("shadow rays"), "{log}");
    assert!(auto == direct, "auto takes the shadow rays the cache asks for");
    let (a, c) = (read_rgba(&dir.join("auto.exr")), read_rgba(&dir.join("cache.exr")));
    let (err, covered) = relative_rmse(&c, &a, r.draw.width as usize, r.draw.height as usize);
    eprintln!("the unrefined lattice against the shadow rays: {:.2}% over {covered} blocks", 100.0 * err);
    assert!(covered >= 4 && err > 0.02, "the lattice left unrefined misses the rim: {err}");
}
