//! The GPU backend: one wgpu invocation per planned cache voxel (`shaders/cache.wgsl`), over
//! the same [`CachePlan`]s, [`PhotonBins`] and [`crate::PathPlan`] as the CPU backend;
//! path-traced Li_multiple through `shaders/path.wgsl`, the reference path tracer's paths;
//! the lights' tables built on the GPU ([`GpuLightTables`]) on the CPU's plans, looked up by
//! both, and read back for the transmittance grids.

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use nimbus_gpu::{storage_entry, params_entry, wgpu, GpuContext, GpuError, GpuVolume, GpuVolumeOptions, LoopGuard};
use nimbus_optics::{split_u64, Environment, GpuLight, GpuMedium};
use nimbus_photon::PhotonMap;
use nimbus_tracking::{light_tables_wgsl, long_path_loop_iterations, majorant_buffer, medium_stage, DensityMedium, EmissionField, GpuEmission, GpuLightTables, GpuMajorantInfo, PATH_WGSL};
use nimbus_volume::{MajorantGrid, Volume};

use crate::plan::Prologue;
use crate::cpu::{empty_ball_density, gather_cell, BALL_DIRECTIONS, BALL_SHELLS, CACHE_PATHS_DOMAIN};
use crate::multiple_lattice::bake_paths;
use crate::importance::MAX_ORIGINS_PER_VOXEL;
use crate::{
    transmittance_grids, BakeStats, CacheError, CacheParams, CachePlan, Gather, IlluminationCache, MultipleEstimator, PathMoments, PathPlan, PhotonBins,
    SOFTWARE_PATH_MAX_DEPTH,
};

/// The most collisions a path takes on `ctx`'s adapter: `params.path_max_depth`, cut to
/// [`SOFTWARE_PATH_MAX_DEPTH`] where the adapter has a loop cap.
fn path_max_depth(ctx: &GpuContext, params: &CacheParams) -> u32 {
    if ctx.loop_cap().is_some() {
        params.path_max_depth.min(SOFTWARE_PATH_MAX_DEPTH)
    } else {
        params.path_max_depth
    }
}

/// Albedo above which paths reach [`SOFTWARE_PATH_MAX_DEPTH`] often enough to matter: roulette
/// keeps one past it with probability albedo^509, 0.6% at 0.99 (the light it carries is more,
/// as in a dense medium those are the paths that stay lit).
const CUT_MATTERS_FROM_ALBEDO: f32 = 0.99;

/// The cache kernels, `shaders/cache.wgsl`.
pub const CACHE_WGSL: &str = include_str!("../../../shaders/cache.wgsl");

/// Largest `--gather-neighbours` the GPU backend takes: each invocation keeps its k nearest
/// in a fixed private array.
pub const GPU_MAX_NEIGHBOURS: u32 = 256;

const WORKGROUP_SIZE: u32 = 64;
/// The bind group `shaders/emission.wgsl` sits at (after the density's, the stage's own and
/// the lights' tables).
const EMISSION_GROUP: u32 = 3;

/// Group 1 binding of the [`LoopGuard`] flag (after the 11 buffers).
const GUARD_BINDING: u32 = 12;

/// WGSL `CacheUniforms`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuCacheParams {
    medium: GpuMedium,
    grid: GpuMajorantInfo,
    eye: [f32; 3],
    step: f32,
    bins_dims: [i32; 3],
    bins_cell: f32,
    first: u32,
    count: u32,
    light_count: u32,
    cutoff: f32,
    k: u32,
    radius: f32,
    radius_sq: f32,
    gather_mode: u32,
    max_shell: i32,
    empty_below: f32,
    seed: [u32; 2],
    max_depth: u32,
    first_path: u32,
    path_count: u32,
    _pad: [u32; 5],
}

/// WGSL `CachePhoton`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuPhoton {
    position: [f32; 3],
    index: u32,
    power: [f32; 3],
    _pad0: u32,
    dir: [f32; 3],
    _pad1: u32,
}

/// WGSL `CacheOut`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuOut {
    li: [f32; 3],
    used: u32,
    /// The paths' mean square (budget.rs's PathMoments); 0 for the other kernels.
    square: f32,
    _pad: [u32; 3],
}

/// PathMoments::halves of one voxel (`PathHalves`, its own buffer: only the paths fill it).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuHalves {
    sums: [f32; 16],
}

/// The CPU's quadrature, the heap bound and the paths' random-number domain as WGSL constants, so the two cannot drift apart.
fn constants_wgsl() -> String {
    let shells: Vec<String> = BALL_SHELLS.iter().map(|s| format!("{s:?}")).collect();
    let dirs: Vec<String> = BALL_DIRECTIONS.iter().map(|d| format!("vec3<f32>({:?}, {:?}, {:?})", d[0], d[1], d[2])).collect();
    format!(
        "const CACHE_MAX_NEIGHBOURS: u32 = {GPU_MAX_NEIGHBOURS}u;\n\
         const CACHE_PATHS_DOMAIN: u32 = {CACHE_PATHS_DOMAIN}u;\n\
         const CACHE_MAX_ORIGINS: u32 = {MAX_ORIGINS_PER_VOXEL}u;\n\
         var<private> BALL_SHELLS: array<f32, 3> = array<f32, 3>({});\n\
         var<private> BALL_DIRECTIONS: array<vec3<f32>, 14> = array<vec3<f32>, 14>({});\n",
        shells.join(", "),
        dirs.join(", ")
    )
}

/// The cache kernels' source, on an adapter with or without FLOAT32_FILTERABLE and a loop cap.
fn cache_source(filterable: bool, loop_guard: bool) -> Result<String, GpuError> {
    Ok(medium_stage(filterable, EMISSION_GROUP, None)
        .module("light_tables", light_tables_wgsl())
        .module("path", PATH_WGSL)
        .module("cache constants", constants_wgsl())
        .module("loop guard", LoopGuard::wgsl_for(loop_guard, 1, GUARD_BINDING))
        .module("cache", CACHE_WGSL)
        .build()?)
}

/// Bakes the cache on the GPU: the same plans, light tables, shadow rays, photon search,
/// paths and estimators as [`crate::bake_cpu`], in f32.
pub fn bake_gpu(ctx: &GpuContext, density: &Volume<f32>, photons: &PhotonMap, params: &CacheParams) -> Result<(IlluminationCache, BakeStats), CacheError> {
    bake_gpu_emitting(ctx, density, photons, params, None)
}

/// [`bake_gpu`] with the medium's emission, the twin of [`crate::bake_cpu_emitting`]: the
/// paths gather it at every collision (path.wgsl with `shaders/emission.wgsl` at group 3).
pub fn bake_gpu_emitting(
    ctx: &GpuContext,
    density: &Volume<f32>,
    photons: &PhotonMap,
    params: &CacheParams,
    emission: Option<&EmissionField>,
) -> Result<(IlluminationCache, BakeStats), CacheError> {
    let Prologue { emission, majorant, mut timed } = Prologue::new(density, params, emission)?;
    let emits = emission.is_some();
    let single = params.bakes_single();
    let multiple = params.bakes_multiple(photons, emits);
    let gathers = multiple && params.estimator == MultipleEstimator::Photons;
    if let Gather::Neighbours { k, .. } = params.gather {
        if gathers && k > GPU_MAX_NEIGHBOURS {
            return Err(CacheError::Param(format!(
                "the GPU backend gathers at most {GPU_MAX_NEIGHBOURS} neighbours, got {k} (use --device cpu)"
            )));
        }
    }
    let bins = gathers.then(|| PhotonBins::new(&photons.positions, gather_cell(photons, params.gather)));
    // Bin-local positions are then exactly the CPU's f32 values.
    let origin = match (&bins, density.world_bounds()) {
        (Some(b), _) => b.origin(),
        (None, Some((lo, hi))) => 0.5 * (lo + hi),
        (None, None) => DVec3::ZERO,
    };
    let lattice = params.light_lattice(photons, emits);
    // The CPU tables the lights whenever something reads them, baked voxels or not (the
    // transmittance grids are view-independent): so does this.
    let volume = (single || multiple || lattice.is_some())
        .then(|| -> Result<GpuVolume, GpuError> {
            let mut volume = GpuVolume::upload(ctx, density, &GpuVolumeOptions::default())?;
            volume.set_world_origin(ctx, origin);
            Ok(volume)
        })
        .transpose()?;
    let medium = DensityMedium { motion: None, density, majorant: &majorant, extinction: params.medium.extinction };
    // Read back at once (which waits for the build): Li_single's lattice and the
    // transmittance grids need them.
    let (tables, depths) = timed.time("light tables", || -> Result<_, GpuError> {
        Ok(match (lattice, &volume) {
            (Some(lattice), Some(volume)) => {
                let tables = GpuLightTables::build(ctx, volume, medium, &params.lights, lattice, params.opaque_depth(), origin)?;
                let depths = tables.read(ctx)?;
                (tables, depths)
            }
            _ => (GpuLightTables::none(ctx, params.lights.len())?, Default::default()),
        })
    })?;
    // The host chooses the lattice and plans the voxels by the CPU's very rule.
    let (plan, own_plan, mut stats) = CachePlan::for_bake(medium, params, &depths, photons, emits, timed);
    let multiple_plan = own_plan.as_ref().unwrap_or(&plan);
    let work = (single && plan.stats.baked > 0) || (multiple && multiple_plan.stats.baked > 0);
    stats.light_table_nodes = tables.nodes();
    let baker = match &volume {
        Some(volume) if work => Some(GpuBaker::new(ctx, density, volume, &majorant, photons, bins.as_ref(), &tables, emission, params, origin)?),
        _ => None,
    };

    let mut nonfinite = 0;
    let mut run = |kernel: Kernel<'_>, plan: &CachePlan| -> Result<Volume<Vec3>, CacheError> {
        let out = match &baker {
            Some(b) => b.run(kernel, &plan.voxel_positions())?.0,
            None => Vec::new(),
        };
        let values: Vec<Vec3> = out.iter().map(|o| Vec3::from(o.li)).collect();
        let (volume, bad) = plan.volume_of(&values);
        nonfinite += bad;
        let used = out.iter().map(|o| o.used as u64).sum();
        match kernel {
            Kernel::Single => {}
            Kernel::Photons => stats.photons_gathered = used,
            Kernel::Paths(..) => unreachable!("the paths run through budget::trace_first and top_up"),
        }
        Ok(volume)
    };
    let li_single = single.then(|| run(Kernel::Single, &plan)).transpose()?;
    let li_multiple = match params.estimator {
        _ if !multiple => None,
        // The paths, their counts and origins, and the lattice, are decided on the host by
        // the CPU's very rule (multiple_lattice.rs).
        MultipleEstimator::Paths { per_voxel } => {
            let cut = path_max_depth(ctx, params);
            if cut < params.path_max_depth && params.medium.albedo.max_element() >= CUT_MATTERS_FROM_ALBEDO {
                stats.paths_cut_at = Some(cut);
            }
            let trace = |_: &str, voxels: &CachePlan, p: &PathPlan, seed: u64| -> Result<Vec<PathMoments>, CacheError> {
                let Some(b) = &baker else { return Ok(Vec::new()) };
                let (out, halves) = b.run(Kernel::Paths(p, seed), &voxels.voxel_positions())?;
                Ok(out.iter().zip(&halves).map(|(o, h)| PathMoments { mean: Vec3::from(o.li), mean_square: o.square, halves: h.sums }).collect())
            };
            let (volume, bad) = bake_paths(multiple_plan, density, &majorant, params, per_voxel, li_single.as_ref(), &mut stats, trace)?;
            nonfinite += bad;
            Some(volume)
        }
        MultipleEstimator::Photons => Some(run(Kernel::Photons, multiple_plan)?),
    };
    stats.nonfinite = nonfinite;
    let transmittance = stats.time("transmittance grids", || transmittance_grids(density, &depths));
    Ok((IlluminationCache { li_single, li_multiple, transmittance }, stats))
}

/// What one [`GpuBaker::run`] bakes.
#[derive(Clone, Copy)]
enum Kernel<'a> {
    /// Li_single (`bake_single`).
    Single,
    /// Li_multiple from the photons (`bake_multiple`).
    Photons,
    /// Li_multiple by the plan's paths (`seed_paths`, then `bake_paths` in passes of as many
    /// paths as the adapter's [`nimbus_gpu::DispatchSizing`] allows).
    Paths(&'a PathPlan, u64),
}

impl Kernel<'_> {
    /// The progress task's name, the CPU's.
    fn name(self) -> &'static str {
        match self {
            Kernel::Single => "single scattering",
            Kernel::Photons => "photon gather",
            Kernel::Paths(..) => "paths",
        }
    }
}

/// Bytes of one WGSL `Rng` in a storage array (vec2, vec4, vec4, u32; 16-byte aligned).
const GPU_RNG_BYTES: u64 = 64;

/// Everything uploaded once per bake.
struct GpuBaker<'a> {
    ctx: &'a GpuContext,
    layout: wgpu::BindGroupLayout,
    volume_layout: wgpu::BindGroupLayout,
    volume_group: wgpu::BindGroup,
    source: String,
    uniforms: GpuCacheParams,
    origin: DVec3,
    /// The majorant for the Simpson shadow rays, and lights, bin starts, photons by bin.
    majorant: wgpu::Buffer,
    buffers: [wgpu::Buffer; 3],
    /// The environment the paths gather (Environment::gpu_words).
    environment: wgpu::Buffer,
    /// The paths' majorant (MajorantGrid::for_tracking), where paths are traced, and the
    /// loop iterations of a long path through it (nimbus_tracking::long_path_loop_iterations).
    tracking: Option<(wgpu::Buffer, GpuMajorantInfo, u64)>,
    /// The lights' tables at group 2.
    tables_layout: wgpu::BindGroupLayout,
    tables_group: wgpu::BindGroup,
    /// The medium's emission at group 3 ([`EMISSION_GROUP`]).
    emission_layout: wgpu::BindGroupLayout,
    emission_group: wgpu::BindGroup,
    guard: LoopGuard,
}

impl<'a> GpuBaker<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        ctx: &'a GpuContext,
        density: &Volume<f32>,
        volume: &GpuVolume,
        majorant: &MajorantGrid,
        photons: &PhotonMap,
        bins: Option<&PhotonBins>,
        tables: &GpuLightTables,
        emission: Option<&EmissionField>,
        params: &CacheParams,
        origin: DVec3,
    ) -> Result<Self, GpuError> {
        let volume_layout = GpuVolume::bind_group_layout(ctx)?;
        let guard = LoopGuard::new(ctx, GUARD_BINDING)?;
        let volume_group = volume.bind_group(ctx, &volume_layout)?;
        let layout = ctx.bind_group_layout(
            "cache",
            &[
                params_entry(0),
                storage_entry(1, true),
                storage_entry(2, true),
                storage_entry(3, true),
                storage_entry(4, true),
                storage_entry(5, true),
                storage_entry(6, false),
                storage_entry(7, false),
                storage_entry(8, true),
                storage_entry(9, true),
                storage_entry(10, true),
                storage_entry(11, false),
                guard.layout_entry(),
            ],
        )?;
        let tables_layout = GpuLightTables::layout(ctx)?;
        let tables_group = tables.bind_group(ctx, &tables_layout)?;
        let emission_layout = GpuEmission::layout(ctx)?;
        let emission_group = GpuEmission::upload(ctx, emission, origin)?.bind_group(ctx, &emission_layout)?;
        let source = cache_source(ctx.float32_filterable(), guard.enabled())?;

        let lights: Vec<GpuLight> = params.lights.iter().map(|l| GpuLight::new(l, origin)).collect();
        let (starts, sorted, dims, cell) = match bins {
            Some(b) => {
                let sorted: Vec<GpuPhoton> = b
                    .order()
                    .iter()
                    .zip(b.local_positions())
                    .map(|(&i, l)| GpuPhoton {
                        position: l.to_array(),
                        index: i,
                        power: photons.power[i as usize].to_array(),
                        dir: photons.dir[i as usize].to_array(),
                        ..Zeroable::zeroed()
                    })
                    .collect();
                (b.starts().to_vec(), sorted, b.dims(), b.cell())
            }
            None => (vec![0, 0], vec![GpuPhoton::zeroed()], glam::IVec3::ONE, 1.0),
        };
        let (k, radius, gather_mode) = match params.gather {
            Gather::Neighbours { k, max_radius } => (k, max_radius, 0),
            Gather::Radius(r) => (0, r, 1),
        };
        // The same cap in the kernel and in the dispatch's bound on a long path.
        let max_depth = path_max_depth(ctx, params);
        let uniforms = GpuCacheParams {
            medium: GpuMedium::from(&params.medium),
            grid: GpuMajorantInfo::new(majorant, density.background()),
            eye: (params.camera.eye() - origin).as_vec3().to_array(),
            step: params.single_step(density) as f32,
            bins_dims: dims.to_array(),
            bins_cell: cell as f32,
            first: 0,
            count: 0,
            light_count: lights.len() as u32,
            cutoff: params.min_transmittance as f32,
            k,
            radius: radius as f32,
            radius_sq: (radius * radius) as f32,
            gather_mode,
            max_shell: (radius / cell).ceil() as i32 + 1,
            empty_below: empty_ball_density(majorant) as f32,
            seed: split_u64(params.seed),
            max_depth,
            first_path: 0,
            path_count: 0,
            _pad: [0; 5],
        };
        let tracking = match params.estimator {
            MultipleEstimator::Paths { .. } if params.bakes_multiple(photons, emission.is_some()) => {
                let grid = MajorantGrid::for_tracking(density, params.medium.extinction);
                let edge = density.transform().voxel_size().max_element();
                let longest = long_path_loop_iterations(&grid, edge, &params.medium, params.lights.len(), params.environment.is_some(), max_depth);
                Some((majorant_buffer(ctx, &grid)?, GpuMajorantInfo::new(&grid, density.background()), longest))
            }
            _ => None,
        };
        let lights_buffer = if lights.is_empty() { ctx.storage_buffer("cache lights", &[GpuLight::zeroed()])? } else { ctx.storage_buffer("cache lights", &lights)? };
        Ok(GpuBaker {
            ctx,
            layout,
            volume_layout,
            volume_group,
            source,
            uniforms,
            origin,
            majorant: majorant_buffer(ctx, majorant)?,
            buffers: [lights_buffer, ctx.storage_buffer("photon bin starts", &starts)?, ctx.storage_buffer("photons by bin", &sorted)?],
            environment: ctx.storage_buffer("cache environment", &Environment::gpu_words(params.environment.as_ref()))?,
            tracking,
            tables_layout,
            tables_group,
            emission_layout,
            emission_group,
            guard,
        })
    }

    /// Runs `kernel` over the voxels at `positions`, in dispatches of as many voxels and
    /// paths as the adapter's [`nimbus_gpu::DispatchSizing`] allows, and reads back.
    /// The voxels' results, and for the paths their halves (else empty).
    fn run(&self, kernel: Kernel<'_>, positions: &[DVec3]) -> Result<(Vec<GpuOut>, Vec<GpuHalves>), GpuError> {
        let ctx = self.ctx;
        let voxels = positions.len() as u64;
        if voxels == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let points: Vec<[f32; 4]> = positions.iter().map(|&p| (p - self.origin).as_vec3().extend(0.0).to_array()).collect();
        let points = ctx.storage_buffer("cache voxels", &points)?;
        let out = match kernel {
            // Each voxel's path count goes in with its zero sum.
            Kernel::Paths(paths, _) => ctx.storage_buffer("cache values", &paths.counts.iter().map(|&used| GpuOut { li: [0.0; 3], used, square: 0.0, _pad: [0; 3] }).collect::<Vec<_>>())?,
            _ => ctx.storage_buffer_zeroed("cache values", voxels * size_of::<GpuOut>() as u64)?,
        };
        // Where each voxel's paths start (one dummy each for the other kernels: bindings
        // cannot be empty). u32 offsets suffice: 2^32 origins would be 64 GiB, past any
        // storage binding, and the upload fails on its size first.
        let (path_first, path_origins) = match kernel {
            Kernel::Paths(paths, _) if !paths.origins.is_empty() => (
                paths.first.iter().map(|&f| f as u32).collect(),
                paths.origins.iter().zip(&paths.octants).map(|(&p, &o)| (p - self.origin).as_vec3().extend(o as f32).to_array()).collect(),
            ),
            _ => (vec![0u32], vec![[0f32; 4]]),
        };
        let path_first = ctx.storage_buffer("cache path firsts", &path_first)?;
        let path_origins = ctx.storage_buffer("cache path origins", &path_origins)?;
        let halves_size = size_of::<GpuHalves>() as u64 * if matches!(kernel, Kernel::Paths(..)) { voxels } else { 1 };
        let halves = ctx.storage_buffer_zeroed("cache path halves", halves_size)?;
        // (entry, first path) in order; the same voxels' state passes between them in `out`
        // and the Rng buffer.
        let sizing = ctx.dispatch;
        let chunk = match kernel {
            Kernel::Paths(..) => sizing.items,
            _ => nimbus_progress::step_size(voxels, sizing.items, u64::from(WORKGROUP_SIZE)),
        };
        let mut per_dispatch = 1;
        let (passes, rng_bytes, uniforms, majorant, work, remedy): (Vec<(&str, u32)>, u64, GpuCacheParams, &wgpu::Buffer, &str, &str) = match kernel {
            Kernel::Single => (vec![("bake_single", 0)], GPU_RNG_BYTES, self.uniforms, &self.majorant, "a cache voxel's shadow rays", "or a longer --step"),
            Kernel::Photons => (vec![("bake_multiple", 0)], GPU_RNG_BYTES, self.uniforms, &self.majorant, "a cache voxel's photon search", "or fewer --gather-neighbours"),
            Kernel::Paths(paths, seed) => {
                assert_eq!(paths.counts.len() as u64, voxels, "one path count per voxel");
                let (buffer, grid, longest) = self.tracking.as_ref().expect("the tracking majorant is uploaded where paths are traced");
                let most = paths.counts.iter().copied().max().unwrap_or(0);
                per_dispatch = sizing.repeats(chunk.min(voxels), *longest);
                let passes = std::iter::once(("seed_paths", 0)).chain((0..most).step_by(per_dispatch as usize).map(|p| ("bake_paths", p))).collect();
                let uniforms = GpuCacheParams { grid: *grid, seed: split_u64(seed), path_count: per_dispatch, ..self.uniforms };
                (passes, voxels * GPU_RNG_BYTES, uniforms, buffer, "a cache voxel's paths", "or a longer --step")
            }
        };
        let rngs = ctx.storage_buffer_zeroed("cache path rngs", rng_bytes)?;
        // Progress in the CPU's units: voxels, or for the paths the paths traced (up to
        // `per_dispatch` a voxel a `bake_paths` pass).
        let done = |entry: &str, first_path: u32, range: std::ops::Range<usize>| -> u64 {
            match kernel {
                Kernel::Paths(paths, _) if entry == "bake_paths" => {
                    paths.counts[range].iter().map(|&c| u64::from(c.saturating_sub(first_path).min(per_dispatch))).sum()
                }
                Kernel::Paths(..) => 0,
                _ => range.len() as u64,
            }
        };
        let total = match kernel {
            Kernel::Paths(paths, _) => paths.counts.iter().map(|&c| u64::from(c)).sum(),
            _ => voxels,
        };
        let task = nimbus_progress::task(kernel.name(), total);
        // Heard, the host waits for the GPU about STEPS times a kernel, as the work done
        // reaches each step; the paths' passes are steps enough, the one-pass kernels go in
        // smaller dispatches.
        let every = total.div_ceil(nimbus_progress::STEPS).max(1);
        let mut pending = 0;
        // A paths pass need not visit chunks whose voxels have all run out of paths: the
        // passes run to the largest count, which one voxel the camera reads closely can set.
        let chunk_most: Vec<u32> = match kernel {
            Kernel::Paths(paths, _) => paths.counts.chunks(chunk as usize).map(|c| c.iter().copied().max().unwrap_or(0)).collect(),
            _ => Vec::new(),
        };
        let mut pipelines: Vec<(&str, wgpu::ComputePipeline)> = Vec::new();
        for &(entry, first_path) in &passes {
            if !pipelines.iter().any(|(e, _)| *e == entry) {
                pipelines.push((entry, ctx.compute_pipeline(entry, &self.source, entry, &[&self.volume_layout, &self.layout, &self.tables_layout, &self.emission_layout])?));
            }
            let pipeline = &pipelines.iter().find(|(e, _)| *e == entry).expect("compiled above").1;
            let mut first = 0;
            while first < voxels {
                let count = (voxels - first).min(chunk);
                if entry == "bake_paths" && chunk_most[(first / chunk) as usize] <= first_path {
                    first += count;
                    continue;
                }
                let dispatch = GpuCacheParams { first: first as u32, count: count as u32, first_path, ..uniforms };
                let params_buffer = ctx.params_buffer("cache params", &dispatch)?;
                let [lights, starts, sorted] = &self.buffers;
                let group = self.guard.buffer_bind_group(
                    ctx,
                    "cache",
                    &self.layout,
                    &[&params_buffer, majorant, lights, &points, starts, sorted, &out, &rngs, &path_first, &path_origins, &self.environment, &halves],
                )?;
                ctx.dispatch_1d(entry, pipeline, &[&self.volume_group, &group, &self.tables_group, &self.emission_group], count, WORKGROUP_SIZE)?;
                pending += done(entry, first_path, first as usize..(first + count) as usize);
                if task.shown() && pending >= every {
                    ctx.wait()?;
                    task.advance(std::mem::take(&mut pending));
                }
                first += count;
            }
        }
        self.guard.check(ctx, work, remedy)?;
        let values = ctx.read_buffer(&out)?;
        let halves: Vec<GpuHalves> = if matches!(kernel, Kernel::Paths(..)) { ctx.read_buffer(&halves)? } else { Vec::new() };
        task.advance(pending);
        Ok((values, halves))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shader_spreads_as_many_rays_over_a_sun_disc() {
        assert!(CACHE_WGSL.contains(&format!("const SUN_DISC_RAYS: u32 = {}u;", crate::cpu::SUN_DISC_RAYS)));
    }

    #[test]
    fn layouts_match_the_wgsl_structs() {
        use nimbus_gpu::host_layout;
        for (filterable, loop_guard) in [(false, false), (true, true)] {
            let mut mirrors = nimbus_tracking::wgsl_mirrors(&["Medium", "Light", "MajorantGridInfo", "LightTable", "EmissionInfo", "VolumeInfo"]);
            mirrors.extend([
                (
                    "CacheUniforms",
                    host_layout!(GpuCacheParams {
                        medium,
                        grid,
                        eye,
                        step,
                        bins_dims,
                        bins_cell,
                        first,
                        count,
                        light_count,
                        cutoff,
                        k,
                        radius,
                        radius_sq,
                        gather_mode,
                        max_shell,
                        empty_below,
                        seed,
                        max_depth,
                        first_path,
                        path_count,
                        _pad
                    }),
                ),
                ("CachePhoton", host_layout!(GpuPhoton { position, index, power, _pad0, dir, _pad1 })),
                ("CacheOut", host_layout!(GpuOut { li, used, square, _pad })),
                ("PathHalves", host_layout!(GpuHalves { sums })),
            ]);
            nimbus_gpu::wgsl_layout::check_layouts(&cache_source(filterable, loop_guard).unwrap(), &mirrors);
        }
    }
}
