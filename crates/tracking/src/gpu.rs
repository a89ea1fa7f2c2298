//! The GPU side of this crate: `shaders/tracking.wgsl` (the WGSL twin of the majorant DDA and
//! the free-path samplers) and the host data it reads, shared by every stage shader that
//! walks rays through the density; `shaders/path.wgsl` (the twin of [`crate::trace_path`]),
//! shared by the reference path tracer and vdbcache's path-traced multiple scattering.

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::{wgpu, GpuContext, GpuError};
use nimbus_volume::MajorantGrid;

/// `shaders/tracking.wgsl`: plain functions, no bindings; stage shaders concatenate it.
pub const TRACKING_WGSL: &str = include_str!("../../../shaders/tracking.wgsl");

/// `shaders/path.wgsl`: `trace_path` and its constants, no bindings; composed after
/// [`TRACKING_WGSL`] by a stage shader that provides `fn path_light(index: u32) -> Light`.
pub const PATH_WGSL: &str = include_str!("../../../shaders/path.wgsl");

/// WGSL `MajorantGridInfo` (tracking.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuMajorantInfo {
    pub origin: [i32; 3],
    pub cell_size: f32,
    pub dims: [i32; 3],
    pub outside: f32,
}

impl GpuMajorantInfo {
    /// `outside` is the bound beyond the grid: the volume's background.
    pub fn new(grid: &MajorantGrid, outside: f32) -> Self {
        GpuMajorantInfo { origin: grid.origin().to_array(), cell_size: grid.cell_size() as f32, dims: grid.dims().to_array(), outside }
    }
}

/// The majorant bounds as a storage buffer (one dummy value for an empty grid: bindings
/// cannot be empty).
pub fn majorant_buffer(ctx: &GpuContext, grid: &MajorantGrid) -> Result<wgpu::Buffer, GpuError> {
    if grid.values().is_empty() {
        ctx.storage_buffer("majorant", &[0f32])
    } else {
        ctx.storage_buffer("majorant", grid.values())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn layout_matches_the_wgsl_struct() {
        assert_eq!(size_of::<super::GpuMajorantInfo>(), 32);
        assert!(super::TRACKING_WGSL.contains("struct MajorantGridInfo"));
    }

    #[test]
    fn path_constants_match_the_wgsl() {
        use crate::{RATIO_ROULETTE, ROULETTE_FROM_DEPTH};
        assert!(super::PATH_WGSL.contains(&format!("const ROULETTE_FROM_DEPTH: u32 = {ROULETTE_FROM_DEPTH}u;")));
        assert!(super::PATH_WGSL.contains(&format!("const RATIO_ROULETTE: f32 = {RATIO_ROULETTE:?};")));
    }
}
