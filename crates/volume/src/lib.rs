//! The in-memory sparse volume every nimbus stage samples.
//!
//! A [`Volume`] stores values in 8^3 bricks aligned to OpenVDB leaf nodes, with the same voxel
//! order inside a brick ([`brick_offset`]) and the same 512-bit activity masks, so the vdb
//! crate copies leaves in and out without reshuffling. Memory follows the active bricks, never
//! the bounding box. [`Volume::sample_index`] is trilinear interpolation identical to
//! `openvdb::tools::BoxSampler` (the vdb crate's tests hold it to that), and the
//! [`MajorantGrid`] gives a conservative upper bound of the interpolated density over cubic
//! cells (bricks, or down to one voxel for optically huge media), walked along a
//! ray by a 3D DDA: the basis for empty-space skipping and for delta/ratio tracking.
//!
//! Conventions (design.md section 2): a voxel's value sits at its integer index coordinate;
//! the [`Transform`] is any affine index-to-world map, kept in f64.

mod majorant;
mod transform;
mod volume;

pub use majorant::{MajorantGrid, MajorantSegment, MajorantWalk, MAX_CELL_OPTICAL_DEPTH, TRACKING_CELL_LOG2};
pub use transform::Transform;
pub use volume::{brick_local, brick_offset, brick_origin, lattice_cell, trilinear, BrickMask, BrickRef, Volume, BRICK_DIM, BRICK_LOG2, BRICK_VOXELS};

use glam::Vec3;

#[derive(Debug, thiserror::Error)]
pub enum VolumeError {
    #[error("transform is singular or not finite")]
    SingularTransform,
}

/// A voxel value type. `lerp` follows OpenVDB's BoxSampler: the difference is taken in the
/// value type, scaled in f64, and added back in the value type.
pub trait Voxel: Copy + bytemuck::Pod + PartialEq + Default + Send + Sync + std::fmt::Debug + 'static {
    fn lerp(a: Self, b: Self, w: f64) -> Self;
}

impl Voxel for f32 {
    #[inline]
    fn lerp(a: f32, b: f32, w: f64) -> f32 {
        a + (((b - a) as f64) * w) as f32
    }
}

/// Two f64 values a voxel: lattices read on the host only, where f32 would round away a
/// difference of two nearly equal readings (nimbus-cache's coarser lattice, whose read less
/// the baked lattice's is the bias estimate).
impl Voxel for glam::DVec2 {
    #[inline]
    fn lerp(a: glam::DVec2, b: glam::DVec2, w: f64) -> glam::DVec2 {
        a + (b - a) * w
    }
}

impl Voxel for Vec3 {
    #[inline]
    fn lerp(a: Vec3, b: Vec3, w: f64) -> Vec3 {
        let d = b - a;
        a + Vec3::new((d.x as f64 * w) as f32, (d.y as f64 * w) as f32, (d.z as f64 * w) as f32)
    }
}
