//! The reference path tracer on the GPU: one invocation per pixel (`shaders/reference.wgsl`).

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::{storage_entry, params_entry, GpuContext, GpuError, GpuVolume, GpuVolumeOptions, LoopGuard};
use nimbus_optics::{split_u64, Environment, GpuCamera, GpuLight, GpuMedium};
use nimbus_tracking::{majorant_buffer, medium_stage, GpuEmission, GpuMajorantInfo, GpuMotion, NO_LIGHT_TABLES_WGSL, PATH_WGSL};
use nimbus_volume::Volume;

use super::ReferenceParams;
use crate::gpu::{PixelTiles, EMISSION_GROUP, MOTION_GROUP};
use crate::{GpuMarchOptions, Image, MarchError, MediumFields};

/// The reference kernel, `shaders/reference.wgsl`.
pub const REFERENCE_WGSL: &str = include_str!("../../../../shaders/reference.wgsl");

/// WGSL `ReferenceUniforms`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuReferenceParams {
    camera: GpuCamera,
    medium: GpuMedium,
    grid: GpuMajorantInfo,
    background: [f32; 3],
    spp: u32,
    seed: [u32; 2],
    max_depth: u32,
    light_count: u32,
    width: u32,
    first_pixel: u32,
    tile_pixels: u32,
    first_sample: u32,
    sample_count: u32,
    map_visible: u32,
    _pad: [u32; 2],
}

/// Samples per pixel per dispatch (see reference.wgsl: lavapipe's loop limit).
const SAMPLES_PER_DISPATCH: u32 = 4;
/// Group 1 binding of the [`LoopGuard`] flag.
const GUARD_BINDING: u32 = 5;

/// Renders the reference on the GPU (tiles of at most `max_tile_pixels`: keep them small
/// for high spp on a desktop GPU, whose watchdog ends long dispatches); `progress` hears each
/// finished tile's pixel count.
pub fn render_reference_gpu(
    ctx: &GpuContext,
    density: &Volume<f32>,
    params: &ReferenceParams,
    max_tile_pixels: u64,
    progress: &dyn Fn(u64),
) -> Result<Image, MarchError> {
    render_reference_gpu_with(ctx, density, params, MediumFields::default(), max_tile_pixels, progress)
}

/// [`render_reference_gpu`] with what the medium holds beyond its density, the twin of
/// [`crate::render_reference_cpu_with`]: emission (path.wgsl's collision estimator) and motion
/// blur (each sample traces the medium at its own time in the shutter, motion.wgsl with the
/// velocity grid at group 3, over the same dilated majorant).
pub fn render_reference_gpu_with(
    ctx: &GpuContext,
    density: &Volume<f32>,
    params: &ReferenceParams,
    fields: MediumFields,
    max_tile_pixels: u64,
    progress: &dyn Fn(u64),
) -> Result<Image, MarchError> {
    let MediumFields { emission, motion, .. } = fields;
    params.validate()?;
    let camera = &params.camera;
    let pixel_count = camera.width() as u64 * camera.height() as u64;
    // Every position on the GPU is relative to the eye.
    let origin = camera.eye();
    let majorant = super::reference_majorant(density, params, motion);
    let mut volume = GpuVolume::upload(ctx, density, &GpuVolumeOptions::default())?;
    volume.set_world_origin(ctx, origin);
    let volume_layout = GpuVolume::bind_group_layout(ctx)?;
    let guard = LoopGuard::new(ctx, GUARD_BINDING)?;
    let layout = ctx.bind_group_layout(
        "reference",
        &[params_entry(0), storage_entry(1, true), storage_entry(2, true), storage_entry(3, false), storage_entry(4, true), guard.layout_entry()],
    )?;
    // The reference ratio-tracks every shadow ray (Shadowing::RatioTracked): no light tables.
    let source = reference_source(ctx.float32_filterable(), guard.enabled())?;
    let emission_layout = GpuEmission::layout(ctx)?;
    let motion_layout = GpuMotion::layout(ctx)?;
    let pipeline = ctx.compute_pipeline("reference", &source, "reference_pixels", &[&volume_layout, &layout, &emission_layout, &motion_layout])?;
    let motion_group = GpuMotion::upload(ctx, motion, density, origin)?.bind_group(ctx, &motion_layout)?;
    let emission = GpuEmission::upload(ctx, emission, origin)?;
    let emission_group = emission.bind_group(ctx, &emission_layout)?;
    let volume_group = volume.bind_group(ctx, &volume_layout)?;

    let mut lights: Vec<GpuLight> = params.lights.iter().map(|l| GpuLight::new(l, origin)).collect();
    let light_count = lights.len() as u32;
    if lights.is_empty() {
        lights.push(GpuLight::zeroed()); // a binding may not be empty
    }
    let light_buffer = ctx.storage_buffer("reference lights", &lights)?;
    let environment = ctx.storage_buffer("reference environment", &Environment::gpu_words(params.environment.as_ref()))?;
    let majorant_buffer = majorant_buffer(ctx, &majorant)?;
    let uniforms = GpuReferenceParams {
        camera: GpuCamera::new(camera, origin),
        medium: GpuMedium::from(&params.medium),
        grid: GpuMajorantInfo::new(&majorant, density.background()),
        background: params.background.to_array(),
        spp: params.spp,
        seed: split_u64(params.seed),
        max_depth: params.max_depth,
        light_count,
        width: camera.width(),
        first_pixel: 0,
        tile_pixels: 0,
        first_sample: 0,
        sample_count: SAMPLES_PER_DISPATCH,
        map_visible: u32::from(crate::visible_map(params.visible_environment()).is_some()),
        _pad: [0; 2],
    };
    let tiles = PixelTiles { pipeline: &pipeline, volume_group: &volume_group, later_groups: &[&emission_group, &motion_group], pixel_count, max_tile_pixels };
    let passes = params.spp.div_ceil(SAMPLES_PER_DISPATCH);
    let pixels = tiles.run(ctx, passes, progress, |first, count, pass, out| {
        let tile = GpuReferenceParams { first_pixel: first, tile_pixels: count, first_sample: pass * SAMPLES_PER_DISPATCH, ..uniforms };
        let params_buffer = ctx.params_buffer("reference params", &tile)?;
        guard.buffer_bind_group(ctx, "reference", &layout, &[&params_buffer, &light_buffer, &majorant_buffer, out, &environment])
    })?;
    guard.check(ctx, "a pixel's paths", "")?;
    let background = crate::constant_background(params.background, params.visible_environment());
    Ok(Image::from_rays(camera.width(), camera.height(), &pixels, background, params.aovs))
}

/// The reference kernel's source, on an adapter with or without FLOAT32_FILTERABLE and a loop
/// cap. It ratio-tracks every shadow ray (Shadowing::RatioTracked): no light tables.
fn reference_source(filterable: bool, loop_guard: bool) -> Result<String, GpuError> {
    Ok(medium_stage(filterable, EMISSION_GROUP, Some(MOTION_GROUP))
        .module("no light tables", NO_LIGHT_TABLES_WGSL)
        .module("path", PATH_WGSL)
        .module("loop guard", LoopGuard::wgsl_for(loop_guard, 1, GUARD_BINDING))
        .module("reference", REFERENCE_WGSL)
        .build()?)
}

/// Pixels per dispatch that keep a reference dispatch short on any device: a quarter of a
/// 1024 x 1024 image at 4 paths per pixel.
pub fn reference_tile_pixels() -> u64 {
    (GpuMarchOptions::DEFAULT_MAX_TILE_PIXELS / 16).max(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::REFERENCE_DOMAIN;

    /// The path's constants are checked where they live (nimbus_tracking's path.wgsl test).
    #[test]
    fn layout_and_constants_match_the_wgsl() {
        for (filterable, loop_guard) in [(false, false), (true, true)] {
            let mut mirrors = nimbus_tracking::wgsl_mirrors(&["Camera", "Medium", "Light", "MajorantGridInfo", "EmissionInfo", "MotionInfo", "VolumeInfo"]);
            mirrors.extend([
                (
                    "ReferenceUniforms",
                    nimbus_gpu::host_layout!(GpuReferenceParams {
                        camera,
                        medium,
                        grid,
                        background,
                        spp,
                        seed,
                        max_depth,
                        light_count,
                        width,
                        first_pixel,
                        tile_pixels,
                        first_sample,
                        sample_count,
                        map_visible,
                        _pad
                    }),
                ),
                ("PixelOut", crate::gpu::GpuPixel::host_layout()),
            ]);
            nimbus_gpu::wgsl_layout::check_layouts(&reference_source(filterable, loop_guard).unwrap(), &mirrors);
        }
        assert!(REFERENCE_WGSL.contains(&format!("REFERENCE_DOMAIN: u32 = 0x{REFERENCE_DOMAIN:08x}u")));
        assert!(REFERENCE_WGSL.contains("fn path_light(index: u32) -> Light"));
    }
}
