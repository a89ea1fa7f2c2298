//! The ground truth: an unbiased volumetric path tracer over the density alone (no photons,
//! no cache), `vdbmarch --reference`.
//!
//! Per camera sample (jittered over the pixel, box filter):
//! - the camera ray's transmittance to the background by ratio tracking (so alpha and the
//!   background term are smooth, not the 0/1 of a delta-tracked escape);
//! - a path ([`nimbus_tracking::trace_path`]): free flights by delta tracking against the
//!   majorant grid; at each real collision the throughput takes the albedo (sigma_s /
//!   sigma_t), next-event estimation adds each light's `E p(w_light, w_out) T` with T by
//!   ratio tracking, then HG picks the next direction. Russian roulette on the throughput
//!   from the third bounce; `max_depth` bounds the collisions. Roulette keeps a path with
//!   the albedo's probability, so at albedo 0.9999 most live past 512 collisions, and a cap
//!   of 512 dropped 2.8% of the image of a dense lump (`nimbus-scene --random 20261207001`
//!   at albedo 0.9999), 0.4% at its own 0.998; 4096 drops 0.01% there (2026-12-07).
//!
//! Lights are suns and points (delta lights), so next-event estimation is the only way light
//! enters the path and needs no MIS. Paths that escape add nothing: the background is seen
//! only through the camera ray's transmittance, as in the marched image.
//!
//! The first collision's light lands in the `single` layer, everything after in `multiple`,
//! so each can be held against the cache's Li_single and Li_multiple. The `depth` layer is
//! left empty (0): a stochastic first-collision distance is not a depth.
//!
//! Backends: [`render_reference_cpu`] (rows in parallel with rayon, f64) and
//! [`render_reference_gpu`] (`shaders/reference.wgsl`, one invocation per pixel, in tiles).
//! Both draw pixel i's samples from the same Philox stream in the same order, but the GPU
//! decides in f32: a path can take another turn now and then, so the images agree in
//! distribution (to Monte Carlo error), not pixel for pixel.

mod cpu;
mod gpu;

pub use cpu::{render_reference_cpu, render_reference_cpu_with};
pub(crate) use cpu::reference_sample;
pub use gpu::{reference_tile_pixels, render_reference_gpu, render_reference_gpu_with, REFERENCE_WGSL};

use glam::Vec3;
use nimbus_optics::{Camera, Environment, Light, Medium};

use nimbus_tracking::MotionBlur;
use nimbus_volume::{MajorantGrid, Volume};

use crate::MarchError;

/// Random-number domain of reference camera samples.
pub(crate) const REFERENCE_DOMAIN: u32 = 0x5245_4650; // "REFP"

/// The random stream of sample `sample` of pixel `pixel`: (pixel, sample) as the (lo, hi)
/// words of the item index. One stream per sample, not per pixel, so the GPU can take a
/// pixel's samples in separate dispatches and still draw exactly what the CPU draws.
pub(crate) fn sample_stream(pixel: u64, sample: u32) -> u64 {
    (u64::from(sample) << 32) | pixel
}

/// The majorant both backends track with: the density's, dilated with motion blur by how far
/// the medium can move within the shutter, so that it bounds the density at every time.
pub(crate) fn reference_majorant(density: &Volume<f32>, params: &ReferenceParams, motion: Option<&MotionBlur>) -> MajorantGrid {
    let majorant = MajorantGrid::for_tracking(density, params.medium.extinction);
    match motion {
        Some(m) => majorant.dilated(m.majorant_radius(density)),
        None => majorant,
    }
}


/// Everything a reference render depends on; the CPU and GPU backends read the same struct.
#[derive(Clone, Debug)]
pub struct ReferenceParams {
    pub medium: Medium,
    pub lights: Vec<Light>,
    pub camera: Camera,
    /// Paths per pixel.
    pub spp: u32,
    /// Most collisions per path.
    pub max_depth: u32,
    pub background: Vec3,
    /// The sky or map lighting the scene (next-event estimation and escaping paths).
    pub environment: Option<Environment>,
    /// Camera rays that leave the volume see the environment in place of `background`.
    pub environment_visible: bool,
    pub seed: u64,
    /// Keep the single, multiple and transmittance layers.
    pub aovs: bool,
}

impl ReferenceParams {
    /// The environment escaping camera rays see, if any (as [`crate::MarchParams`]'s).
    pub fn visible_environment(&self) -> Option<&Environment> {
        self.environment.as_ref().filter(|_| self.environment_visible)
    }

    /// vdbmarch's `--max-depth` default (the module doc).
    pub const DEFAULT_MAX_DEPTH: u32 = 4096;

    pub fn validate(&self) -> Result<(), MarchError> {
        self.medium.validate().map_err(|e| MarchError::Param(e.to_string()))?;
        if self.spp == 0 {
            return Err(MarchError::Param("--spp must be at least 1".into()));
        }
        if self.max_depth == 0 {
            return Err(MarchError::Param("--max-depth must be at least 1".into()));
        }
        if !self.background.is_finite() {
            return Err(MarchError::Param("--background must be finite".into()));
        }
        let pixels = self.camera.width() as u64 * self.camera.height() as u64;
        if pixels > u32::MAX as u64 {
            return Err(MarchError::Param(format!("{pixels} pixels is more than the reference renders (2^32 - 1)")));
        }
        Ok(())
    }
}

