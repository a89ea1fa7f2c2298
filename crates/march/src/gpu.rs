//! The GPU backend: one wgpu invocation per pixel (`shaders/march.wgsl`).

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, IVec3, Vec3, Vec4};
use nimbus_cache::IlluminationCache;
use nimbus_gpu::{storage_entry, params_entry, wgpu, GpuContext, GpuError, GpuVolume, GpuVolumeOptions};
use nimbus_optics::{split_u64, Environment, GpuCamera, GpuMedium};
use nimbus_tracking::{medium_stage, EmissionField, GpuEmission, GpuMajorantInfo, GpuMotion, MotionBlur};
use nimbus_volume::{MajorantGrid, Volume};

use crate::offsets::Offsets;
use crate::{assemble, Image, MarchError, MarchParams, MediumFields, RayResult};

/// Perlin noise and fBm, the WGSL twin of `nimbus_optics::noise` (`shaders/noise.wgsl`):
/// plain functions, no bindings, for any stage shader to concatenate.
pub const NOISE_WGSL: &str = include_str!("../../../shaders/noise.wgsl");
/// The march kernel, `shaders/march.wgsl`.
pub const MARCH_WGSL: &str = include_str!("../../../shaders/march.wgsl");

pub(crate) const WORKGROUP_SIZE: u32 = 64;
/// The bind group `shaders/emission.wgsl` sits at in the march and the reference (after the
/// density's and the stage's own).
pub(crate) const EMISSION_GROUP: u32 = 2;
/// Bind group of the velocity grid (nimbus_tracking::GpuMotion) in the march and the reference.
pub(crate) const MOTION_GROUP: u32 = 3;
/// Most pixels one dispatch marches (128 MiB of results): large images go in tiles, so the
/// result buffer stays within every device's storage-binding limit, read-back memory stays
/// bounded, and no single dispatch runs long enough to trip a desktop GPU's watchdog.

/// How the GPU backend reads the illumination cache.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CacheLookup {
    /// One hardware-filtered fetch per lookup where the device filters 32-bit float textures
    /// (design.md: hardware-filtered 3D textures); its weights are quantised to the
    /// filter's sub-texel precision (8 bits on common hardware and lavapipe), so a lookup
    /// is within about 1/256 of the local range of Li of the exact value. Exact where the
    /// device cannot filter.
    #[default]
    Filtered,
    /// Eight texel loads and trilinear weights in f32: agrees with the CPU to rounding.
    Exact,
}

/// Options of [`render_gpu_with`] that have no CPU counterpart.
#[derive(Clone, Debug)]
pub struct GpuMarchOptions {
    pub cache_lookup: CacheLookup,
    /// Most pixels per dispatch (further capped by the device's storage-binding limit).
    pub max_tile_pixels: u64,
}

impl GpuMarchOptions {
    /// Most pixels one dispatch marches by default (128 MiB of results): large images go in
    /// tiles, so the result buffer stays within every device's storage-binding limit,
    /// read-back memory stays bounded, and no single dispatch runs long enough to trip a
    /// desktop GPU's watchdog.
    pub const DEFAULT_MAX_TILE_PIXELS: u64 = 1 << 22;
}

impl Default for GpuMarchOptions {
    fn default() -> Self {
        GpuMarchOptions { cache_lookup: CacheLookup::default(), max_tile_pixels: Self::DEFAULT_MAX_TILE_PIXELS }
    }
}

/// WGSL `MarchUniforms`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuMarchParams {
    camera: GpuCamera,
    medium: GpuMedium,
    grid: GpuMajorantInfo,
    background: [f32; 3],
    step: f32,
    noise_base: [u32; 3],
    spp: u32,
    noise_offset: [f32; 3],
    noise_inv_scale: f32,
    seed: [u32; 2],
    noise_octaves: u32,
    noise_seed: u32,
    offset_noise: f32,
    min_transmittance: f32,
    flags: u32,
    width: u32,
    pixel_count: u32,
    /// Global index of the first pixel of this dispatch's tile.
    first_pixel: u32,
    /// Pixels in this tile.
    tile_pixels: u32,
    _pad: u32,
    /// The baked offset noise (crate::offsets): the eye's lattice index, nodes per world unit,
    /// the brick table's first brick and extent, and whether the noise is baked (else exact).
    offset_eye: [f32; 3],
    offset_per_world: f32,
    offset_lo: [i32; 3],
    offset_baked: u32,
    offset_dims: [i32; 3],
    _pad1: u32,
}

/// WGSL `PixelOut` (march.wgsl and reference.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct GpuPixel {
    single: [f32; 3],
    transmittance: f32,
    multiple: [f32; 3],
    depth: f32,
    /// The environment map seen through the volume (RayResult::behind).
    behind: [f32; 3],
    _pad: f32,
    /// The medium's own emission, attenuated (RayResult::emission).
    emission: [f32; 3],
    _pad1: f32,
}

/// `p / scale` split into a wrapping u32 lattice point and an f32 remainder, as noise.wgsl
/// takes positions (the CPU's perlin3 casts its f64 cell through i64 to u32).
fn noise_split(p: DVec3, scale: f64) -> ([u32; 3], [f32; 3]) {
    let q = p / scale;
    let cell = q.floor();
    let base = [cell.x as i64 as u32, cell.y as i64 as u32, cell.z as i64 as u32];
    (base, (q - cell).as_vec3().to_array())
}

/// What the shader's majorant walk reads for a cell of bound `majorant`: its step factor,
/// or the bound itself where it marks no medium (zero, negative or NaN).
fn cell_factor(params: &MarchParams, majorant: f32) -> f32 {
    if majorant > 0.0 {
        params.step_factor(majorant) as f32
    } else {
        majorant
    }
}

/// Renders the image on the GPU with the default [`GpuMarchOptions`] (hardware-filtered
/// cache lookups where the device can filter).
pub fn render_gpu(ctx: &GpuContext, density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams) -> Result<Image, MarchError> {
    render_gpu_with(ctx, density, cache, params, MediumFields::default(), &GpuMarchOptions::default())
}

/// Renders the image on the GPU, the twin of [`crate::render_cpu_with`]: the same rays,
/// random numbers, step lattice, majorant skipping, offset noise and early termination as
/// the CPU, in f32; with emission each sample also adds `T e(x) (1 - exp(-sigma_t dt)) /
/// sigma_t` (`shaders/emission.wgsl`); with motion blur each sample's time in the shutter
/// comes from the same stream and the lookups are at `x - t v(x)` (the velocity grid at
/// group 3), over the same dilated majorant.
pub fn render_gpu_with(
    ctx: &GpuContext,
    density: &Volume<f32>,
    cache: &IlluminationCache,
    params: &MarchParams,
    fields: MediumFields,
    options: &GpuMarchOptions,
) -> Result<Image, MarchError> {
    let MediumFields { emission, motion, direct_single } = fields;
    if direct_single.is_some() {
        // The shadow rays per sample are the CPU march's (vdbmarch takes the CPU for them).
        return Err(MarchError::Param("single scattering by shadow rays at each sample runs on the CPU march".into()));
    }
    params.validate()?;
    let (majorant, offsets) = crate::cpu::march_grids(density, params, motion);
    if ctx.loop_cap().is_some() {
        let steps = longest_march(density, &majorant, params);
        let work = format!("a pixel's march of up to {steps} steps ({} spp)", params.spp);
        ctx.check_loop_bound(steps.saturating_mul(ITERATIONS_PER_STEP), work, "or a longer --step")?;
    }
    let pixels = march_pixels(ctx, density, &majorant, offsets.as_ref(), cache, params, emission, motion, options)?;
    Ok(assemble(params, &pixels))
}

/// Loop iterations a march step costs on llvmpipe, whose loop cap (65535 per SIMD group,
/// [`GpuContext::loop_cap`]) counts the lookups' and noise loops' passes too: measured on
/// lavapipe, 10,000 steps ran whole and 15,000 did not (4.4 to 6.5 iterations a step, with
/// brick-sized majorant cells, when the DDA's own iterations were few).
const ITERATIONS_PER_STEP: u64 = 6;

/// An upper bound on the loop iterations one pixel takes, in march steps: spp times the
/// grid's diagonal over the step, plus the majorant cells a ray can cross. Each cell crossed
/// costs the DDA loop, the march's segment loop and its closing test, at most three
/// iterations, less than a sample step's (the lookups and noise loops) but no longer
/// negligible with cells of one or two voxels: counted as one step each.
fn longest_march(density: &Volume<f32>, majorant: &MajorantGrid, params: &MarchParams) -> u64 {
    let Some((lo, hi)) = density.world_bounds() else { return 0 };
    let samples = ((hi - lo).length() / params.step).ceil() + 1.0;
    // A straight ray crosses each cell plane of the grid at most once.
    let cells = f64::from(majorant.dims().element_sum()) + 1.0;
    ((samples + cells) * f64::from(params.spp)).min(u64::MAX as f64) as u64
}

fn march_pixels(
    ctx: &GpuContext,
    density: &Volume<f32>,
    majorant: &MajorantGrid,
    offsets: Option<&Offsets>,
    cache: &IlluminationCache,
    params: &MarchParams,
    emission: Option<&EmissionField>,
    motion: Option<&MotionBlur>,
    options: &GpuMarchOptions,
) -> Result<Vec<RayResult>, GpuError> {
    let camera = &params.camera;
    let pixel_count = camera.width() as u64 * camera.height() as u64;
    // Every position on the GPU is relative to the eye.
    let origin = camera.eye();

    let mut density_gpu = GpuVolume::upload(ctx, density, &GpuVolumeOptions::default())?;
    density_gpu.set_world_origin(ctx, origin);
    // An absent cache grid is bound as an empty volume and never read (flags).
    let single = GpuVolume::upload_or_empty(ctx, cache.li_single.as_ref(), origin)?;
    let multiple = GpuVolume::upload_or_empty(ctx, cache.li_multiple.as_ref(), origin)?;

    let filterable = ctx.float32_filterable();
    let volume_layout = GpuVolume::bind_group_layout(ctx)?;
    let mut entries = GpuVolume::layout_entries(0, filterable).to_vec();
    entries.extend(GpuVolume::layout_entries(4, filterable));
    entries.extend([params_entry(8), storage_entry(9, true), storage_entry(10, false), storage_entry(11, true), storage_entry(12, true), storage_entry(13, true)]);
    let layout = ctx.bind_group_layout("march", &entries)?;
    let filtered = options.cache_lookup == CacheLookup::Filtered;
    let source = march_source(filterable, filtered)?;
    let emission_layout = GpuEmission::layout(ctx)?;
    let motion_layout = GpuMotion::layout(ctx)?;
    let pipeline = ctx.compute_pipeline("march", &source, "march_pixels", &[&volume_layout, &layout, &emission_layout, &motion_layout])?;
    let emission = GpuEmission::upload(ctx, emission, origin)?;
    let emission_group = emission.bind_group(ctx, &emission_layout)?;
    let motion_group = GpuMotion::upload(ctx, motion, density, origin)?.bind_group(ctx, &motion_layout)?;

    let (noise_base, noise_offset) =
        if params.offset_noise > 0.0 { noise_split(origin, params.noise_scale) } else { ([0; 3], [0.0; 3]) };
    // The baked offset noise, the CPU's bake itself (an empty table where there is none).
    let (offset_table, offset_lo, offset_dims) = offsets.map_or((&[][..], IVec3::ZERO, IVec3::ZERO), |o| o.lattice.table());
    let offset_values = offsets.map_or(&[][..], |o| o.lattice.values());
    let offset_eye = offsets.map_or(DVec3::ZERO, |o| o.to_lattice(origin));
    let offset_table = ctx.storage_buffer("offset bricks", if offset_table.is_empty() { &[u32::MAX][..] } else { offset_table })?;
    let offset_values = ctx.storage_buffer("offsets", if offset_values.is_empty() { &[Vec4::ZERO][..] } else { offset_values })?;
    let uniforms = GpuMarchParams {
        camera: GpuCamera::new(camera, origin),
        medium: GpuMedium::from(&params.medium),
        grid: GpuMajorantInfo::new(majorant, cell_factor(params, density.background())),
        background: params.background.to_array(),
        step: params.step as f32,
        noise_base,
        spp: params.spp,
        noise_offset,
        noise_inv_scale: if params.offset_noise > 0.0 { (1.0 / params.noise_scale) as f32 } else { 0.0 },
        seed: split_u64(params.seed),
        noise_octaves: params.noise_octaves,
        noise_seed: params.seed as u32,
        offset_noise: params.offset_noise as f32,
        min_transmittance: params.min_transmittance as f32,
        flags: u32::from(cache.li_single.is_some()) | (u32::from(cache.li_multiple.is_some()) << 1),
        width: camera.width(),
        pixel_count: u32::try_from(pixel_count).map_err(|_| GpuError::TooLarge {
            what: "the image".into(),
            size: pixel_count,
            limit: u32::MAX as u64,
            limit_name: "u32 pixel index",
        })?,
        first_pixel: 0,
        tile_pixels: 0,
        _pad: 0,
        offset_eye: offset_eye.as_vec3().to_array(),
        offset_per_world: offsets.map_or(0.0, |o| o.per_world as f32),
        offset_lo: offset_lo.to_array(),
        offset_baked: u32::from(offsets.is_some()),
        offset_dims: offset_dims.to_array(),
        _pad1: 0,
    };
    // The march reads its cells' step factors where the walk reads bounds (0: empty, as a
    // zero bound is): `MarchParams::step_factor` once per cell, so both backends take the
    // same groups.
    let factors: Vec<f32> = majorant.values().iter().map(|&m| cell_factor(params, m)).collect();
    let majorant_buffer = if factors.is_empty() { ctx.storage_buffer("step factors", &[0f32])? } else { ctx.storage_buffer("step factors", &factors)? };
    // A map behind the volume (a uniform one is the constant background, added on the host).
    let behind = ctx.storage_buffer("march environment", &Environment::gpu_words(crate::visible_map(params.visible_environment())))?;
    let volume_group = density_gpu.bind_group(ctx, &volume_layout)?;
    // Progress in pixels, a tile's at its read-back; heard, in smaller tiles.
    let task = nimbus_progress::task("march", pixel_count);
    let max_tile_pixels = nimbus_progress::step_size(pixel_count, options.max_tile_pixels, u64::from(WORKGROUP_SIZE));
    let tiles = PixelTiles { pipeline: &pipeline, volume_group: &volume_group, later_groups: &[&emission_group, &motion_group], pixel_count, max_tile_pixels };
    tiles.run(ctx, 1, &|n| task.advance(n), |first, count, _, out| {
        let tile_uniforms = GpuMarchParams { first_pixel: first, tile_pixels: count, ..uniforms };
        let params_buffer = ctx.params_buffer("march params", &tile_uniforms)?;
        let mut group_entries = single.bind_group_entries(0).to_vec();
        group_entries.extend(multiple.bind_group_entries(4));
        group_entries.extend([
            wgpu::BindGroupEntry { binding: 8, resource: params_buffer.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 9, resource: majorant_buffer.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 10, resource: out.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 11, resource: behind.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 12, resource: offset_table.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 13, resource: offset_values.as_entire_binding() },
        ]);
        ctx.bind_group("march", &layout, &group_entries)
    })
}

/// A per-pixel kernel (one invocation per pixel writing a WGSL `PixelOut`) run over an image
/// in tiles of consecutive pixels: the result buffer stays within every device's
/// storage-binding limit, read-back memory stays bounded, and no single dispatch runs long
/// enough to trip a desktop GPU's watchdog.
pub(crate) struct PixelTiles<'a> {
    pub pipeline: &'a wgpu::ComputePipeline,
    /// Group 0: the density volume.
    pub volume_group: &'a wgpu::BindGroup,
    /// Groups 2 and up (the emission's).
    pub later_groups: &'a [&'a wgpu::BindGroup],
    pub pixel_count: u64,
    pub max_tile_pixels: u64,
}

impl PixelTiles<'_> {
    /// `group(first, count, pass, out)` makes group 1 for pass `pass` (of `passes` dispatches
    /// per tile, each seeing what the previous left in `out`) over the tile of `count` pixels
    /// from `first`, written to `out` from its start; `progress` hears each finished tile's
    /// pixel count.
    pub fn run(
        &self,
        ctx: &GpuContext,
        passes: u32,
        progress: &dyn Fn(u64),
        group: impl Fn(u32, u32, u32, &wgpu::Buffer) -> Result<wgpu::BindGroup, GpuError>,
    ) -> Result<Vec<RayResult>, GpuError> {
        let limits = ctx.limits();
        let binding_pixels = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) / size_of::<GpuPixel>() as u64;
        let tile = self.pixel_count.min(self.max_tile_pixels).min(binding_pixels).max(1);
        let out = ctx.storage_buffer_zeroed("pixels", tile * size_of::<GpuPixel>() as u64)?;
        let mut result = Vec::with_capacity(self.pixel_count as usize);
        let mut first = 0u64;
        while first < self.pixel_count {
            let count = tile.min(self.pixel_count - first);
            for pass in 0..passes {
                let group = group(first as u32, count as u32, pass, &out)?;
                let mut groups = vec![self.volume_group, &group];
                groups.extend_from_slice(self.later_groups);
                ctx.dispatch_1d("pixels", self.pipeline, &groups, count, WORKGROUP_SIZE)?;
            }
            let pixels: Vec<GpuPixel> = ctx.read_buffer(&out)?;
            result.extend(pixels[..count as usize].iter().map(|p| RayResult {
                single: Vec3::from(p.single),
                multiple: Vec3::from(p.multiple),
                transmittance: p.transmittance,
                depth: if p.depth >= 0.0 { p.depth } else { f32::INFINITY },
                emission: Vec3::from(p.emission),
                behind: Vec3::from(p.behind),
            }));
            progress(count);
            first += count;
        }
        Ok(result)
    }
}

/// The march kernel's source, on an adapter with or without FLOAT32_FILTERABLE, reading the
/// cache with filtered fetches or not ([`CacheLookup`]).
fn march_source(filterable: bool, cache_filtered: bool) -> Result<String, GpuError> {
    Ok(medium_stage(filterable, EMISSION_GROUP, Some(MOTION_GROUP))
        .module("CACHE_FILTERED", format!("const CACHE_FILTERED: bool = {cache_filtered};"))
        .module("noise", NOISE_WGSL)
        .module("march", MARCH_WGSL)
        .build()?)
}

#[cfg(test)]
impl GpuPixel {
    /// The layout of the pixels the march and the reference write (each its `PixelOut`).
    pub(crate) fn host_layout() -> nimbus_gpu::wgsl_layout::HostStruct {
        nimbus_gpu::host_layout!(GpuPixel { single, transmittance, multiple, depth, behind, _pad, emission, _pad1 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::MARCH_DOMAIN;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        for (filterable, cache_filtered) in [(false, false), (true, true)] {
            let mut mirrors = nimbus_tracking::wgsl_mirrors(&["Camera", "Medium", "MajorantGridInfo", "EmissionInfo", "MotionInfo", "VolumeInfo"]);
            mirrors.extend([
                (
                    "MarchUniforms",
                    nimbus_gpu::host_layout!(GpuMarchParams {
                        camera,
                        medium,
                        grid,
                        background,
                        step,
                        noise_base,
                        spp,
                        noise_offset,
                        noise_inv_scale,
                        seed,
                        noise_octaves,
                        noise_seed,
                        offset_noise,
                        min_transmittance,
                        flags,
                        width,
                        pixel_count,
                        first_pixel,
                        tile_pixels,
                        _pad,
                        offset_eye,
                        offset_per_world,
                        offset_lo,
                        offset_baked,
                        offset_dims,
                        _pad1
                    }),
                ),
                ("PixelOut", GpuPixel::host_layout()),
            ]);
            nimbus_gpu::wgsl_layout::check_layouts(&march_source(filterable, cache_filtered).unwrap(), &mirrors);
        }
    }

    #[test]
    fn the_shader_uses_the_cpu_random_domains() {
        assert!(MARCH_WGSL.contains(&format!("MARCH_DOMAIN: u32 = 0x{MARCH_DOMAIN:08x}u")));
        assert!(MARCH_WGSL.contains(&format!("GROUP_DOMAIN: u32 = 0x{:08x}u", crate::GROUP_DOMAIN)));
        assert!(nimbus_tracking::tracking_wgsl_moving(MOTION_GROUP).contains(&format!("MOTION_DOMAIN: u32 = 0x{:08x}u", crate::MOTION_DOMAIN)));
    }

    #[test]
    fn noise_positions_split_like_the_cpu_cell() {
        let (base, offset) = noise_split(DVec3::new(-2.5, 1e6 + 0.25, 3.0), 0.5);
        assert_eq!(base, [(-5i64) as u32, 2_000_000, 6]);
        assert_eq!(offset, [0.0, 0.5, 0.0]);
    }
}
