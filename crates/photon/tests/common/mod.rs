//! Shared by the GPU agreement tests and the bench: a device (or a loud skip) and test media.
#![allow(dead_code)]

use glam::{DVec3, IVec3};
use nimbus_gpu::GpuContext;
use nimbus_volume::{Transform, Volume};

/// The process-wide test device (see [`nimbus_gpu::test_context`]).
pub fn gpu() -> Option<&'static GpuContext> {
    nimbus_gpu::test_context()
}

/// A smooth, lumpy cloud in a cube of `n`^3 voxels (voxel 0.1, centred near 0): a ball of
/// radius n/2 whose density falls off toward the edge, times a gentle ripple, so free paths
/// cross real gradients and voxel boundaries.
pub fn cloud(n: i32, peak: f32) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::new(0.03, -0.02, 0.01)), 0.0);
    let r = n as f32 / 2.0;
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                let p = IVec3::new(x, y, z).as_vec3() - (r - 0.5);
                let q = p.length() / r;
                if q < 1.0 {
                    let ripple = 1.0 + 0.4 * (p.x * 0.7).sin() * (p.y * 0.5).cos() * (p.z * 0.3 + 1.0).sin();
                    v.set(IVec3::new(x, y, z) - IVec3::splat(n / 2), peak * (1.0 - q * q) * ripple);
                }
            }
        }
    }
    v
}
