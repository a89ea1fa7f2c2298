//! Shared by the GPU agreement tests and the bench: a device (or a loud skip) and test media.
#![allow(dead_code)]

use std::sync::OnceLock;

use glam::{DVec3, IVec3};
use nimbus_gpu::{DeviceChoice, GpuContext, GpuError};
use nimbus_volume::{Transform, Volume};

/// The process-wide test device: any adapter, software (lavapipe) included. `None`, after a
/// loud message, only when the machine has no adapter at all.
pub fn gpu() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Option<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| match DeviceChoice::Gpu.resolve() {
        Ok(device) => {
            let ctx = device.gpu().expect("--device gpu resolves to a GPU").clone();
            eprintln!("GPU tests run on {}", ctx.info);
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            eprintln!("\n!!!!!!!! SKIPPING GPU TEST: {e} !!!!!!!!\n");
            None
        }
        Err(e) => panic!("a GPU adapter exists but cannot be used: {e}"),
    })
    .as_ref()
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
