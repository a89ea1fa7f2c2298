//! vdbmarch's engine: the image, by marching camera rays through the density and reading the
//! illumination cache at each sample (design.md section 5, the paper's section 3.6).
//!
//! Along a camera ray, each step of length dt through sigma_t adds
//! `T * (1 - exp(-sigma_t dt)) * albedo * Li(x)` and multiplies T by `exp(-sigma_t dt)`: the
//! exact integral of `T sigma_s Li` over the step for Li constant over it, stable however
//! thick the step is. `Li = Li_single + Li_multiple` comes from the cache by trilinear lookup.
//!
//! - Steps sit on a per-sample lattice `t_k = (k + xi) dt` with xi random per pixel sample,
//!   which turns the banding of a fixed lattice into noise, and lets empty majorant segments
//!   be skipped without moving the lattice.
//! - `spp` samples per pixel are jittered over the pixel (box filter), stratified on the
//!   largest square grid of cells (`cpu::pixel_jitter`), each with its own xi.
//! - Offset noise (the paper's Perlin jitter) moves each sample position by a smooth vector
//!   fBm field of amplitude `offset_noise` (world units), breaking up the grid look of
//!   coarse volumes; amplitude 0 costs nothing.
//! - Rays stop once T < `min_transmittance`; rays that miss every non-empty majorant cell
//!   cost one DDA walk.
//!
//! `vdbmarch --reference` renders the same image by an unbiased path tracer over the
//! density alone ([`render_reference_cpu`], [`ReferenceParams`]; see `reference.rs`): the
//! ground truth every accuracy figure is measured against.
//!
//! # Backends
//!
//! Both read the same [`MarchParams`], compute one [`RayResult`] per pixel and hand them to
//! the same image assembly ([`Image::from_rays`], through one function).
//!
//! - [`render_cpu`]: pixels in parallel with rayon, in f64.
//! - [`render_gpu`] / [`render_gpu_with`]: one wgpu invocation per pixel
//!   (`shaders/march.wgsl`, over `shaders/tracking.wgsl` for the majorant DDA and
//!   `shaders/noise.wgsl`, the bit-exact-hash WGSL twin of `nimbus_optics::noise`, for the
//!   offset noise). Pixel i draws from the same Philox stream as on the CPU, in the same
//!   order (jitter, then the lattice offset xi, per sample), so the two images agree to f32
//!   rounding (the tests hold lit pixels to 1e-4 relative). The density is the default
//!   volume of the brick atlas, sampled exactly; `Li_single` and `Li_multiple` are two more
//!   atlas volumes, read by hardware-filtered lookups where the device filters float
//!   textures ([`CacheLookup::Filtered`], the default: within ~1/256 of Li's local range
//!   of the exact value) or exactly ([`CacheLookup::Exact`]). Positions are f32 relative to
//!   the eye, noise positions split into a lattice point and a remainder, so far-from-origin
//!   scenes keep their precision. Across adjacent non-empty majorant segments the GPU
//!   carries the lattice index over instead of recomputing it from the segment start, so
//!   a sample lying on a boundary within f32 rounding is taken exactly once; `1 - exp(-sigma_t dt)` is evaluated
//!   without cancellation in thin media.

// The unit tests share tests/common, which names this crate.
#[cfg(test)]
extern crate self as nimbus_march;

mod cpu;
mod gpu;
mod image;
mod layout;
mod reference;
mod simd;

pub use cpu::{march_ray, render_cpu, RayResult};
pub use gpu::{render_gpu, render_gpu_with, CacheLookup, GpuMarchOptions, MARCH_WGSL, NOISE_WGSL};
pub use image::{Image, ImageError};
pub use reference::{reference_tile_pixels, render_reference_cpu, render_reference_gpu, ReferenceParams, REFERENCE_WGSL};

/// The image from per-pixel ray results (pixel 0 top-left, rows top to bottom): what every
/// backend ends with.
pub(crate) fn assemble(params: &MarchParams, pixels: &[RayResult]) -> Image {
    Image::from_rays(params.camera.width(), params.camera.height(), pixels, params.background, params.aovs)
}

use glam::Vec3;
use nimbus_optics::{Camera, Medium};

/// Everything a render depends on; the CPU and GPU backends read the same struct.
#[derive(Clone, Debug)]
pub struct MarchParams {
    pub medium: Medium,
    pub camera: Camera,
    /// Step along camera rays, world units.
    pub step: f64,
    /// Samples per pixel.
    pub spp: u32,
    pub background: Vec3,
    /// Amplitude of the sample-position jitter field, world units (0: off).
    pub offset_noise: f64,
    /// Feature size of the jitter field, world units.
    pub noise_scale: f64,
    pub noise_octaves: u32,
    pub min_transmittance: f64,
    pub seed: u64,
    /// Keep the single, multiple, transmittance and depth layers.
    pub aovs: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum MarchError {
    #[error("invalid parameter: {0}")]
    Param(String),
    #[error(transparent)]
    Gpu(#[from] nimbus_gpu::GpuError),
}

impl MarchParams {
    pub fn validate(&self) -> Result<(), MarchError> {
        self.medium.validate().map_err(|e| MarchError::Param(e.to_string()))?;
        if !(self.step > 0.0 && self.step.is_finite()) {
            return Err(MarchError::Param(format!("--step must be positive, got {}", self.step)));
        }
        if self.spp == 0 {
            return Err(MarchError::Param("--spp must be at least 1".into()));
        }
        if !(self.offset_noise >= 0.0 && self.offset_noise.is_finite()) {
            return Err(MarchError::Param(format!("--offset-noise must be >= 0, got {}", self.offset_noise)));
        }
        if self.offset_noise > 0.0 && !(self.noise_scale > 0.0 && self.noise_scale.is_finite()) {
            return Err(MarchError::Param(format!("--noise-scale must be positive, got {}", self.noise_scale)));
        }
        if !self.background.is_finite() {
            return Err(MarchError::Param("--background must be finite".into()));
        }
        if !(0.0..1.0).contains(&self.min_transmittance) {
            return Err(MarchError::Param(format!("--min-transmittance must be in [0,1), got {}", self.min_transmittance)));
        }
        Ok(())
    }
}
