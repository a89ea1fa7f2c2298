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
//!
//! conserve-mass adds the one pass that is not per voxel: `mass`, one invocation per particle
//! summing its kernel over the grid points of its support box. It reads the final lengths of
//! every proposed brick at once (a whole-grid buffer and a dense brick -> slot table, where the
//! other passes see one chunk), so the lengths come back to the host between the passes.

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::{storage_entry, params_entry, GpuContext, GpuError};
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
    particle_count: u32,
    plane_first: u32,
    plane_count: u32,
    attribute_stride: u32,
    attribute_group: u32,
    ici_rungs: u32,
    ici_h: [f32; 8],
}

/// The density kernels' source (every pass's pipeline): no volume, so not composed after it.
fn density_source() -> Result<String, GpuError> {
    Ok(nimbus_gpu::ShaderComposer::new().module("dispatch", nimbus_gpu::DISPATCH_WGSL).module("density", DENSITY_WGSL).build()?)
}

fn method_code(method: Method) -> u32 {
    match method {
        Method::Usl => 0,
        Method::Asl2 => 1,
        Method::Asl3 => 2,
        Method::Knn => 3,
        Method::Ici => 4,
    }
}

/// The passes each method runs, in order (WGSL entry points).
fn passes(method: Method) -> &'static [&'static str] {
    match method {
        Method::Usl => &["density"],
        Method::Asl2 => &["predict", "density"],
        Method::Asl3 => &["predict", "correct", "density"],
        Method::Knn => &["knn", "density"],
        // The ladder; the host's rule over the whole grid (ici.rs) gives the lengths, then the
        // density at them.
        Method::Ici => &["ladder", "density"],
    }
}

/// The uniforms every pass starts from (per-chunk and per-pass fields 0).
fn density_uniforms(prep: &Prepared, pp: &PointParams, method: Method) -> GpuDensityParams {
    let cells = &prep.cells;
    let (ladder, rungs) = crate::kernel::ici_ladder(pp.h_min, pp.h0);
    GpuDensityParams {
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
        particle_count: prep.positions.len() as u32,
        plane_first: 0,
        plane_count: 0,
        attribute_stride: 0,
        attribute_group: 0,
        ici_rungs: rungs as u32,
        ici_h: std::array::from_fn(|k| if k < rungs { ladder[k] } else { 0.0 }),
    }
}

/// The particles as the passes read them: index-space position and mass, cell-sorted.
fn particle_buffer(ctx: &GpuContext, prep: &Prepared) -> Result<wgpu::Buffer, GpuError> {
    let particles: Vec<[f32; 4]> = prep.positions.iter().zip(&prep.masses).map(|(p, &m)| [p.x, p.y, p.z, m]).collect();
    ctx.storage_buffer("density particles", &particles)
}

fn brick_buffer(ctx: &GpuContext, origins: &[glam::IVec3]) -> Result<wgpu::Buffer, GpuError> {
    let bricks: Vec<[i32; 4]> = origins.iter().map(|o| [o.x, o.y, o.z, 0]).collect();
    ctx.storage_buffer("density bricks", &bricks)
}

/// Runs the method's passes over every proposed brick, in chunks; bricks with no density are
/// dropped, the rest come back in proposal order.
///
/// With `conserve_mass` the passes before `density` run over every chunk first and their
/// lengths come back to the host; the `mass` pass then sums each particle's kernel over the
/// grid from them (a whole-grid buffer of lengths), the host turns the sums into masses m / S
/// ([`crate::normalised_masses`], shared with the CPU) and uploads them, and `density` runs
/// per chunk on the kept lengths.
pub(crate) fn estimate_bricks(ctx: &GpuContext, prep: &Prepared, method: Method, conserve_mass: bool, pp: &PointParams, keep: &Keep) -> Result<Vec<BrickResult>, GpuError> {
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
    // ici's ladder pass writes every rung's two sums per voxel into the rho buffer.
    let rho_floats = if method == Method::Ici { 2 * crate::kernel::ICI_MAX_RUNGS as u64 } else { 1 };
    let chunk_bricks = MAX_CHUNK_BRICKS.min((binding_limit / (4 * rho_floats * BRICK_VOXELS as u64)).max(1) as usize);
    // Progress counts bricks, a chunk's at its read-back; heard, in smaller chunks.
    let chunk_bricks = nimbus_progress::step_size(prep.bricks.len() as u64, chunk_bricks as u64, 1) as usize;
    let chunk_voxels = (chunk_bricks.min(prep.bricks.len()) * BRICK_VOXELS) as u64;

    let uniforms = density_uniforms(prep, pp, method);
    let params_buffer = ctx.params_buffer("density params", &uniforms)?;
    let particle_buffer = particle_buffer(ctx, prep)?;
    let cell_buffer = ctx.storage_buffer("density cells", &prep.cells.start)?;
    let brick_buffer = brick_buffer(ctx, &prep.bricks)?;
    let n0 = ctx.storage_buffer_zeroed("density n0", chunk_voxels * 4)?;
    let h = ctx.storage_buffer_zeroed("density h", chunk_voxels * 4)?;
    let rho = ctx.storage_buffer_zeroed("density rho", chunk_voxels * 4 * rho_floats)?;
    let used = ctx.storage_buffer_zeroed("density used", chunk_voxels * 4)?;

    let layout = ctx.bind_group_layout(
        "density",
        &[
            params_entry(0),
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
        &[&params_buffer, &particle_buffer, &cell_buffer, &brick_buffer, &n0, &h, &rho, &used],
    )?;
    let source = density_source()?;
    let pipelines = passes(method)
        .iter()
        .map(|&entry| Ok((entry, ctx.compute_pipeline(entry, &source, entry, &[&layout])?)))
        .collect::<Result<Vec<_>, GpuError>>()?;

    let mut results = Vec::new();
    // Reads a chunk's sums back as per-brick results (bricks with no density dropped).
    let collect = |chunk: usize, origins: &[glam::IVec3], results: &mut Vec<BrickResult>| -> Result<(), GpuError> {
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
        Ok(())
    };
    // Sets the uniforms for chunk `chunk` and runs `pipelines` over its voxels.
    let run = |chunk: usize, bricks: usize, pipelines: &[(&str, wgpu::ComputePipeline)]| -> Result<(), GpuError> {
        let mut chunk_uniforms = uniforms;
        chunk_uniforms.first_brick = (chunk * chunk_bricks) as u32;
        chunk_uniforms.voxel_count = (bricks * BRICK_VOXELS) as u32;
        ctx.queue.write_buffer(&params_buffer, 0, bytemuck::bytes_of(&chunk_uniforms));
        for (entry, pipeline) in pipelines {
            ctx.dispatch_1d(entry, pipeline, &[&group], (bricks * BRICK_VOXELS) as u64, WORKGROUP_SIZE)?;
        }
        Ok(())
    };
    let (length_passes, density_pass) = pipelines.split_at(pipelines.len() - 1);
    let chunks: Vec<&[glam::IVec3]> = prep.bricks.chunks(chunk_bricks).collect();
    // ici's rule reaches into the next brick and chunk: its ladder comes back to the host,
    // which chooses the lengths as for the CPU (ici.rs).
    if conserve_mass || method == Method::Ici {
        // The lengths of every proposed brick, 0 where nothing is evaluated (as the CPU keeps
        // them); usl's are h0 wherever the mass pass looks (inside the grid).
        let mut lengths = Vec::with_capacity(prep.bricks.len() * BRICK_VOXELS);
        let mut n0_all = Vec::new();
        let mut ladders = Vec::new();
        let (all, rungs) = crate::kernel::ici_ladder(pp.h_min, pp.h0);
        // usl's lengths are h0: nothing to compute, nothing to show.
        let task = (method != Method::Usl).then(|| nimbus_progress::task("smoothing lengths", prep.bricks.len() as u64));
        let advance = |bricks: usize| task.iter().for_each(|t| t.advance(bricks as u64));
        for (chunk, origins) in chunks.iter().enumerate() {
            let voxels = origins.len() * BRICK_VOXELS;
            if method == Method::Usl {
                lengths.resize(lengths.len() + voxels, pp.h0);
                continue;
            }
            run(chunk, origins.len(), length_passes)?;
            if method == Method::Ici {
                let raw: Vec<f32> = ctx.read_buffer(&rho)?;
                let n0_chunk: Vec<u32> = ctx.read_buffer(&n0)?;
                const R: usize = crate::kernel::ICI_MAX_RUNGS;
                for b in 0..origins.len() {
                    let at = |v: usize| (b * BRICK_VOXELS + v) * 2 * R;
                    let sums: Vec<[f32; BRICK_VOXELS]> = (0..rungs).map(|k| std::array::from_fn(|v| raw[at(v) + k])).collect();
                    let squares: Vec<[f32; BRICK_VOXELS]> = (0..rungs).map(|k| std::array::from_fn(|v| raw[at(v) + R + k])).collect();
                    let reached: [bool; BRICK_VOXELS] = std::array::from_fn(|v| n0_chunk[b * BRICK_VOXELS + v] > 0);
                    ladders.push(reached.iter().any(|&r| r).then(|| crate::ici::RungSums::from_sums(&all[..rungs], &sums, &squares, reached)));
                }
                n0_all.extend_from_slice(&n0_chunk[..voxels]);
                advance(origins.len());
                continue;
            }
            let h_chunk: Vec<f32> = ctx.read_buffer(&h)?;
            let n0_chunk: Vec<u32> = ctx.read_buffer(&n0)?;
            lengths.extend(h_chunk[..voxels].iter().zip(&n0_chunk[..voxels]).map(|(&h, &n)| if n > 0 { h } else { 0.0 }));
            n0_all.extend_from_slice(&n0_chunk[..voxels]);
            advance(origins.len());
        }
        drop(task);
        if method == Method::Ici {
            let kept = crate::ici::choose_lengths(prep, &all[..rungs], &ladders, pp.confidence);
            lengths = kept.into_iter().flat_map(|b| b.map_or([0.0; BRICK_VOXELS], |b| *b)).collect();
        }
        if conserve_mass {
            let sums = kernel_sums(ctx, prep, pp, &source, uniforms, &params_buffer, &particle_buffer, &lengths)?;
            let masses = crate::normalised_masses(prep, pp, &sums);
            let particles: Vec<[f32; 4]> = prep.positions.iter().zip(&masses).map(|(p, &m)| [p.x, p.y, p.z, m]).collect();
            ctx.queue.write_buffer(&particle_buffer, 0, bytemuck::cast_slice(&particles));
        }
        // The density pass reads each voxel's h and n0 (reached) from the chunk's buffers.
        if method != Method::Usl {
            let task = nimbus_progress::task("density", prep.bricks.len() as u64);
            for (chunk, origins) in chunks.iter().enumerate() {
                let span = chunk * chunk_bricks * BRICK_VOXELS..(chunk * chunk_bricks + origins.len()) * BRICK_VOXELS;
                ctx.queue.write_buffer(&h, 0, bytemuck::cast_slice(&lengths[span.clone()]));
                ctx.queue.write_buffer(&n0, 0, bytemuck::cast_slice(&n0_all[span]));
                run(chunk, origins.len(), density_pass)?;
                collect(chunk, origins, &mut results)?;
                task.advance(origins.len() as u64);
            }
            return Ok(results);
        }
    }

    let task = nimbus_progress::task("density", prep.bricks.len() as u64);
    for (chunk, origins) in chunks.iter().enumerate() {
        run(chunk, origins.len(), if conserve_mass { density_pass } else { &pipelines })?;
        collect(chunk, origins, &mut results)?;
        task.advance(origins.len() as u64);
    }
    Ok(results)
}

/// conserve-mass: each particle's kernel sum over the grid (the `mass` pass, one invocation
/// per particle) from the final `lengths` of every proposed brick, in proposal order.
#[allow(clippy::too_many_arguments)] // the pass's buffers, shared with the other passes
fn kernel_sums(
    ctx: &GpuContext,
    prep: &Prepared,
    pp: &PointParams,
    source: &str,
    mut uniforms: GpuDensityParams,
    params_buffer: &wgpu::Buffer,
    particle_buffer: &wgpu::Buffer,
    lengths: &[f32],
) -> Result<Vec<f64>, GpuError> {
    // The support's bounding box spans at most `side` grid points a side. A software adapter
    // ends an invocation's loops silently past its cap (an h0 of ~10 voxels already needs
    // 41^3 iterations), so there the box goes in slabs of z planes, a dispatch each.
    let side = (2.0 * crate::kernel::KAPPA * pp.h0).floor() as u32 + 1;
    let loops = |planes: u32| planes as u64 * (side as u64 * side as u64 + side as u64 + 1) + 1;
    let work = "a particle's kernel sum over a slab of its support box";
    let mut planes = side;
    while planes > 1 && ctx.check_loop_bound(loops(planes), work, "").is_err() {
        planes = planes.div_ceil(2);
    }
    ctx.check_loop_bound(loops(planes), work, "or a smaller --h0")?;

    let (slots, _) = crate::brick_slots(prep);
    let length_buffer = ctx.storage_buffer("density lengths", lengths)?;
    let slot_buffer = ctx.storage_buffer("density brick slots", &slots)?;
    let sum_buffer = ctx.storage_buffer_zeroed("density kernel sums", prep.positions.len() as u64 * 4)?;
    let particle_layout = ctx.bind_group_layout("density mass particles", &[params_entry(0), storage_entry(1, true)])?;
    let mass_layout = ctx.bind_group_layout("density mass", &[storage_entry(0, true), storage_entry(1, true), storage_entry(2, false)])?;
    let particle_group = ctx.buffer_bind_group("density mass particles", &particle_layout, &[params_buffer, particle_buffer])?;
    let mass_group = ctx.buffer_bind_group("density mass", &mass_layout, &[&length_buffer, &slot_buffer, &sum_buffer])?;
    let pipeline = ctx.compute_pipeline("mass", source, "mass", &[&particle_layout, &mass_layout])?;
    uniforms.plane_count = planes;
    for first in (0..side).step_by(planes as usize) {
        uniforms.plane_first = first;
        ctx.queue.write_buffer(params_buffer, 0, bytemuck::bytes_of(&uniforms));
        ctx.dispatch_1d("mass", &pipeline, &[&particle_group, &mass_group], prep.positions.len() as u64, WORKGROUP_SIZE)?;
    }
    Ok(ctx.read_buffer::<f32>(&sum_buffer)?.into_iter().map(f64::from).collect())
}

/// Channels one attribute dispatch sums: two vec4s per particle and voxel (WGSL
/// `acc_channels`).
const ATTRIBUTE_GROUP: usize = 8;

/// The attribute pass on the GPU (`attributes` in shaders/density.wgsl): the particles and
/// their channel values uploaded once, then [`Self::sums`] per slice of the bricks with
/// density, one dispatch per group of eight channels. A gather per voxel, as the density
/// pass, where the CPU splats per brick: the same kernel sums to summation order.
pub(crate) struct AttributePass<'a> {
    ctx: &'a GpuContext,
    uniforms: GpuDensityParams,
    params_buffer: wgpu::Buffer,
    particle_buffer: wgpu::Buffer,
    cell_buffer: wgpu::Buffer,
    value_buffer: wgpu::Buffer,
    channels: usize,
    layout: wgpu::BindGroupLayout,
    attribute_layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// Most bricks one dispatch covers (its sums buffer within the binding limit).
    chunk_bricks: usize,
}

impl<'a> AttributePass<'a> {
    /// `values`: `channels` floats per particle in [`Prepared`] order (attributes.rs
    /// channel_values).
    pub(crate) fn new(ctx: &'a GpuContext, prep: &Prepared, pp: &PointParams, values: &[f32], channels: usize) -> Result<Self, GpuError> {
        if ctx.loop_cap().is_some() {
            // Lengths never exceed h0: the density's widest gather bounds this one.
            ctx.check_loop_bound(longest_gather(prep, Method::Usl, pp), "a grid point's attribute gather (particles within kappa*h0)", "or a smaller --h0")?;
        }
        let groups = channels.div_ceil(ATTRIBUTE_GROUP);
        let stride = groups * ATTRIBUTE_GROUP;
        let mut padded = vec![0.0f32; prep.positions.len() * stride];
        for (out, v) in padded.chunks_mut(stride).zip(values.chunks(channels)) {
            out[..channels].copy_from_slice(v);
        }
        let mut uniforms = density_uniforms(prep, pp, Method::Usl);
        uniforms.attribute_stride = (stride / 4) as u32;
        let layout = ctx.bind_group_layout("density attributes particles", &[params_entry(0), storage_entry(1, true), storage_entry(2, true), storage_entry(3, true)])?;
        let attribute_layout = ctx.bind_group_layout("density attributes", &[storage_entry(3, true), storage_entry(4, true), storage_entry(5, false)])?;
        let source = density_source()?;
        let limits = ctx.limits();
        let binding_limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let sums_per_brick = (BRICK_VOXELS * ATTRIBUTE_GROUP * 4) as u64;
        Ok(AttributePass {
            ctx,
            uniforms,
            params_buffer: ctx.params_buffer("density attribute params", &uniforms)?,
            particle_buffer: particle_buffer(ctx, prep)?,
            cell_buffer: ctx.storage_buffer("density cells", &prep.cells.start)?,
            value_buffer: ctx.storage_buffer("density attribute values", &padded)?,
            channels,
            pipeline: ctx.compute_pipeline("attributes", &source, "attributes", &[&layout, &attribute_layout])?,
            layout,
            attribute_layout,
            chunk_bricks: MAX_CHUNK_BRICKS.min((binding_limit / sums_per_brick).max(1) as usize),
        })
    }

    /// Per brick of `bricks` (their final lengths kept), per channel: sum_q values[q][c] *
    /// m4_shape(r / h) over the particles within kappa*h of each voxel where the density is
    /// positive, 0 elsewhere (as cpu.rs splat_attributes).
    pub(crate) fn sums(&self, bricks: &[BrickResult]) -> Result<Vec<Vec<[f32; BRICK_VOXELS]>>, GpuError> {
        let ctx = self.ctx;
        let mut out: Vec<Vec<[f32; BRICK_VOXELS]>> = bricks.iter().map(|_| vec![[0.0; BRICK_VOXELS]; self.channels]).collect();
        for (chunk, slice) in bricks.chunks(self.chunk_bricks).enumerate() {
            let origins: Vec<glam::IVec3> = slice.iter().map(|b| b.origin).collect();
            let lengths: Vec<f32> = slice
                .iter()
                .flat_map(|b| {
                    let h = b.h.as_ref().expect("lengths kept for the attribute pass");
                    (0..BRICK_VOXELS).map(move |v| if b.rho[v] > 0.0 { h[v] } else { 0.0 })
                })
                .collect();
            let voxels = lengths.len();
            let brick_buffer = brick_buffer(ctx, &origins)?;
            let length_buffer = ctx.storage_buffer("density attribute lengths", &lengths)?;
            let sum_buffer = ctx.storage_buffer_zeroed("density attribute sums", (voxels * ATTRIBUTE_GROUP * 4) as u64)?;
            let group = ctx.buffer_bind_group("density attributes particles", &self.layout, &[&self.params_buffer, &self.particle_buffer, &self.cell_buffer, &brick_buffer])?;
            let entries: Vec<wgpu::BindGroupEntry> = [&self.value_buffer, &length_buffer, &sum_buffer]
                .iter()
                .zip(3..)
                .map(|(buffer, binding)| wgpu::BindGroupEntry { binding, resource: buffer.as_entire_binding() })
                .collect();
            let attribute_group = ctx.bind_group("density attributes", &self.attribute_layout, &entries)?;
            for g in 0..self.channels.div_ceil(ATTRIBUTE_GROUP) {
                let mut uniforms = self.uniforms;
                uniforms.voxel_count = voxels as u32;
                uniforms.attribute_group = g as u32;
                ctx.queue.write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&uniforms));
                ctx.dispatch_1d("attributes", &self.pipeline, &[&group, &attribute_group], voxels as u64, WORKGROUP_SIZE)?;
                let sums: Vec<f32> = ctx.read_buffer(&sum_buffer)?;
                for (b, brick) in out[chunk * self.chunk_bricks..][..slice.len()].iter_mut().enumerate() {
                    let group = g * ATTRIBUTE_GROUP..self.channels.min((g + 1) * ATTRIBUTE_GROUP);
                    for (k, channel) in brick[group].iter_mut().enumerate() {
                        for (v, value) in channel.iter_mut().enumerate() {
                            *value = sums[((b * BRICK_VOXELS + v) * ATTRIBUTE_GROUP) + k];
                        }
                    }
                }
            }
        }
        Ok(out)
    }
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
        // The ladder's inner loop over the rungs, per candidate.
        Method::Ici => candidates * (crate::kernel::ICI_MAX_RUNGS as u64 + 1),
        _ => candidates,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        let host = nimbus_gpu::host_layout!(GpuDensityParams {
            cell_origin,
            cell_edge,
            cell_dims,
            n_star,
            grid_dims,
            h0,
            h_min,
            relax,
            k,
            voxel_count,
            first_brick,
            method,
            particle_count,
            plane_first,
            plane_count,
            attribute_stride,
            attribute_group,
            ici_rungs,
            ici_h
        });
        nimbus_gpu::wgsl_layout::check_layouts(&density_source().unwrap(), &[("DensityUniforms", host)]);
    }

    #[test]
    fn shader_constants_match() {
        assert!(DENSITY_WGSL.contains(&format!("const KNN_MAX: u32 = {KNN_MAX}u;")));
        assert!(DENSITY_WGSL.contains(&format!("const ICI_MAX_RUNGS: u32 = {}u;", crate::kernel::ICI_MAX_RUNGS)));
        assert!(crate::kernel::ICI_MAX_RUNGS <= 8, "the uniforms hold eight rungs");
        assert!(DENSITY_WGSL.contains(&format!("const WORKGROUP_SIZE: u32 = {WORKGROUP_SIZE}u;")));
        assert!(DENSITY_WGSL.contains(&format!("const KAPPA: f32 = {:.1};", crate::kernel::KAPPA)));
        assert!(DENSITY_WGSL.contains(&format!("array<vec4<f32>, {}>", ATTRIBUTE_GROUP / 4)));
    }
}
