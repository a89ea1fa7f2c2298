//! What the cache's tests share: the sphere scene (`sphere`) and the plain bake they vary.

#![allow(dead_code)]

pub mod sphere;

use nimbus_cache::{CacheParams, Gather, LightLattice, MultipleEstimator, ShadowMode};
use glam::{DVec3, IVec3};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_volume::{Transform, Volume};

/// The plain bake the tests vary: Li_single alone on the density's own lattice, Simpson
/// steps of a quarter voxel toward the lights' tables, no cut-off; the photon gather's
/// settings for where a test turns multiple scattering on.
pub fn params(medium: Medium, lights: Vec<Light>, camera: Camera) -> CacheParams {
    CacheParams {
        environment: None,
        medium,
        lights,
        camera,
        step: 0.25,
        cache_scale: 1.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        single: true,
        multiple: false,
        gather: Gather::Neighbours { k: 32, max_radius: 1.0 },
        estimator: MultipleEstimator::Photons,
        seed: 0,
        min_transmittance: 0.0,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    }
}

/// The voxel edge of [`block`]s.
pub const VOXEL: f64 = 0.1;

/// Voxels of [`VOXEL`] from the origin: the density `value` gives on the index box [lo, hi].
pub fn block(lo: IVec3, hi: IVec3, value: impl Fn(IVec3) -> f32) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(VOXEL, DVec3::ZERO), 0.0);
    for x in lo.x..=hi.x {
        for y in lo.y..=hi.y {
            for z in lo.z..=hi.z {
                let c = IVec3::new(x, y, z);
                v.set(c, value(c));
            }
        }
    }
    v
}
