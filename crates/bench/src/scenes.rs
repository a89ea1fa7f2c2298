//! Scenes the bundled two are not (issue #30): made here, from formulas, so that the defaults
//! are measured on media they were never tuned to. Each is a density volume with the flags
//! (medium, light, camera) that complete it; `nimbus-scene NAME OUT.vdb` writes one and
//! prints its flags, `scripts/bench_unseen.sh` runs the chain on each against the path-traced
//! reference and the brute-force single-scatter march.
//!
//! - `anvil`: a sheared anvil layer on non-cubic voxels (0.025 x 0.03 x 0.02), at negative
//!   indices, a million units from the origin; optical depth about 1.2 through it vertically,
//!   about 8 along it; g 0.6, coloured albedo.
//! - `forward`: lumpy puffs on a rotated lattice of flat voxels (0.05 x 0.05 x 0.1), strongly
//!   forward scattering (g 0.9), lit from behind and beside.
//! - `sheet`: a thin dense sheet a few voxels thick (voxels 0.04 x 0.04 x 0.01), lit at a
//!   grazing angle: shadows sharper than the lattice across it, long paths along it.

use glam::{DAffine3, DMat3, DQuat, DVec3, IVec3};
use nimbus_volume::{Transform, Volume};

/// A scene: its density and the flags vdbcache and vdbmarch take for the rest.
pub struct Scene {
    pub density: Volume<f32>,
    /// Medium and lights (vdbcache's flags).
    pub medium: Vec<String>,
    /// The camera (vdbcache's flags; vdbmarch reads it from the cache).
    pub camera: Vec<String>,
}

impl Scene {
    /// A scene seen from `centre + from`, looking at `centre` with +Z up.
    fn new(density: Volume<f32>, medium: &str, centre: DVec3, from: DVec3, fov: f64) -> Scene {
        let eye = centre + from;
        let camera = format!("--eye {},{},{} --look-at {},{},{} --up 0,0,1 --fov {fov}", eye.x, eye.y, eye.z, centre.x, centre.y, centre.z);
        Scene { density, medium: words(medium), camera: words(&camera) }
    }
}

pub const NAMES: &[&str] = &["anvil", "forward", "sheet"];

pub fn scene(name: &str) -> Option<Scene> {
    match name {
        "anvil" => Some(anvil()),
        "forward" => Some(forward()),
        "sheet" => Some(sheet()),
        _ => None,
    }
}

fn words(s: &str) -> Vec<String> {
    s.split_whitespace().map(String::from).collect()
}

/// Smooth value noise from a few incommensurate sines: deterministic, no dependency, lumpy
/// on the scale `1 / frequency`.
fn lumps(p: DVec3, frequency: f64) -> f64 {
    let q = p * frequency;
    let a = (q.x * 1.00 + 0.3).sin() * (q.y * 1.31 + 1.7).sin() * (q.z * 0.87 + 0.5).sin();
    let b = (q.x * 2.13 + q.z * 0.7 + 2.1).sin() * (q.y * 1.93 - 0.4).sin();
    let c = (q.y * 3.71 + q.x * 1.1 + 0.9).sin() * (q.z * 3.07 + 1.3).sin();
    0.5 * a + 0.3 * b + 0.2 * c
}

/// The volume over index box `lo..=hi` with `f(world)` where positive.
fn fill(transform: Transform, lo: IVec3, hi: IVec3, f: impl Fn(DVec3) -> f64 + Sync) -> Volume<f32> {
    crate::random::fill(transform, lo, hi, |ijk| f(transform.to_world(ijk.as_dvec3())))
}

fn anvil() -> Scene {
    let size = DVec3::new(0.025, 0.03, 0.02);
    let offset = DVec3::new(1.0e6, -1.0e6, 2.0e3);
    let transform = Transform::new(DAffine3::from_mat3_translation(DMat3::from_diagonal(size), offset)).unwrap();
    // About 4 x 3 x 0.8 world units, all at negative indices.
    let (lo, hi) = (IVec3::new(-170, -110, -50), IVec3::new(-10, -10, -10));
    let centre = transform.to_world(((lo + hi).as_dvec3()) * 0.5);
    let density = fill(transform, lo, hi, |w| {
        let p = w - centre;
        // The layer's mid-plane rises along x (the shear of an anvil blown downwind) and its
        // thickness thins toward the edges.
        let mid = 0.12 * p.x + 0.05 * (p.y * 1.7).sin();
        let half = 0.22 * (1.0 - (p.x / 2.1).powi(2)).max(0.0).sqrt() * (1.0 - (p.y / 1.55).powi(4)).max(0.0);
        if half <= 0.0 {
            return 0.0;
        }
        let s = (p.z - mid) / half;
        let profile = (1.0 - s * s).max(0.0);
        3.2 * profile * (1.0 + 0.6 * lumps(p, 4.0)).max(0.0)
    });
    Scene::new(density, "--extinction 1 --g 0.6 --albedo 0.95,0.9,0.8 --sun dir=0.4,0.25,-0.88,irradiance=3", centre, DVec3::new(-1.5, -7.0, 1.6), 40.0)
}

fn forward() -> Scene {
    let size = DVec3::new(0.05, 0.05, 0.1);
    let rotation = DQuat::from_euler(glam::EulerRot::ZYX, 0.6, 0.25, -0.15);
    let transform = Transform::new(DAffine3::from_mat3_translation(DMat3::from_quat(rotation) * DMat3::from_diagonal(size), DVec3::new(3.0, -2.0, 1.0))).unwrap();
    let (lo, hi) = (IVec3::new(-40, -40, -20), IVec3::new(40, 40, 20));
    let centre = transform.to_world(DVec3::ZERO);
    let puffs = [(DVec3::new(0.0, 0.0, 0.0), 1.1), (DVec3::new(0.9, 0.4, 0.3), 0.7), (DVec3::new(-0.8, -0.3, 0.2), 0.8), (DVec3::new(0.1, 0.8, -0.4), 0.6)];
    let density = fill(transform, lo, hi, |w| {
        let p = w - centre;
        let mut d = 0.0f64;
        for (c, r) in puffs {
            let q = (p - c).length() / r;
            d = d.max((1.0 - q * q).max(0.0));
        }
        4.0 * d * (1.0 + 0.5 * lumps(p, 5.0)).max(0.0)
    });
    Scene::new(density, "--extinction 1 --g 0.9 --albedo 0.98 --sun dir=-0.45,0.85,-0.27,irradiance=2 --sun dir=0.6,-0.2,-0.77,irradiance=1", centre, DVec3::new(2.0, -6.0, 1.0), 35.0)
}

fn sheet() -> Scene {
    let size = DVec3::new(0.04, 0.04, 0.01);
    let transform = Transform::new(DAffine3::from_mat3_translation(DMat3::from_diagonal(size), DVec3::new(-2.0, 5.0, 0.5))).unwrap();
    let (lo, hi) = (IVec3::new(0, 0, 0), IVec3::new(100, 80, 40));
    let centre = transform.to_world(((lo + hi).as_dvec3()) * 0.5);
    let density = fill(transform, lo, hi, |w| {
        let p = w - centre;
        // A sheet 0.06 thick (6 voxels), gently curved, with an optical depth of about 3
        // across and tens along it.
        let mid = 0.08 * (p.x * 1.3).sin() + 0.05 * (p.y * 2.0).cos();
        let s = (p.z - mid) / 0.03;
        let edge = (1.0 - (p.x / 1.9).powi(6)).max(0.0) * (1.0 - (p.y / 1.5).powi(6)).max(0.0);
        60.0 * (1.0 - s * s).max(0.0) * edge * (1.0 + 0.4 * lumps(p, 6.0)).max(0.0)
    });
    Scene::new(density, "--extinction 1 --g 0.3 --albedo 0.9 --sun dir=0.3,0.1,-0.2,irradiance=3", centre, DVec3::new(0.5, -5.0, 1.2), 45.0)
}
