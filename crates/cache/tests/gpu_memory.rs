//! A GPU bake's host memory does not grow with its passes of paths (issue #49). lavapipe
//! (Mesa 22.3) compiled the whole pipeline again at every dispatch whose uniform buffer it
//! could inline, and kept each compiled shader: about 10 MB a pass of paths, 4.2 GB for the
//! glowing cube at `--paths 64`. The stages' parameters are storage buffers since
//! (nimbus_gpu::GpuContext::params_buffer).
//!
//! Each bake runs in a child process (this test binary again, one test selected), which
//! reports its peak RSS (VmHWM): a bake of four times the passes must peak no higher, within
//! a margin well under what the passes' difference cost before.

use glam::{IVec3, Vec3};
use nimbus_cache::{bake_gpu, CacheParams, MultipleEstimator};
use nimbus_gpu::DispatchSizing;
use nimbus_optics::{Camera, Light, Medium};
use nimbus_photon::PhotonMap;

mod support;

/// Set in the child: the paths per voxel its bake traces, one per pass.
const PASSES: &str = "NIMBUS_TEST_PATH_PASSES";
/// How the child reports its peak RSS.
const MARK: &str = "peak rss KiB: ";

/// A cube of 8^3 voxels of a moderately dense medium lit by one sun: paths of a few
/// collisions, Li_multiple alone on its own coarser lattice.
fn bake(passes: u32) {
    let ctx = nimbus_gpu::test_context().expect("the parent found an adapter");
    // One path a voxel a dispatch, so the passes are as many as the paths.
    let ctx = ctx.with_dispatch(DispatchSizing { max_repeats: 1, ..ctx.dispatch });
    let v = support::block(IVec3::ZERO, IVec3::splat(7), |c| 1.0 + 0.1 * c.x as f32);
    let (lo, hi) = v.world_bounds().unwrap();
    let p = CacheParams {
        single: false,
        multiple: true,
        multiple_scale: Some(2.0),
        estimator: MultipleEstimator::Paths { per_voxel: passes },
        ..support::params(
            Medium { extinction: 5.0, albedo: Vec3::splat(0.8), g: 0.0 },
            vec![Light::sun(Vec3::new(0.3, 0.2, -1.0).normalize(), Vec3::ONE).unwrap()],
            Camera::default_for_bounds(lo, hi).unwrap(),
        )
    };
    let (_, stats) = bake_gpu(&ctx, &v, &PhotonMap::default(), &p).unwrap();
    assert!(stats.paths > 0);
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).expect("VmHWM in /proc/self/status");
    println!("{MARK}{}", line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim());
}

/// The child's side: bakes only when the parent asked (PASSES set).
#[test]
fn bake_in_a_child_process() {
    if let Ok(passes) = std::env::var(PASSES) {
        bake(passes.parse().unwrap());
    }
}

/// Peak RSS in KiB of a child baking `passes` passes.
fn peak_kib(passes: u32) -> u64 {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "bake_in_a_child_process", "--nocapture", "--test-threads=1"])
        .env(PASSES, passes.to_string())
        // One malloc arena: the peak then does not depend on which threads happened to allocate.
        .env("MALLOC_ARENA_MAX", "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "the child failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout.lines().find_map(|l| l.split_once(MARK).map(|(_, kib)| kib.trim())).unwrap_or_else(|| panic!("no peak in:\n{stdout}")).parse().unwrap()
}

#[test]
fn peak_memory_does_not_grow_with_the_passes_of_paths() {
    if std::env::var(PASSES).is_ok() || nimbus_gpu::test_context().is_none() {
        return;
    }
    let (few, many) = (peak_kib(6), peak_kib(24));
    eprintln!("peak RSS: {few} KiB at 6 passes, {many} KiB at 24");
    // Before the fix the 18 passes more cost about 180 MB.
    assert!(many <= few + 40 * 1024, "peak RSS grows with the passes: {few} KiB at 6, {many} KiB at 24");
}
