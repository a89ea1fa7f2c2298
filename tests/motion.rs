//! End-to-end motion blur (issue #20): a ball with a velocity grid `v` through vdbcache and
//! vdbmarch, piped as a shell pipes them: the blur spreads the ball along its velocity by
//! the distance the shutter covers, the GPU march agrees with the CPU's, the EXR records
//! the blur, and bad input is refused.


use glam::{DVec3, IVec3, Vec3};
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};
use nimbus_volume::{Transform, Volume};

mod common;

use common::{exr_attribute, pipe_ok, pipe_output, rgba_of};

const VOXEL: f64 = 0.05;

/// A ball of radius 0.4 at the origin, and `velocity` (world units a second) on its voxels
/// under the name `grid`.
fn moving_ball(grid: &str, velocity: Vec3) -> Vec<u8> {
    let mut density = Volume::new(Transform::uniform(VOXEL, DVec3::ZERO), 0.0f32);
    let mut v = Volume::new(Transform::uniform(VOXEL, DVec3::ZERO), Vec3::ZERO);
    for c in (-12..=12).flat_map(|x| (-12..=12).flat_map(move |y| (-12..=12).map(move |z| IVec3::new(x, y, z)))) {
        let r = c.as_dvec3().length() * VOXEL / 0.4;
        if r < 1.0 {
            density.set(c, (3.0 * (1.0 - r)) as f32);
        }
        // The velocity reaches past the ball by the distance it moves (the lookups at x - t v(x)
        // read v where the ball is going).
        v.set(c, velocity);
    }
    for c in (-12..=24).flat_map(|x| (-14..=14).flat_map(move |y| (-14..=14).map(move |z| IVec3::new(x, y, z)))) {
        v.set(c, velocity);
    }
    let mut file = VdbFile::new();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume(grid, &v, GridClass::Unknown).unwrap();
    file.to_bytes(&WriteOptions::default()).unwrap()
}

const SCENE: &[&str] = &[
    "--eye", "0,-4,0", "--look-at", "0,0,0", "--up", "0,0,1", "--fov", "20", "--width", "64", "--height", "16",
    "--extinction", "4", "--albedo", "0.9",
];




/// The variance (pixels squared) and the sum of the image's alpha profile along x (each
/// column's summed alpha): a blur over a travel of L pixels convolves the profile with a
/// box of width L, which keeps the sum and adds L^2 / 12 to the variance.
fn profile_moments(pixels: &[[f32; 4]]) -> (f64, f64) {
    let profile: Vec<f64> = (0..64).map(|x| (0..16).map(|y| pixels[y * 64 + x][3] as f64).sum()).collect();
    let sum: f64 = profile.iter().sum();
    let mean = profile.iter().enumerate().map(|(x, a)| x as f64 * a).sum::<f64>() / sum;
    let variance = profile.iter().enumerate().map(|(x, a)| (x as f64 - mean).powi(2) * a).sum::<f64>() / sum;
    (variance, sum)
}

#[test]
fn a_moving_ball_blurs_along_its_velocity_through_the_chain() {
    // 12 units a second over a shutter of 0.5 frames at 24 fps: 0.25 world units of travel.
    let vdb = moving_ball("v", Vec3::new(12.0, 0.0, 0.0));
    let cache = pipe_ok("vdbcache", SCENE, &vdb).stdout;
    let sharp = pipe_ok("vdbmarch", &["--spp", "16", "--device", "cpu"], &cache).stdout;
    let blurred = pipe_ok("vdbmarch", &["--spp", "16", "--device", "cpu", "--motion-blur", "-v"], &cache);
    let log = String::from_utf8_lossy(&blurred.stderr);
    assert!(log.contains("motion blur: velocity grid 'v'") && log.contains("0.2500 world units"), "{log}");
    assert_eq!(exr_attribute(&blurred.stdout, "nimbus:motion_blur").as_deref(), Some("grid=v,shutter=0.5,fps=24,scale=1"));
    assert_eq!(exr_attribute(&sharp, "nimbus:motion_blur").as_deref(), Some("none"));
    let (s, b) = (rgba_of(&sharp), rgba_of(&blurred.stdout));
    let ((vs, ss), (vb, sb)) = (profile_moments(&s), profile_moments(&b));
    // A pixel is 2 x 4 tan(10 deg) / 64 = 0.0220 world units at the ball: the 0.25 it
    // travels is 11.3 pixels, which adds 10.7 pixels^2 to the variance.
    let travel = 0.25 / (8.0 * 10f64.to_radians().tan() / 64.0);
    let added = vb - vs;
    eprintln!("alpha profile: variance sharp {vs:.2}, blurred {vb:.2} (+{added:.2}, a box of {travel:.1} pixels adds {:.2}); sums {ss:.2}, {sb:.2}", travel * travel / 12.0);
    assert!((added / (travel * travel / 12.0) - 1.0).abs() < 0.15, "the blur added {added} pixels^2");
    assert!((sb / ss - 1.0).abs() < 0.02, "alpha sums {ss} and {sb}");

    // The GPU march takes the same times and lookups.
    let gpu = rgba_of(&pipe_ok("vdbmarch", &["--spp", "16", "--device", "gpu", "--motion-blur"], &cache).stdout);
    let apart = gpu.iter().zip(&b).flat_map(|(g, c)| (0..4).map(move |k| (g[k] - c[k]).abs())).fold(0.0f32, f32::max);
    eprintln!("GPU march against the CPU's: {apart:.2e}");
    assert!(apart < 1e-3, "{apart}");

    // The reference blurs too, on either backend.
    let reference = rgba_of(&pipe_ok("vdbmarch", &[SCENE, &["--reference", "--spp", "16", "--device", "cpu", "--motion-blur"]].concat(), &vdb).stdout);
    let (vr, _) = profile_moments(&reference);
    eprintln!("reference: alpha profile variance {vr:.2}");
    assert!(((vr - vs) / (travel * travel / 12.0) - 1.0).abs() < 0.2, "the reference's blur added {} pixels^2", vr - vs);
    let gpu_reference = rgba_of(&pipe_ok("vdbmarch", &[SCENE, &["--reference", "--spp", "16", "--device", "gpu", "--motion-blur"]].concat(), &vdb).stdout);
    let (vg, _) = profile_moments(&gpu_reference);
    eprintln!("GPU reference: alpha profile variance {vg:.2}");
    // The same draws, decided in f32: the blur's width to a small fraction of what it adds.
    assert!((vg - vr).abs() < 0.03 * (vr - vs), "GPU reference {vg} against the CPU's {vr}");
}

#[test]
fn motion_blur_finds_houdini_and_blender_velocity_grids_and_refuses_bad_input() {
    // Houdini's `vel`, Blender's `velocity` are found without --velocity-grid.
    for name in ["vel", "velocity"] {
        let vdb = moving_ball(name, Vec3::new(2.0, 0.0, 0.0));
        let out = pipe_ok("vdbmarch", &[SCENE, &["--reference", "--spp", "1", "--motion-blur", "-v", "--device", "cpu"]].concat(), &vdb);
        assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("velocity grid '{name}'")));
    }
    // No velocity grid: a clear error naming the vec3 grids there are, exit 2.
    let vdb = moving_ball("wind", Vec3::new(2.0, 0.0, 0.0));
    let out = pipe_output("vdbmarch", &[SCENE, &["--reference", "--motion-blur"]].concat(), &vdb);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.starts_with("error: --motion-blur needs a velocity grid") && err.contains("wind"), "{err}");
    // Named, it is used.
    pipe_ok("vdbmarch", &[SCENE, &["--reference", "--spp", "1", "--motion-blur", "--velocity-grid", "wind", "--device", "cpu"]].concat(), &vdb);
    // A scalar grid named as velocity, a bad shutter and fps, and --shutter without
    // --motion-blur: exit 2.
    for args in [
        &["--motion-blur", "--velocity-grid", "density"][..],
        &["--motion-blur", "--velocity-grid", "wind", "--shutter", "-1"],
        &["--motion-blur", "--velocity-grid", "wind", "--fps", "0"],
        &["--shutter", "0.5"],
    ] {
        let out = pipe_output("vdbmarch", &[SCENE, &["--reference"], args].concat(), &vdb);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    }
}
