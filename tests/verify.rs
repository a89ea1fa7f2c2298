//! `vdbmarch --verify` end to end (issue #47): a small ball baked and marched, the image's
//! error reported in the EXR header against the reference tracer, a cache baked for the
//! wrong medium reported far off, and the bad combinations refused.

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{bin, exr_attribute, run, SUN};

fn scratch(name: &str) -> PathBuf {
    common::scratch("verify", name)
}

const CAMERA: &[&str] = &["--eye", "0,-6,1", "--look-at", "0,0,0", "--width", "32", "--height", "24"];
// Optical depth about 7 across the ball: its multiple scattering is most of its light.
const MEDIUM: &[&str] = &["--extinction", "0.005", "--g", "0.3"];

/// The ball's density, and its cache baked with `albedo` (the rest of the medium as MEDIUM).
fn bake(dir: &Path, albedo: &str) -> PathBuf {
    let (ply, d, c) = (dir.join("ball.ply"), dir.join("d.vdb"), dir.join(format!("c{albedo}.vdb")));
    if !d.exists() {
        common::write_ball(&ply, 3000, 0.0);
        run(Command::new(bin("particles2vdb")).arg(&ply).args(["--resolution", "16", "--neighbours", "16", "-o"]).arg(&d));
    }
    run(Command::new(bin("vdbcache")).arg(&d).args(MEDIUM).args(["--albedo", albedo, "--sun", SUN]).args(CAMERA).args(["--seed", "3", "-o"]).arg(&c));
    c
}

/// `nimbus:verify`'s fields, each checked to be a number.
fn fields(text: &str) -> Vec<(String, f64)> {
    text.split(',')
        .map(|kv| {
            let (k, v) = kv.split_once('=').unwrap_or_else(|| panic!("'{kv}' in '{text}' is not key=value"));
            (k.to_string(), v.parse::<f64>().unwrap_or_else(|_| panic!("'{v}' in '{text}' is not a number")))
        })
        .collect()
}

fn field(fields: &[(String, f64)], key: &str) -> f64 {
    fields.iter().find(|(k, _)| k == key).unwrap_or_else(|| panic!("no {key} in {fields:?}")).1
}

/// Marches `cache` with --verify (and `extra` flags); the header's fields and stderr.
fn verify(dir: &Path, cache: &Path, name: &str, extra: &[&str]) -> (Vec<(String, f64)>, String) {
    let exr = dir.join(format!("{name}.exr"));
    let out = run(Command::new(bin("vdbmarch")).arg(cache).args(["--verify", "--verify-max-spp", "512"]).args(extra).arg("-o").arg(&exr));
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let text = exr_attribute(&std::fs::read(&exr).unwrap(), "nimbus:verify").unwrap_or_else(|| panic!("{name}: no nimbus:verify in the header; stderr: {stderr}"));
    eprintln!("{name}: {text}\n{stderr}");
    let f = fields(&text);
    for (k, v) in &f {
        assert!(v.is_finite(), "{name}: {k} = {v} in '{text}'");
    }
    let (rel, lo, hi) = (field(&f, "rel_rmse"), field(&f, "lo"), field(&f, "hi"));
    assert!(0.0 <= lo && lo <= rel && rel <= hi, "{name}: {text}");
    assert!(field(&f, "pixels") >= 20.0 && field(&f, "block") == 2.0, "{name}: {text}");
    let line: Vec<&str> = stderr.lines().filter(|l| l.contains("verify: relative RMSE")).collect();
    assert_eq!(line.len(), 1, "{name}: one line on stderr: {stderr}");
    (f, stderr)
}

#[test]
fn verify_reports_the_render_s_error_and_finds_a_wrong_cache() {
    let dir = scratch("ball");
    let right = bake(&dir, "0.9");
    let wrong = bake(&dir, "0.5");
    let (good, _) = verify(&dir, &right, "right", &[]);
    // The cache baked for albedo 0.5 marched as 0.9 (the march warns and goes on): its
    // Li_multiple is for a darker medium than the one the image shows.
    let (bad, stderr) = verify(&dir, &wrong, "wrong", &["--albedo", "0.9"]);
    assert!(stderr.contains("differs from the one the cache was baked with"), "{stderr}");
    let (g, b) = (field(&good, "rel_rmse"), field(&bad, "rel_rmse"));
    // Measured (32 x 24): two references at 2048 paths a pixel put the image 1.85% and 1.84%
    // off, 2.32% off each other, so the image's own error is about 0.85%; --verify says 1.12%
    // (0.48-1.51%) at its default cap on paths, 1.49% (0-2.68%) at the 512 here. The wrong
    // cache: 63% (58-69%), mean ratio 0.54.
    assert!(g < 0.04, "the defaults' image is within a few percent: {good:?}");
    assert!(b > 5.0 * g && field(&bad, "lo") > field(&good, "hi"), "the wrong cache is far off: {bad:?} against {good:?}");
    assert!(field(&bad, "mean_ratio") < 0.7 && (field(&good, "mean_ratio") - 1.0).abs() < 0.03, "{bad:?} {good:?}");

    // Reproducible: the same seed, the same report (and image); -q: no line at all.
    let quick = ["--verify", "--verify-pixels", "8", "--verify-max-spp", "256", "-q", "-o"];
    let quiet = run(Command::new(bin("vdbmarch")).arg(&right).args(quick).arg(dir.join("q.exr")));
    assert!(quiet.stderr.is_empty(), "{}", String::from_utf8_lossy(&quiet.stderr));
    run(Command::new(bin("vdbmarch")).arg(&right).args(quick).arg(dir.join("q2.exr")));
    assert_eq!(std::fs::read(dir.join("q.exr")).unwrap(), std::fs::read(dir.join("q2.exr")).unwrap());
    assert!(exr_attribute(&std::fs::read(dir.join("q.exr")).unwrap(), "nimbus:verify").is_some());
    // -v: the verification's time and paths.
    let verbose = run(Command::new(bin("vdbmarch")).arg(&right).args(["--verify", "--verify-pixels", "8", "--verify-block", "1", "--verify-max-spp", "256", "-v", "-o"]).arg(dir.join("v.exr")));
    let text = String::from_utf8_lossy(&verbose.stderr);
    assert!(text.lines().any(|l| l.contains("verify") && l.contains(" s ") && l.contains("paths")), "{text}");
    assert!(text.contains(" pixels against"), "{text}");
    let single = exr_attribute(&std::fs::read(dir.join("v.exr")).unwrap(), "nimbus:verify").unwrap();
    assert!(single.contains(",pixels=") && !single.contains("block"), "no block field for single pixels: {single}");

    // exrheader shows the attribute, where it is installed.
    match Command::new("exrheader").arg(dir.join("right.exr")).output() {
        Ok(out) => {
            let header = String::from_utf8_lossy(&out.stdout);
            assert!(header.lines().any(|l| l.starts_with("nimbus:verify") && l.contains("rel_rmse=")), "{header}");
        }
        Err(_) => eprintln!("SKIPPED exrheader check: exrheader not installed (apt install openexr)"),
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_verify_flags_are_usage_errors() {
    let dir = scratch("usage");
    let cache = bake(&dir, "0.9");
    let cases: &[(&[&str], &str)] = &[
        (&["--verify", "--reference"], "cannot be used with --reference"),
        (&["--verify", "--verify-block", "3"], "--verify-block must be 1 or 2"),
        (&["--verify", "--verify-pixels", "0"], "--verify-pixels must be at least 1"),
        (&["--verify", "--verify-target", "0"], "--verify-target must be a positive number"),
        (&["--verify-pixels", "64"], "--verify"),
    ];
    for (args, want) in cases {
        let out = Command::new(bin("vdbmarch")).arg(&cache).args(*args).arg("-o").arg(dir.join("x.exr")).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?} should say '{want}': {err}");
        assert!(err.trim_end().lines().count() <= 6, "a short message: {err}");
        assert!(!dir.join("x.exr").exists(), "{args:?} wrote an image");
    }
    // Ours are one line.
    let out = Command::new(bin("vdbmarch")).arg(&cache).args(["--verify", "--reference", "-o"]).arg(dir.join("x.exr")).output().unwrap();
    assert_eq!(String::from_utf8_lossy(&out.stderr).trim_end().lines().count(), 1);
    std::fs::remove_dir_all(&dir).ok();
}
