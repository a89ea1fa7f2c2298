//! The GPU backend: one wgpu invocation per voxel of the proposed bricks and per pass
//! (`shaders/density.wgsl`), each gathering from the cells [`crate::prepare`] sorted the
//! particles into, as the CPU does. The per-brick sums come back to the host and go through
//! the same [`Keep::brick`] and finishing step as the CPU's.
//!
//! Why a per-voxel gather and not the CPU's per-brick splat: a splat on the GPU needs float
//! atomics (not in WGSL), while a gather writes each voxel once. The gather visits the
//! particles of the cells overlapping the support's bounding box, a constant factor (the box
//! over the sphere, with cells of about one support radius) above the splat's pairs, still
//! O(N) per pass for bounded h0.

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::{storage_entry, uniform_entry, GpuContext, GpuError};
use nimbus_volume::BRICK_VOXELS;

use crate::params::Method;
use crate::setup::Prepared;
use crate::{BrickResult, Keep, PointParams};

/// The density kernels, `shaders/density.wgsl`: they read no volume, so they are composed
/// after `shaders/dispatch.wgsl` only, not the volume prelude.
pub const DENSITY_WGSL: &str = include_str!("../../../shaders/density.wgsl");

const WORKGROUP_SIZE: u32 = 64;
/// Twin of the WGSL constant: knn ranks up to this use a private sorted list, larger ones
/// bisect with counting passes.
const KNN_MAX: u32 = 64;
/// Most bricks one chunk of dispatches covers (2^14 bricks = 8M voxels, 32 MiB per per-voxel
/// buffer): bounds device memory and keeps each dispatch short on software adapters.
const MAX_CHUNK_BRICKS: usize = 1 << 14;

/// WGSL `DensityUniforms`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuDensityParams {
    cell_origin: [f32; 3],
    cell_edge: f32,
    cell_dims: [i32; 3],
    n_star: f32,
    grid_dims: [i32; 3],
    h0: f32,
    h_min: f32,
    relax: f32,
    k: u32,
    voxel_count: u32,
    first_brick: u32,
    method: u32,
    _pad: [u32; 2],
}

fn method_code(method: Method) -> u32 {
    match method {
        Method::Usl => 0,
        Method::Asl2 => 1,
        Method::Asl3 => 2,
        Method::Knn => 3,
    }
}

/// The passes each method runs, in order (WGSL entry points).
fn passes(method: Method) -> &'static [&'static str] {
    match method {
        Method::Usl => &["density"],
        Method::Asl2 => &["predict", "density"],
        Method::Asl3 => &["predict", "correct", "density"],
        Method::Knn => &["knn", "density"],
    }
}

/// Runs the method's passes over every proposed brick, in chunks; bricks with no density are
/// dropped, the rest come back in proposal order.
pub(crate) fn estimate_bricks(ctx: &GpuContext, prep: &Prepared, method: Method, pp: &PointParams, keep: &Keep) -> Result<Vec<BrickResult>, GpuError> {
    if prep.bricks.is_empty() {
        return Ok(Vec::new());
    }
    // Measured without this: 100k particles around one point came back from lavapipe with
    // 75% of their mass.
    if ctx.loop_cap().is_some() {
        let work = "a grid point's gather (particles in reach, times the method's passes over them)";
        ctx.check_loop_bound(longest_gather(prep, method, pp), work, "or a smaller --h0")?;
    }
    let limits = ctx.limits();
    let binding_limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
    let chunk_bricks = MAX_CHUNK_BRICKS.min((binding_limit / (4 * BRICK_VOXELS as u64)).max(1) as usize);
    let chunk_voxels = (chunk_bricks.min(prep.bricks.len()) * BRICK_VOXELS) as u64;

    let particles: Vec<[f32; 4]> = prep.positions.iter().zip(&prep.masses).map(|(p, &m)| [p.x, p.y, p.z, m]).collect();
    let bricks: Vec<[i32; 4]> = prep.bricks.iter().map(|o| [o.x, o.y, o.z, 0]).collect();
    let cells = &prep.cells;
    let mut uniforms = GpuDensityParams {
        cell_origin: cells.origin.to_array(),
        cell_edge: cells.edge,
        cell_dims: cells.dims.to_array(),
        n_star: pp.n_star,
        grid_dims: prep.grid.dims.to_array(),
        h0: pp.h0,
        h_min: pp.h_min,
        relax: pp.relax,
        k: pp.n_star as u32,
        voxel_count: 0,
        first_brick: 0,
        method: method_code(method),
        _pad: [0; 2],
    };

    let uniform_buffer = ctx.uniform_buffer("density params", &uniforms)?;
    let particle_buffer = ctx.storage_buffer("density particles", &particles)?;
    drop(particles);
    let cell_buffer = ctx.storage_buffer("density cells", &cells.start)?;
    let brick_buffer = ctx.storage_buffer("density bricks", &bricks)?;
    let n0 = ctx.storage_buffer_zeroed("density n0", chunk_voxels * 4)?;
    let h = ctx.storage_buffer_zeroed("density h", chunk_voxels * 4)?;
    let rho = ctx.storage_buffer_zeroed("density rho", chunk_voxels * 4)?;
    let used = ctx.storage_buffer_zeroed("density used", chunk_voxels * 4)?;

    let layout = ctx.bind_group_layout(
        "density",
        &[
            uniform_entry(0),
            storage_entry(1, true),
            storage_entry(2, true),
            storage_entry(3, true),
            storage_entry(4, false),
            storage_entry(5, false),
            storage_entry(6, false),
            storage_entry(7, false),
        ],
    )?;
    let group = ctx.buffer_bind_group(
        "density",
        &layout,
        &[&uniform_buffer, &particle_buffer, &cell_buffer, &brick_buffer, &n0, &h, &rho, &used],
    )?;
    let source = format!("{}\n{DENSITY_WGSL}", nimbus_gpu::DISPATCH_WGSL);
    let pipelines = passes(method)
        .iter()
        .map(|&entry| Ok((entry, ctx.compute_pipeline(entry, &source, entry, &[&layout])?)))
        .collect::<Result<Vec<_>, GpuError>>()?;

    let mut results = Vec::new();
    for (chunk, origins) in prep.bricks.chunks(chunk_bricks).enumerate() {
        let voxels = (origins.len() * BRICK_VOXELS) as u64;
        uniforms.first_brick = (chunk * chunk_bricks) as u32;
        uniforms.voxel_count = voxels as u32;
        ctx.queue.write_buffer(&uniform_buffer, 0, bytemuck::bytes_of(&uniforms));
        for (entry, pipeline) in &pipelines {
            ctx.dispatch_1d(entry, pipeline, &[&group], voxels, WORKGROUP_SIZE)?;
        }
        let rho: Vec<f32> = ctx.read_buffer(&rho)?;
        let h: Vec<f32> = ctx.read_buffer(&h)?;
        let used: Vec<u32> = ctx.read_buffer(&used)?;
        for (b, &origin) in origins.iter().enumerate() {
            let span = b * BRICK_VOXELS..(b + 1) * BRICK_VOXELS;
            let brick = |v: &[f32]| -> Box<[f32; BRICK_VOXELS]> { Box::new(v.try_into().expect("one brick")) };
            if rho[span.clone()].iter().all(|&r| r <= 0.0) {
                continue;
            }
            let used: Box<[u32; BRICK_VOXELS]> = Box::new(used[span.clone()].try_into().expect("one brick"));
            results.extend(keep.brick(chunk * chunk_bricks + b, origin, brick(&rho[span.clone()]), brick(&h[span]), used, pp));
        }
    }
    Ok(results)
}

/// An upper bound on the particle-loop iterations of one invocation: the most particles in
/// the block of cells any grid point's widest gather (radius kappa*h0) visits, times the
/// gathers one invocation makes (knn above KNN_MAX bisects the 32 bits of r^2 with counting
/// gathers; below it, insertions shift its sorted list of N*).
fn longest_gather(prep: &Prepared, method: Method, pp: &PointParams) -> u64 {
    let cells = &prep.cells;
    let reach = crate::kernel::KAPPA * pp.h0;
    let w = (reach / cells.edge).ceil() as usize + 1;
    let d = cells.dims;
    // Cell ids run x fastest, then y, then z (CellGrid::id), the order of `index` below, so
    // the per-cell counts are the differences of the counting sort's starts.
    let (nx, ny, nz) = (d.x as usize, d.y as usize, d.z as usize);
    let index = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
    let mut a: Vec<u64> = cells.start.windows(2).map(|s| (s[1] - s[0]) as u64).collect();
    debug_assert_eq!(a.len(), nx * ny * nz);
    // Box sums of the per-cell counts over a window of +-w cells, one axis at a time.
    let window = |len: usize, get: &dyn Fn(usize) -> u64, out: &mut dyn FnMut(usize, u64)| {
        let mut prefix = vec![0u64; len + 1];
        for i in 0..len {
            prefix[i + 1] = prefix[i] + get(i);
        }
        for i in 0..len {
            let lo = i.saturating_sub(w);
            let hi = (i + w + 1).min(len);
            out(i, prefix[hi] - prefix[lo]);
        }
    };
    for axis in 0..3 {
        let b = a.clone();
        let (len, outer) = match axis {
            0 => (nx, ny * nz),
            1 => (ny, nx * nz),
            _ => (nz, nx * ny),
        };
        for o in 0..outer {
            let at = |i: usize| match axis {
                0 => index(i, o % ny, o / ny),
                1 => index(o % nx, i, o / nx),
                _ => index(o % nx, o / nx, i),
            };
            window(len, &|i| b[at(i)], &mut |i, v| a[at(i)] = v);
        }
    }
    let candidates = a.into_iter().max().unwrap_or(0);
    let k = pp.n_star as u64;
    match method {
        Method::Knn if k > KNN_MAX as u64 => 33 * candidates,
        // A candidate enters the sorted list only while it is among the k nearest so far:
        // about k ln(n/k) insertions for particles in no particular order, each shifting at
        // most k entries.
        Method::Knn => candidates + k * k * ((candidates as f64 / k.max(1) as f64 + 1.0).ln().ceil() as u64),
        _ => candidates,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        assert_eq!(size_of::<GpuDensityParams>(), 80);
    }

    #[test]
    fn shader_constants_match() {
        assert!(DENSITY_WGSL.contains(&format!("const KNN_MAX: u32 = {KNN_MAX}u;")));
        assert!(DENSITY_WGSL.contains(&format!("const WORKGROUP_SIZE: u32 = {WORKGROUP_SIZE}u;")));
        assert!(DENSITY_WGSL.contains(&format!("const KAPPA: f32 = {:.1};", crate::kernel::KAPPA)));
    }
}
