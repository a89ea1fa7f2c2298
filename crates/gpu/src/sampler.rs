//! Batch sampling of a [`GpuVolume`] at index-space points: how the tests hold the WGSL
//! sampler to `Volume::sample_index`, and a handy probe for stage tests.

use glam::Vec3;

use crate::volume::GpuVoxel;
use crate::{context::storage_entry, GpuContext, GpuError, GpuVolume, SAMPLE_POINTS_WGSL};

const WORKGROUP_SIZE: u32 = 64;

/// Which WGSL sampling function to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleMode {
    /// `volume_sample_index`: 8 texel loads, exact trilinear.
    Exact,
    /// `volume_sample_index_filtered`: one hardware-filtered fetch.
    Filtered,
}

/// Compiled pipelines for [`PointSampler::sample`]; build once, sample many times.
#[derive(Debug)]
pub struct PointSampler {
    volume_layout: wgpu::BindGroupLayout,
    points_layout: wgpu::BindGroupLayout,
    exact: wgpu::ComputePipeline,
    filtered: wgpu::ComputePipeline,
}

impl PointSampler {
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let volume_layout = GpuVolume::bind_group_layout(ctx)?;
        let points_layout = ctx.bind_group_layout("sample points", &[storage_entry(0, true), storage_entry(1, false)])?;
        let source = sampler_source(ctx.float32_filterable())?;
        let layouts = [&volume_layout, &points_layout];
        let exact = ctx.compute_pipeline("sample points (exact)", &source, "sample_exact", &layouts)?;
        let filtered = ctx.compute_pipeline("sample points (filtered)", &source, "sample_filtered", &layouts)?;
        Ok(PointSampler { volume_layout, points_layout, exact, filtered })
    }

    /// Samples `volume` (uploaded from a `Volume<T>`) at each index-space point.
    pub fn sample<T: GpuVoxel>(&self, ctx: &GpuContext, volume: &GpuVolume, points: &[Vec3], mode: SampleMode) -> Result<Vec<T>, GpuError> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let points_buffer = ctx.storage_buffer("sample points", points)?;
        let samples_buffer = ctx.storage_buffer_zeroed("samples", points.len() as u64 * 16)?;
        let volume_group = volume.bind_group(ctx, &self.volume_layout)?;
        let points_group = ctx.buffer_bind_group("sample points", &self.points_layout, &[&points_buffer, &samples_buffer])?;
        let pipeline = match mode {
            SampleMode::Exact => &self.exact,
            SampleMode::Filtered => &self.filtered,
        };
        ctx.dispatch_1d("sample points", pipeline, &[&volume_group, &points_group], points.len() as u64, WORKGROUP_SIZE)?;
        let texels: Vec<[f32; 4]> = ctx.read_buffer(&samples_buffer)?;
        Ok(texels.into_iter().map(T::from_texel).collect())
    }
}

/// The sampler kernel's source on an adapter with or without FLOAT32_FILTERABLE.
pub(crate) fn sampler_source(filterable: bool) -> Result<String, GpuError> {
    Ok(crate::ShaderComposer::stage(filterable).module("sample_points", SAMPLE_POINTS_WGSL).build()?)
}
