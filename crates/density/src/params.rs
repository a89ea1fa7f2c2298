//! The parameter struct every backend (CPU now, GPU later) reads, and its validation.

use glam::DVec3;

use crate::DensityError;

/// How the smoothing length h(x) is chosen at each grid point (design.md section 8).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// Uniform: h = h0 everywhere. One pass.
    Usl,
    /// Adaptive, predictor only: h = h1 from the count within kappa*h0. Two passes.
    Asl2,
    /// Adaptive, predictor + corrector. Three passes. The default until issue #21.
    Asl3,
    /// Exact reference: h = (distance to the N*-th nearest particle) / kappa.
    Knn,
    /// Error-following (issue #21), the default: per grid point the length, from a ladder
    /// between h_min and h0, whose estimated error is least (the bias from the differences
    /// between rungs averaged about the point, plus the variance; `ici.rs`), averaged over
    /// its neighbours and interpolated between rungs; the ladder pass, the rule over the
    /// whole grid, then the density pass. Both backends.
    Ici,
}

impl Method {
    pub const ALL: [Method; 5] = [Method::Usl, Method::Asl2, Method::Asl3, Method::Knn, Method::Ici];

    pub fn name(self) -> &'static str {
        match self {
            Method::Usl => "usl",
            Method::Asl2 => "asl2",
            Method::Asl3 => "asl3",
            Method::Knn => "knn",
            Method::Ici => "ici",
        }
    }

    pub fn from_name(name: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name().eq_ignore_ascii_case(name))
    }
}

/// The upper bound of the smoothing length (and the uniform length for `usl`), world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum H0 {
    /// Chosen from a histogram of particle number density; see [`crate::auto_h0`].
    Auto,
    Fixed(f64),
}

/// Grid spacing: a voxel edge in world units, or a voxel count along the longest axis of
/// the bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resolution {
    VoxelSize(f64),
    Longest(u32),
}

/// fBm noise perturbation of the density: `rho * max(0, 1 + amplitude * fbm(x / scale))`,
/// x the world position. Amplitude 0 (the default) switches it off at no cost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseParams {
    pub amplitude: f32,
    /// Feature size L in world units.
    pub scale: f64,
    pub octaves: u32,
    pub seed: u32,
}

impl Default for NoiseParams {
    fn default() -> Self {
        NoiseParams { amplitude: 0.0, scale: 1.0, octaves: 4, seed: 0 }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct DensityParams {
    pub method: Method,
    /// N*, the target neighbour count of the adaptive methods and of `h0 auto`.
    pub neighbours: u32,
    pub h0: H0,
    /// Floor of the smoothing length; design.md's default is 1.2 voxels.
    pub h_min: HMin,
    /// s in [0, 1], the asl3 relaxation for overestimated lengths.
    pub relax: f32,
    /// Gamma, ici's noise allowance in standard deviations ([`DEFAULT_ICI_CONFIDENCE`],
    /// [`crate::kernel::ici_rung`]).
    pub confidence: f32,
    /// Mass of each particle when the set has no `mass` attribute.
    pub mass: f32,
    pub resolution: Resolution,
    /// Explicit world bounds (low, high corner). `None` = the particles' bounding box padded
    /// by kappa*h0 on every side, so the density falls to zero inside the grid.
    pub bounds: Option<(DVec3, DVec3)>,
    /// Refuse grids whose bounding box holds more voxels than this, before any heavy work.
    pub max_voxels: u64,
    pub noise: NoiseParams,
    /// A voxel is active where rho > active_tolerance * max(rho).
    pub active_tolerance: f32,
    /// Also output the smoothing length used at each voxel (world units).
    pub smoothing_length: bool,
    /// Also output the number of particles used at each voxel.
    pub neighbour_count: bool,
    /// Normalise each particle's mass by its kernel's sum over the grid, so the grid holds
    /// exactly the particles' mass where h varies steeply (one more kernel pass; see the
    /// crate docs). Off: design.md's gather form.
    pub conserve_mass: bool,
    /// Particle attributes (names in [`crate::ParticleSet::attributes`]) to interpolate onto
    /// grids beside the density, with its smoothing lengths ([`crate::AttributeOutput`]).
    pub attributes: Vec<String>,
    /// A vec3 particle attribute the density noise is evaluated at instead of the world
    /// position (Houdini's `rest`): interpolated as an attribute, so the noise pattern moves
    /// and deforms with the particles instead of the particles moving through it. `None`:
    /// the noise is anchored in world space.
    pub noise_rest: Option<String>,
}

/// The floor of the smoothing length (`--h-min`): a world length, or a number of voxels.
/// Voxels are resolved with the grid, since with `--resolution` the voxel size follows from
/// the bounds, which follow from h0, which is at least h_min.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HMin {
    World(f64),
    Voxels(f64),
    /// The method's own floor: [`DEFAULT_H_MIN_VOXELS`], or [`ICI_H_MIN_VOXELS`] for ici.
    Auto,
}

/// The `--h-min` text form: a length, or a voxel count with the suffix `vox`.
impl std::fmt::Display for HMin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HMin::World(h) => write!(f, "{h}"),
            HMin::Voxels(n) => write!(f, "{n}vox"),
            HMin::Auto => write!(f, "auto"),
        }
    }
}

impl HMin {
    /// The floor in world units for `method` on a grid of this voxel size.
    pub fn resolve(self, method: Method, voxel: f64) -> f64 {
        match self {
            HMin::World(h) => h,
            HMin::Voxels(n) => n * voxel,
            HMin::Auto if method == Method::Ici => ICI_H_MIN_VOXELS * voxel,
            HMin::Auto => DEFAULT_H_MIN_VOXELS * voxel,
        }
    }
}

/// The default N* (design.md section 8, issue #18; the paper's 32 until then). Measured in
/// `examples/accuracy.rs` (tables in the crate docs): with [`DEFAULT_H_MIN_VOXELS`] it brings
/// asl3 within 3% of the best-tuned usl on the knots, the shell and a smooth plume, at about
/// 1.6x the time of 32, and with the gather estimate's mass excess accepted (+1.3% on a
/// smooth 20k-particle blob, +3.9% on the shell; `conserve_mass` makes it exact).
pub const DEFAULT_NEIGHBOURS: u32 = 80;

/// The default floor of the smoothing length in voxels (design.md section 8, issue #18; one
/// voxel until then): with N* = 80 the setting that also brings the plume within 3%.
pub const DEFAULT_H_MIN_VOXELS: f64 = 1.2;

/// ici's Gamma, the weight of the standard deviation beside the bias: 0.8 on every scene
/// (crate docs, issue #21). The accuracy example at 0.6, 0.8, 1 and 1.2 (knots, shell, plume,
/// Cloud1-class): 0.1086, 0.2121, 0.0757, 0.1433; 0.1078, 0.2115, 0.0720, 0.1378; 0.1086,
/// 0.2162, 0.0710, 0.1366; 0.1107, 0.2265, 0.0715, 0.1371. 0.8 is the only one at or below
/// the best usl on all four.
pub const DEFAULT_ICI_CONFIDENCE: f32 = 0.8;

/// ici's default floor, the ladder's shortest rung, in voxels: below the other methods' floor,
/// because its rule goes there only where the particles are dense enough to pay for it (the
/// knots' error is 0.1078 against 0.1408 with a 1.2-voxel floor, Cloud1-class 0.1378 against
/// 0.1381).
pub const ICI_H_MIN_VOXELS: f64 = 0.75;

impl Default for DensityParams {
    fn default() -> Self {
        DensityParams {
            method: Method::Ici,
            neighbours: DEFAULT_NEIGHBOURS,
            h0: H0::Auto,
            h_min: HMin::Auto,
            relax: 0.0,
            confidence: DEFAULT_ICI_CONFIDENCE,
            mass: 1.0,
            resolution: Resolution::Longest(256),
            bounds: None,
            max_voxels: 1 << 32,
            noise: NoiseParams::default(),
            noise_rest: None,
            active_tolerance: 1e-6,
            smoothing_length: false,
            neighbour_count: false,
            conserve_mass: false,
            attributes: Vec::new(),
        }
    }
}

impl DensityParams {
    /// Checks every value on its own; combinations are checked where they are used.
    pub fn validate(&self) -> Result<(), DensityError> {
        let bad = |name: &'static str, value: String, why: &'static str| {
            Err(DensityError::InvalidParam { name, value, why })
        };
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if self.neighbours == 0 {
            return bad("neighbours", "0".into(), "must be at least 1");
        }
        if let H0::Fixed(h) = self.h0 {
            if !positive(h) {
                return bad("h0", h.to_string(), "must be positive and finite");
            }
        }
        if let HMin::World(h) | HMin::Voxels(h) = self.h_min {
            if !positive(h) {
                return bad("h-min", h.to_string(), "must be positive and finite");
            }
        }
        if !(0.0..=1.0).contains(&self.relax) {
            return bad("relax", self.relax.to_string(), "must be in [0, 1]");
        }
        if !(self.confidence.is_finite() && self.confidence > 0.0) {
            return bad("confidence", self.confidence.to_string(), "must be positive and finite");
        }
        if !(self.mass.is_finite() && self.mass >= 0.0) {
            return bad("mass", self.mass.to_string(), "must be finite and not negative");
        }
        match self.resolution {
            Resolution::VoxelSize(v) if !positive(v) => return bad("voxel-size", v.to_string(), "must be positive and finite"),
            Resolution::Longest(0) => return bad("resolution", "0".into(), "must be at least 1"),
            _ => {}
        }
        if let Some((lo, hi)) = self.bounds {
            if !(lo.is_finite() && hi.is_finite() && hi.cmpgt(lo).all()) {
                return bad("bounds", format!("{lo} .. {hi}"), "need finite corners with low < high on every axis");
            }
        }
        if self.noise.amplitude != 0.0 && !(positive(self.noise.scale) && self.noise.amplitude.is_finite()) {
            return bad("noise-scale", self.noise.scale.to_string(), "must be positive and finite");
        }
        if !(self.active_tolerance.is_finite() && self.active_tolerance >= 0.0) {
            return bad("active-tolerance", self.active_tolerance.to_string(), "must be finite and not negative");
        }
        Ok(())
    }
}
