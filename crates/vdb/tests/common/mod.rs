//! Shared fixtures for the nimbus-vdb integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{DAffine3, DQuat, DVec3, IVec3, Vec3};
use nimbus_volume::{brick_offset, Transform, Volume, Voxel, BRICK_VOXELS};

/// A fresh directory under the target dir's tmp, removed on drop.
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("nimbus-vdb-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    pub fn path(&self, file: &str) -> PathBuf {
        self.0.join(file)
    }
    pub fn dir(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A deterministic pseudo-random stream (splitmix64), so fixtures need no dependency.
pub struct Rng(u64);
impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Rotated, non-uniformly scaled and far from the origin: every part of the affine map
/// (and the row-vector transposition at the bridge) must survive a round trip.
pub fn awkward_transform() -> Transform {
    let rot = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let m = DAffine3::from_scale_rotation_translation(DVec3::new(0.1, 0.25, 0.05), rot, DVec3::new(1e5, -2.5e5, 3.0));
    Transform::new(m).unwrap()
}

/// A sparse volume with bricks spread over negative and positive indices, partial
/// activity masks and inactive voxels holding values of their own.
pub fn sample_volume<T: Voxel>(transform: Transform, background: T, value: impl Fn(&mut Rng) -> T) -> Volume<T> {
    let mut rng = Rng::new(7);
    let mut vol = Volume::new(transform, background);
    let origins = [IVec3::new(0, 0, 0), IVec3::new(-8, 16, 8), IVec3::new(40, -24, 0), IVec3::new(-800, 8, 1600)];
    for (n, origin) in origins.iter().enumerate() {
        let values: Vec<T> = (0..BRICK_VOXELS).map(|_| value(&mut rng)).collect();
        let mut mask = [0u64; 8];
        match n {
            0 => mask = [u64::MAX; 8],                                         // fully active
            1 => mask.iter_mut().for_each(|w| *w = rng.next_u64()),              // random
            2 => mask[3] = 1 << 17,                                              // a single voxel
            _ => mask[0] = 0b1011,                                               // a corner
        }
        vol.insert_brick(*origin, &values, &mask);
    }
    vol
}

pub fn sample_float_volume(transform: Transform) -> Volume<f32> {
    sample_volume(transform, 0.0f32, |r| r.f32() * 3.0)
}

pub fn sample_vec3_volume(transform: Transform) -> Volume<Vec3> {
    sample_volume(transform, Vec3::new(0.5, -1.0, 2.0), |r| Vec3::new(r.f32(), -r.f32(), r.f32() * 100.0))
}

/// Bricks, masks, values, background and transform all equal, exactly.
pub fn assert_volumes_equal<T: Voxel>(a: &Volume<T>, b: &Volume<T>) {
    assert_eq!(a.transform().index_to_world(), b.transform().index_to_world(), "transforms differ");
    assert_eq!(a.background(), b.background(), "backgrounds differ");
    assert_eq!(a.brick_count(), b.brick_count(), "brick counts differ");
    assert_eq!(a.active_voxel_count(), b.active_voxel_count(), "active voxel counts differ");
    for brick in a.bricks() {
        let index = b.brick_index(brick.origin).unwrap_or_else(|| panic!("brick {} missing", brick.origin));
        let other = b.brick(index);
        assert_eq!(brick.active, other.active, "masks differ in brick {}", brick.origin);
        assert_eq!(brick.values, other.values, "values differ in brick {}", brick.origin);
    }
}

/// Index of voxel `local` in a brick's value slice (shorthand for tests).
pub fn at(local: IVec3) -> usize {
    brick_offset(local)
}

/// Debian's Python with pyopenvdb, or None (with a loud message) when it is missing.
pub fn python_with_pyopenvdb() -> Option<&'static str> {
    let py = "/usr/bin/python3";
    let ok = Command::new(py).args(["-c", "import pyopenvdb"]).output().is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("\n!!! SKIPPED: {py} with pyopenvdb (Debian python3-openvdb) is not installed !!!\n");
    }
    ok.then_some(py)
}

/// vdb_print (Debian libopenvdb-tools), or None with a loud message.
pub fn vdb_print() -> Option<&'static str> {
    let ok = Command::new("vdb_print").arg("-version").output().is_ok();
    if !ok {
        eprintln!("\n!!! SKIPPED: vdb_print (Debian libopenvdb-tools) is not installed !!!\n");
    }
    ok.then_some("vdb_print")
}

pub fn pyvdb_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pyvdb.py")
}

/// Runs a command, panicking with its stderr when it fails; returns stdout.
pub fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    assert!(out.status.success(), "{cmd:?} failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}
