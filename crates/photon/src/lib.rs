//! vdbphoton's engine: photons traced from the lights through the nonhomogeneous medium.
//!
//! A photon leaves a light where it can meet medium (for a sun, a point of the plane upstream
//! of the medium over which some non-empty part of it lies, see [`SunEmission`]; for a point
//! light, a direction in which some lies, see [`PointEmission`]), flies to its next interaction by one of three [`DistanceSampling`]
//! modes (design.md section 5), and at each interaction after the first scattering event is
//! stored in the [`PhotonMap`] with the power it scatters and the direction it arrived from.
//! It then survives by Russian roulette with probability mean(albedo) and scatters by
//! Henyey-Greenstein sampling. The first interaction is not stored: it is direct light,
//! which vdbcache computes exactly as single scattering.
//!
//! With the medium's emission ([`trace_cpu_emitting`], issue #19) photons also leave the
//! emitting voxels ([`MediumEmission`]: power `4 pi integral e dV`, positions in proportion
//! to emitted power, isotropic directions), chosen among the sources in proportion to power,
//! and are stored from their first interaction on: the cache has no single-scattering term
//! for emission, so that interaction is theirs to carry. Both backends ([`trace_gpu_emitting`]).
//!
//! Photon `i` draws every random number from `Rng(seed, i)`, and photons are emitted in
//! index order until the stored count is reached, so the map is the same on any thread count
//! and on the GPU backend (up to f32 rounding there, see below). Power is set at the end: each photon carries
//! (light power / light choice probability) / photons emitted.
//!
//! # Backends
//!
//! Both backends read the same [`PhotonParams`] and share the set-up and the batch loop
//! (`batch.rs`: what to skip, emission in index-ordered batches, the stopping rule, the
//! final power scale); they differ only in how a batch of paths is traced.
//!
//! - [`trace_cpu`] runs photon paths in parallel with rayon, in f64.
//! - [`trace_gpu`] runs one wgpu invocation per path (`shaders/photon.wgsl` over
//!   `shaders/tracking.wgsl`, the WGSL twin of `nimbus_tracking`'s majorant DDA and free-path
//!   samplers). The density is the default volume of the brick atlas (exact trilinear
//!   loads), the majorant grid a storage buffer. Every random number comes from the same
//!   Philox stream as on the CPU (f64 draws take the same two words), so photon i's path
//!   depends only on (seed, i). Stored photons are appended through an atomic counter into a
//!   bounded buffer with their (path, interaction) tag (a dispatch that overflows it is run
//!   again with room for all, which changes nothing as paths are deterministic), then sorted
//!   on the host, so the map comes out in the CPU's order. The arithmetic is f32 (positions
//!   relative to the volume's centre), so a path can part from its CPU twin where a decision
//!   (a roulette draw, a delta-tracking acceptance, a Simpson panel) falls within rounding
//!   of its threshold; the maps agree photon for photon until then and statistically after
//!   (the tests hold count, emitted count, mean power, centroid and spread together).
//!   Difference kept: where the majorant grid's outside bound (the volume's background) is
//!   non-zero, the GPU does not integrate the infinite stretch beyond the grid.

mod batch;
mod cpu;
mod emission;
mod gpu;
mod medium;

pub use cpu::{trace_cpu, trace_cpu_emitting};
pub use emission::{PointEmission, SunEmission, DIRECTION_COLUMNS, DIRECTION_ROWS};
pub use gpu::{trace_gpu, trace_gpu_emitting, PHOTON_WGSL};
pub use medium::MediumEmission;

use glam::{DVec3, Vec3};
use nimbus_optics::{Light, Medium};
use nimbus_volume::Volume;

/// The total power a trace of `density` with `params` emits (design.md section 5: a sun E
/// times the area of its [`SunEmission`], a point light I times the solid angle of its
/// [`PointEmission`]); None where the trace would be skipped. Each stored photon's power is a
/// share of it divided by the photons emitted.
pub fn emitted_power(density: &Volume<f32>, params: &PhotonParams) -> Result<Option<Vec3>, PhotonError> {
    emitted_power_emitting(density, params, None)
}

/// [`emitted_power`] with the medium's emission ([`MediumEmission`]): the lights' and
/// `4 pi integral e dV`.
pub fn emitted_power_emitting(density: &Volume<f32>, params: &PhotonParams, emission: Option<&nimbus_tracking::EmissionField>) -> Result<Option<Vec3>, PhotonError> {
    Ok(match batch::prepare(density, params, emission)? {
        batch::Prepared::Trace(setup) => Some(setup.emitter.power.iter().copied().sum()),
        batch::Prepared::Skip(..) => None,
    })
}

/// How the distance to the next interaction is sampled (design.md section 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DistanceSampling {
    /// Inversion of the optical-depth integral by composite Simpson (the paper's Eq. 2): the
    /// same distribution as delta tracking up to its step, at 2-5x the cost per photon; kept
    /// for comparison.
    Simpson,
    /// sigma_t frozen at the start point (the paper's Eq. 1): biased, for comparison.
    Exponential,
    /// Delta tracking against the majorant grid: unbiased, and the default (1.4-2.1x more
    /// accurate than Simpson at equal time in `make bench`).
    Delta,
}

impl DistanceSampling {
    pub fn name(self) -> &'static str {
        match self {
            DistanceSampling::Simpson => "simpson",
            DistanceSampling::Exponential => "exponential",
            DistanceSampling::Delta => "delta",
        }
    }
}

impl std::str::FromStr for DistanceSampling {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "simpson" => Ok(DistanceSampling::Simpson),
            "exponential" => Ok(DistanceSampling::Exponential),
            "delta" => Ok(DistanceSampling::Delta),
            _ => Err(format!("unknown distance sampling '{s}' (simpson, exponential or delta)")),
        }
    }
}

/// Everything a photon trace depends on; the CPU and GPU backends read the same struct.
#[derive(Clone, Debug)]
pub struct PhotonParams {
    pub medium: Medium,
    pub lights: Vec<Light>,
    /// A sky or map: photons also leave it (stored from their first interaction, as the
    /// cache has no single-scattering term for it).
    pub environment: Option<nimbus_optics::Environment>,
    pub distance: DistanceSampling,
    /// Simpson step as a fraction of the smallest voxel edge.
    pub step: f64,
    /// Photons to store.
    pub photons: u64,
    /// Emission stops here even if fewer photons were stored.
    pub max_emitted: u64,
    /// A path ends after this many interactions.
    pub max_interactions: u32,
    pub seed: u64,
}

impl Default for PhotonParams {
    fn default() -> Self {
        PhotonParams {
            medium: Medium::default(),
            lights: vec![Light::default_sun()],
            environment: None,
            distance: DistanceSampling::Delta,
            step: 0.5,
            photons: 200_000,
            max_emitted: 50_000_000,
            max_interactions: 64,
            seed: 0,
        }
    }
}

/// Photons stored at interactions after the first scattering event (a light's) or from the
/// first interaction on (the medium's emission's), in emission order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PhotonMap {
    /// World-space positions.
    pub positions: Vec<DVec3>,
    /// Power scattered at the interaction (arriving power times albedo), RGB.
    pub power: Vec<Vec3>,
    /// Unit direction the photon travelled before the interaction (w_in).
    pub dir: Vec<Vec3>,
}

impl PhotonMap {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn total_power(&self) -> Vec3 {
        self.power.iter().copied().sum()
    }
}

/// What happened to the emitted photons.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TraceStats {
    pub emitted: u64,
    pub stored: u64,
    /// Paths that left the volume.
    pub escaped: u64,
    /// Paths ended by Russian roulette.
    pub absorbed: u64,
    /// Paths cut at `max_interactions`.
    pub truncated: u64,
    pub interactions: u64,
    /// Why nothing was traced, when nothing was.
    pub skipped: Option<String>,
}

impl TraceStats {
    pub fn mean_interactions(&self) -> f64 {
        if self.emitted == 0 {
            0.0
        } else {
            self.interactions as f64 / self.emitted as f64
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PhotonError {
    #[error("invalid parameter: {0}")]
    Param(String),
    #[error(transparent)]
    Gpu(#[from] nimbus_gpu::GpuError),
}

impl PhotonParams {
    pub fn validate(&self) -> Result<(), PhotonError> {
        self.medium.validate().map_err(|e| PhotonError::Param(e.to_string()))?;
        if !(self.step > 0.0 && self.step.is_finite()) {
            return Err(PhotonError::Param(format!("--step must be positive, got {}", self.step)));
        }
        if self.max_interactions == 0 {
            return Err(PhotonError::Param("--max-interactions must be at least 1".into()));
        }
        Ok(())
    }
}
