//! The GPU backend: one wgpu invocation per planned cache voxel (`shaders/cache.wgsl`), over
//! the same [`CachePlan`] and [`PhotonBins`] as the CPU backend.

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use nimbus_gpu::{storage_entry, uniform_entry, wgpu, GpuContext, GpuError, GpuVolume, GpuVolumeOptions, LoopGuard};
use nimbus_optics::{GpuLight, GpuMedium, OPTICS_WGSL};
use nimbus_photon::PhotonMap;
use nimbus_tracking::{majorant_buffer, GpuMajorantInfo, TRACKING_WGSL};
use nimbus_volume::{MajorantGrid, Volume};

use crate::cpu::{empty_ball_density, gather_cell, BALL_DIRECTIONS, BALL_SHELLS};
use crate::{BakeStats, CacheError, CacheParams, CachePlan, Gather, IlluminationCache, MultipleEstimator, PhotonBins};

/// The cache kernels, `shaders/cache.wgsl`.
pub const CACHE_WGSL: &str = include_str!("../../../shaders/cache.wgsl");

/// Largest `--gather-neighbours` the GPU backend takes: each invocation keeps its k nearest
/// in a fixed private array.
pub const GPU_MAX_NEIGHBOURS: u32 = 256;

const WORKGROUP_SIZE: u32 = 64;
/// Voxels per dispatch: bounds how long one submission runs (drivers reset long ones).
const CHUNK: u64 = 1 << 15;
/// Group 1 binding of the [`LoopGuard`] flag (after the 7 buffers).
const GUARD_BINDING: u32 = 7;

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
    _pad: [u32; 2],
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
}

/// The CPU's quadrature and the heap bound as WGSL constants, so the two cannot drift apart.
fn constants_wgsl() -> String {
    let shells: Vec<String> = BALL_SHELLS.iter().map(|s| format!("{s:?}")).collect();
    let dirs: Vec<String> = BALL_DIRECTIONS.iter().map(|d| format!("vec3<f32>({:?}, {:?}, {:?})", d[0], d[1], d[2])).collect();
    format!(
        "const CACHE_MAX_NEIGHBOURS: u32 = {GPU_MAX_NEIGHBOURS}u;\n\
         var<private> BALL_SHELLS: array<f32, 3> = array<f32, 3>({});\n\
         var<private> BALL_DIRECTIONS: array<vec3<f32>, 14> = array<vec3<f32>, 14>({});\n",
        shells.join(", "),
        dirs.join(", ")
    )
}

/// Bakes the cache on the GPU: the same plan, shadow rays, photon search and estimator as
/// [`crate::bake_cpu`], in f32.
pub fn bake_gpu(ctx: &GpuContext, density: &Volume<f32>, photons: &PhotonMap, params: &CacheParams) -> Result<(IlluminationCache, BakeStats), CacheError> {
    params.validate()?;
    let single = params.bakes_single();
    let multiple = params.bakes_multiple(photons);
    if multiple && matches!(params.estimator, MultipleEstimator::Paths { .. }) {
        return Err(CacheError::Param("path-traced multiple scattering runs on the CPU backend only so far (use --device cpu)".into()));
    }
    if let Gather::Neighbours { k, .. } = params.gather {
        if multiple && k > GPU_MAX_NEIGHBOURS {
            return Err(CacheError::Param(format!(
                "the GPU backend gathers at most {GPU_MAX_NEIGHBOURS} neighbours, got {k} (use --device cpu)"
            )));
        }
    }
    let majorant = MajorantGrid::build(density);
    let plan = CachePlan::new(density, &majorant, &params.camera, params.cache_scale);
    let mut stats = plan.stats.clone();
    let bins = multiple.then(|| PhotonBins::new(&photons.positions, gather_cell(photons, params.gather)));
    // Bin-local positions are then exactly the CPU's f32 values.
    let origin = match (&bins, density.world_bounds()) {
        (Some(b), _) => b.origin(),
        (None, Some((lo, hi))) => 0.5 * (lo + hi),
        (None, None) => DVec3::ZERO,
    };
    let positions = plan.voxel_positions();
    let baker = (!positions.is_empty() && (single || multiple))
        .then(|| GpuBaker::new(ctx, density, &majorant, photons, bins.as_ref(), params, origin, &positions))
        .transpose()?;

    let mut nonfinite = 0;
    let mut run = |entry: &str| -> Result<Volume<Vec3>, CacheError> {
        let out = match &baker {
            Some(b) => b.run(entry)?,
            None => Vec::new(),
        };
        let values: Vec<Vec3> = out.iter().map(|o| Vec3::from(o.li)).collect();
        let (volume, bad) = plan.volume_of(&values);
        nonfinite += bad;
        if entry == "bake_multiple" {
            stats.photons_gathered = out.iter().map(|o| o.used as u64).sum();
        }
        Ok(volume)
    };
    let li_single = single.then(|| run("bake_single")).transpose()?;
    let li_multiple = multiple.then(|| run("bake_multiple")).transpose()?;
    stats.nonfinite = nonfinite;
    Ok((IlluminationCache { li_single, li_multiple }, stats))
}

/// Everything uploaded once per bake.
struct GpuBaker<'a> {
    ctx: &'a GpuContext,
    layout: wgpu::BindGroupLayout,
    volume_layout: wgpu::BindGroupLayout,
    volume_group: wgpu::BindGroup,
    source: String,
    uniforms: GpuCacheParams,
    buffers: [wgpu::Buffer; 5],
    out: wgpu::Buffer,
    guard: LoopGuard,
    voxels: u64,
    _volume: GpuVolume,
}

impl<'a> GpuBaker<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        ctx: &'a GpuContext,
        density: &Volume<f32>,
        majorant: &MajorantGrid,
        photons: &PhotonMap,
        bins: Option<&PhotonBins>,
        params: &CacheParams,
        origin: DVec3,
        positions: &[DVec3],
    ) -> Result<Self, GpuError> {
        let mut volume = GpuVolume::upload(ctx, density, &GpuVolumeOptions::default())?;
        volume.set_world_origin(ctx, origin);
        let volume_layout = GpuVolume::bind_group_layout(ctx)?;
        let guard = LoopGuard::new(ctx, GUARD_BINDING)?;
        let volume_group = volume.bind_group(ctx, &volume_layout)?;
        let layout = ctx.bind_group_layout(
            "cache",
            &[
                uniform_entry(0),
                storage_entry(1, true),
                storage_entry(2, true),
                storage_entry(3, true),
                storage_entry(4, true),
                storage_entry(5, true),
                storage_entry(6, false),
                guard.layout_entry(),
            ],
        )?;
        let source = ctx.compose_shader(&format!(
            "{OPTICS_WGSL}\n{TRACKING_WGSL}\n{}\n{}\n{CACHE_WGSL}",
            constants_wgsl(),
            guard.wgsl(1)
        ));

        let lights: Vec<GpuLight> = params.lights.iter().map(|l| GpuLight::new(l, origin)).collect();
        let points: Vec<[f32; 4]> = positions.iter().map(|&p| (p - origin).as_vec3().extend(0.0).to_array()).collect();
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
            _pad: [0; 2],
        };
        let lights_buffer = if lights.is_empty() { ctx.storage_buffer("cache lights", &[GpuLight::zeroed()])? } else { ctx.storage_buffer("cache lights", &lights)? };
        let voxels = positions.len() as u64;
        Ok(GpuBaker {
            ctx,
            layout,
            volume_layout,
            volume_group,
            source,
            uniforms,
            buffers: [
                majorant_buffer(ctx, majorant)?,
                lights_buffer,
                ctx.storage_buffer("cache voxels", &points)?,
                ctx.storage_buffer("photon bin starts", &starts)?,
                ctx.storage_buffer("photons by bin", &sorted)?,
            ],
            out: ctx.storage_buffer_zeroed("cache values", voxels * size_of::<GpuOut>() as u64)?,
            guard,
            voxels,
            _volume: volume,
        })
    }

    /// Runs kernel `entry` over every voxel, in dispatches of [`CHUNK`], and reads back.
    fn run(&self, entry: &str) -> Result<Vec<GpuOut>, GpuError> {
        let ctx = self.ctx;
        let pipeline = ctx.compute_pipeline(entry, &self.source, entry, &[&self.volume_layout, &self.layout])?;
        let mut first = 0;
        while first < self.voxels {
            let count = (self.voxels - first).min(CHUNK);
            let uniforms = GpuCacheParams { first: first as u32, count: count as u32, ..self.uniforms };
            let uniform_buffer = ctx.uniform_buffer("cache params", &uniforms)?;
            let [a, b, c, d, e] = &self.buffers;
            let group = self.guard.buffer_bind_group(ctx, "cache", &self.layout, &[&uniform_buffer, a, b, c, d, e, &self.out])?;
            ctx.dispatch_1d(entry, &pipeline, &[&self.volume_group, &group], count, WORKGROUP_SIZE)?;
            first += count;
        }
        let work = match entry {
            "bake_single" => "a cache voxel's shadow rays",
            _ => "a cache voxel's photon search",
        };
        self.guard.check(ctx, work, "or a longer --step (shadow rays) or fewer --gather-neighbours")?;
        ctx.read_buffer(&self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        assert_eq!(size_of::<GpuCacheParams>(), 144);
        assert_eq!(size_of::<GpuPhoton>(), 48);
        assert_eq!(size_of::<GpuOut>(), 16);
    }
}
