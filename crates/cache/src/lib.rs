//! vdbcache's engine: the [`IlluminationCache`], in-scattered radiance per unit scattering
//! coefficient toward the camera, baked per voxel (design.md section 5).
//!
//! - `Li_single(x) = sum over lights p(w_light, w_out) E T_light(x)`, on the density's own
//!   lattice by default. T_light comes from each sun's tabled transmittance
//!   ([`nimbus_tracking::OpticalDepthVolume`], built once per bake: [`ShadowMode::Table`]),
//!   or from a Simpson shadow ray per voxel ([`ShadowMode::Rays`], and always for point
//!   lights). The table and the shadow rays agree to the error of a brute-force
//!   single-scatter march; the table is the cheaper (docs/benchmarks.md).
//! - `Li_multiple`, by default ([`MultipleEstimator::Paths`]) the mean of paths traced from
//!   the voxel ([`li_multiple_paths`] over [`nimbus_tracking::trace_path`], the reference
//!   path tracer's own, with next-event estimation reading the table), on its own lattice
//!   (`multiple_scale`, default 2 density voxels). The [`PathPlan`] decides how many and from
//!   where: N per voxel on average, spread as sqrt(G_v), the squared derivatives of the
//!   march's pixels with respect to the voxel's value summed over the image
//!   ([`CameraImportance`]); each starting at a point where the camera's rays read the voxel,
//!   drawn by that point's weight in the image. So the voxel holds the average of what the
//!   image reads through it, and a coarse lattice blurs but does not darken (values at the
//!   voxels' centres did; docs/benchmarks.md). Voxels no camera ray reads, nor a neighbour, get no paths.
//!   A voxel's paths take their first directions from R2 sequences (one per half of its
//!   paths, even and odd, each rotated by the voxel's stream: each direction still the phase
//!   function's), which spread them evenly and keep the halves independent.
//!   Unbiased per point, so the error falls as 1/sqrt(N). Where
//!   [`CacheParams::path_tolerance`] is given, that count is a first pass: the paths' spread
//!   per voxel, weighted by the camera importance, predicts the relative noise they leave in
//!   the image, and a second pass scales every voxel's paths until it is within the
//!   tolerance (budget.rs: [`predicted_noise`], [`more_paths`]; both backends, on the host).
//!   Where [`CacheParams::multiple_tolerance`] is given, the same paths, summed by their
//!   origins' octants in two independent halves, estimate the bias the lattice leaves in
//!   the image, and a lattice biased beyond it is traced again finer (multiple_lattice.rs:
//!   [`lattice_bias`], [`refined_scale`]; the estimate taken at [`LATTICE_BIAS_UNDER_READ`]
//!   times its value, as it under-read the bias measured against the reference; a refined
//!   lattice's bias measured against the bake before it, [`BakedLattice`]). With the medium's emission
//!   ([`bake_cpu_emitting`], [`bake_gpu_emitting`]) the paths gather it too, so Li_multiple holds emitted light
//!   the medium scatters (a fire lights its smoke; vdbmarch adds the unscattered emission
//!   along camera rays itself), with or without lights.
//! - Or the paper's estimator ([`MultipleEstimator::Photons`]):
//!   `[sum_p p(w_p, w_out) dPhi_p / (4/3 pi r^3)] / mean sigma_s(ball)`, the volume radiance
//!   estimate over the photons in a ball around x (radius fixed, or the distance to the K-th
//!   nearest photon), divided by the mean scattering coefficient over the same ball, which
//!   stays stable at thin edges. Its error falls as the k-nearest-neighbour density
//!   estimate's (about N^-0.3 on the bundled cloud), so it loses to the paths at every budget
//!   measured.
//!
//! `w_out` points from the voxel toward the camera's eye, so the cache holds what that camera
//! sees. The [`CachePlan`] decides which cache voxels are baked: only those within one cache
//! cell of density (found through the majorant grid) and inside the camera's view (a
//! conservative sphere test), so empty space and what the camera cannot see cost nothing.
//!
//! Photons are found through [`PhotonBins`], a counting-sort grid built in O(photons).
//!
//! Two backends read the same [`CacheParams`], plans and path plan: [`bake_cpu`] (rayon over
//! the planned voxels) and [`bake_gpu`] (`shaders/cache.wgsl`, one invocation per voxel; the
//! light tables built by `shaders/optical_depth.wgsl` and read through
//! `shaders/light_tables.wgsl`; the k nearest photons by the same shell-by-shell search over
//! the same bins, kept in a per-invocation heap of at most [`GPU_MAX_NEIGHBOURS`]). They agree
//! to f32 rounding (about 1e-6 of the peak on lavapipe), the paths in distribution. The GPU
//! cache kernel binds 14 storage buffers per stage: every desktop GPU offers that, wgpu's
//! portable default (8) does not.
//!
//! A gather ball whose mean density is under [`EMPTY_BALL_FRACTION`] of the volume's peak
//! counts as empty: dividing its photons by a near-zero mean would send the voxel, and through
//! interpolation its neighbours, to huge values.

mod bins;
mod budget;
mod cpu;
mod gpu;
mod importance;
mod lattice;
mod multiple_lattice;
mod plan;

pub use bins::PhotonBins;
pub use budget::{more_paths, noise_short_of, paths_share, predicted_noise, second_pass_seed, single_levels, PathMoments, LEAST_PATHS_SHARE, MAX_PATH_GROWTH, PATH_TOLERANCE, UNESTIMATED_SHARE};
pub use cpu::{bake_cpu, bake_cpu_emitting, gather_cell, li_multiple, li_multiple_paths, li_single, mean_density_in_ball, toward_eye, transmittance_grids, EMPTY_BALL_FRACTION};
pub use gpu::{bake_gpu, bake_gpu_emitting, CACHE_WGSL, GPU_MAX_NEIGHBOURS};
pub use importance::{pixel_samples_per_side, CameraImportance, PathPlan, IMPORTANCE_RAYS, MAX_ORIGINS_PER_VOXEL, MAX_SAMPLES_PER_PIXEL_SIDE};
pub use lattice::{choose_single_lattice, SingleLattice, LATTICE_SAMPLES, MAX_REFINEMENT, SINGLE_LATTICE_TOLERANCE};
pub use multiple_lattice::{lattice_bias, refined_scale, BakedLattice, LatticeBias, MultipleLattice, LATTICE_BIAS_UNDER_READ, MULTIPLE_LATTICE_TOLERANCE};
pub use plan::{cache_transform, CachePlan};
pub use nimbus_tracking::LightLattice;

use nimbus_optics::{Camera, Environment, Light, Medium};
use nimbus_tracking::{DensityMedium, LightDepths};
use nimbus_volume::Volume;

/// How the multiple-scattering estimate chooses its ball.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Gather {
    /// The ball reaches the K-th nearest photon (at most `max_radius`).
    Neighbours { k: u32, max_radius: f64 },
    /// A fixed radius (world units).
    Radius(f64),
}

/// How Li_multiple is estimated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MultipleEstimator {
    /// The photon map's radiance estimate (the paper's method), over the ball
    /// [`CacheParams::gather`] chooses. Biased by the ball's size, and its error falls slowly
    /// with the photon count (as the k-nearest-neighbour density estimate's does, about
    /// N^-0.3 on the bundled cloud).
    Photons,
    /// Paths traced from each cache voxel ([`li_multiple_paths`]): unbiased per voxel, its
    /// error falling as 1/sqrt(paths), and needs no photons. `per_voxel` paths per voxel on
    /// average: one each, the rest where the camera's image depends most on the voxel
    /// ([`CameraImportance::paths`]).
    Paths { per_voxel: u32 },
}

impl MultipleEstimator {
    /// Paths per voxel for a quality preset's count `preset` in this medium: half of it where
    /// the paths send probes toward the lights (|g| >= [`nimbus_tracking::PROBE_FROM_G`]),
    /// which halves a path's variance there, so the image keeps its error at less cost
    /// (docs/benchmarks.md "Probes toward the lights": the bundled cloud at g 0.6, seed-to-seed
    /// 1.78% at 32 paths with probes, 1.77% at 64 without).
    pub fn default_paths(preset: u32, medium: &Medium) -> MultipleEstimator {
        let probes = medium.g.abs() >= nimbus_tracking::PROBE_FROM_G;
        MultipleEstimator::Paths { per_voxel: if probes { (preset / 2).max(1) } else { preset } }
    }

    /// The text form for metadata and `-v`: `photons` or `paths:N`.
    pub fn describe(self) -> String {
        match self {
            MultipleEstimator::Photons => "photons".into(),
            MultipleEstimator::Paths { per_voxel } => format!("paths:{per_voxel}"),
        }
    }
}

/// How single scattering and the paths' next-event estimation find the transmittance toward
/// a light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShadowMode {
    /// Each sun's optical depth tabled once on a light-aligned lattice
    /// ([`nimbus_tracking::OpticalDepthVolume`]) and looked up; point lights trace shadow rays.
    Table(LightLattice),
    /// A shadow ray per point and light: composite Simpson for Li_single, ratio tracking in
    /// the paths.
    Rays,
}

impl ShadowMode {
    /// The text form for metadata and `-v`.
    pub fn describe(self) -> String {
        match self {
            ShadowMode::Table(l) => format!("table:{}:{}", l.across, l.along),
            ShadowMode::Rays => "rays".into(),
        }
    }
}

/// Most collisions of a path-traced multiple-scattering estimate ([`CacheParams::path_max_depth`]
/// by default), as the reference's (`vdbmarch --reference --max-depth`). A truncation:
/// roulette keeps a path with the albedo's probability, so at albedo 0.999 most paths outlive
/// 512 collisions in a dense medium. At 512 (before 2026-12-07, night) the cut left
/// `nimbus-scene --random 20261207015` (15 optical depths a voxel, albedo 0.984-0.999) 1%
/// dark where the image is lit, 1.88% off the 4096-collision reference against 0.45% off one
/// cut at 512 as well; 2.8% of a dense lump's image at albedo 0.9999
/// (`--random 20261207001`). Below albedo 0.98 no path comes near either cap.
pub const PATH_MAX_DEPTH: u32 = 4096;

/// The cap on an adapter with a loop cap (lavapipe): a path of 4096 collisions outruns
/// llvmpipe's loop cap on its own, whatever the dispatch holds, and the shader cannot yet
/// resume a path across dispatches. A bake on such an adapter says so where the medium's
/// albedo lets paths reach it ([`BakeStats::paths_cut_at`]).
pub const SOFTWARE_PATH_MAX_DEPTH: u32 = 512;

/// Everything a bake depends on; the CPU and GPU backends read the same struct.
#[derive(Clone, Debug)]
pub struct CacheParams {
    pub medium: Medium,
    pub lights: Vec<Light>,
    /// The sky or environment map, if any: the paths gather it (all of its orders, the
    /// first included, by next-event estimation at the voxel and at every collision), so it
    /// lives in Li_multiple; Li_single holds the lights' single scattering alone.
    pub environment: Option<Environment>,
    pub camera: Camera,
    /// Simpson step toward the lights, as a fraction of the smallest density voxel edge.
    pub step: f64,
    /// Cache voxel edge in density voxels (>= 1 coarser).
    pub cache_scale: f64,
    /// Li_multiple's own voxel edge in density voxels, where it differs from `cache_scale`:
    /// multiple scattering is smoother than single (whose shadows are as sharp as the
    /// density), so a coarser lattice serves it at a fraction of the voxels.
    pub multiple_scale: Option<f64>,
    /// Where given, Li_single's lattice is `cache_scale` refined per axis until its
    /// estimated relative interpolation error is within this ([`choose_single_lattice`]);
    /// None keeps `cache_scale` on every axis.
    pub single_tolerance: Option<f64>,
    /// Where given, the path-traced Li_multiple is topped up until the relative noise its
    /// paths leave in the image, predicted from their measured spread, is within this
    /// (budget.rs; at most [`MAX_PATH_GROWTH`] times the paths); None traces the estimator's
    /// count alone.
    pub path_tolerance: Option<f64>,
    /// Where given, the path-traced Li_multiple is traced again on a finer lattice where the
    /// bias its lattice leaves in the image, estimated from the paths, exceeds this
    /// (multiple_lattice.rs); None keeps `multiple_scale`.
    pub multiple_tolerance: Option<f64>,
    pub single: bool,
    pub multiple: bool,
    pub gather: Gather,
    /// Where Li_multiple comes from: the photons, or paths traced from the voxels.
    pub estimator: MultipleEstimator,
    /// Seed of the path-traced estimate (voxel i draws from `Rng(seed, i)`).
    pub seed: u64,
    /// Shadow rays stop once transmittance falls below this; below it light counts as black.
    pub min_transmittance: f64,
    /// Where transmittance toward the lights comes from.
    pub shadows: ShadowMode,
    /// Most collisions of a path ([`PATH_MAX_DEPTH`]; a GPU with a loop cap cuts it to
    /// [`SOFTWARE_PATH_MAX_DEPTH`]).
    pub path_max_depth: u32,
}

/// The baked grids; `None` where that part was not asked for or had nothing to gather.
#[derive(Clone, Debug, Default)]
pub struct IlluminationCache {
    pub li_single: Option<Volume<glam::Vec3>>,
    pub li_multiple: Option<Volume<glam::Vec3>>,
    /// The transmittance toward each tabled light (by its index in the lights) at the
    /// density's voxels: view-independent, for artists' own shading.
    pub transmittance: Vec<(usize, Volume<f32>)>,
}

/// What the bake did, for `-v` and metadata.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BakeStats {
    /// Cache voxels in the bricks near density.
    pub candidates: u64,
    /// Of those, skipped for lying outside the camera's view.
    pub culled_view: u64,
    /// Of those, skipped for having no density within one cache cell.
    pub culled_empty: u64,
    pub baked: u64,
    pub photons_gathered: u64,
    /// Paths traced for the path-traced multiple scattering.
    pub paths: u64,
    /// Of the baked voxels, given no paths because no camera ray reads them or a neighbour.
    pub culled_unseen: u64,
    /// The relative noise the paths leave in the image, predicted after the first pass and
    /// after all (budget.rs), where [`CacheParams::path_tolerance`] asked for it.
    pub path_noise: Option<(f64, f64)>,
    /// What the paths' noise was held to: their share of [`CacheParams::path_tolerance`]
    /// after the lattices' estimated biases and the margin (budget.rs, [`paths_share`]).
    pub path_noise_tolerance: Option<f64>,
    /// Most the top-ups could grow the settled lattice's first pass (budget.rs: 
    /// [`MAX_PATH_GROWTH`], more on a refined lattice whose first pass was cut).
    pub path_growth_cap: f64,
    /// Nodes of the lights' tabled transmittance.
    pub light_table_nodes: u64,
    /// Voxels whose estimate came out non-finite (stored as zero); should stay 0.
    pub nonfinite: u64,
    /// Where the paths were cut short of [`CacheParams::path_max_depth`] (a GPU's loop cap,
    /// [`SOFTWARE_PATH_MAX_DEPTH`]) in a medium whose albedo lets them reach the cut: the
    /// collisions they stopped at.
    pub paths_cut_at: Option<u32>,
    /// Li_single's lattice as chosen ([`choose_single_lattice`]), where it was measured.
    pub single_lattice: Option<SingleLattice>,
    /// Li_multiple's lattice as settled by its estimated bias, where it was estimated.
    pub multiple_lattice: Option<MultipleLattice>,
    /// Wall-clock milliseconds of the bake's parts, in order, for `-v`.
    pub stages: Vec<(&'static str, u64)>,
}

#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    #[error("invalid parameter: {0}")]
    Param(String),
    #[error(transparent)]
    Gpu(#[from] nimbus_gpu::GpuError),
}

impl BakeStats {
    /// Runs `f` and records its wall-clock time as stage `name`.
    pub fn time<R>(&mut self, name: &'static str, f: impl FnOnce() -> R) -> R {
        let start = std::time::Instant::now();
        let r = f();
        self.stages.push((name, start.elapsed().as_millis() as u64));
        r
    }

    /// Adds `ms` to the stage `name`, where it is the last recorded, else records it (the
    /// paths' first pass and top-up are one stage, whatever the lattice estimate between).
    pub fn add_stage(&mut self, name: &'static str, ms: u64) {
        match self.stages.last_mut() {
            Some((last, t)) if *last == name => *t += ms,
            _ => self.stages.push((name, ms)),
        }
    }

    /// The stages as `name 0.123 s, ...`.
    pub fn describe_stages(&self) -> String {
        self.stages.iter().map(|(n, ms)| format!("{n} {:.3} s", *ms as f64 / 1000.0)).collect::<Vec<_>>().join(", ")
    }

    /// Counts over two lattices (Li_multiple on its own): the voxel counts add up.
    pub fn add(&mut self, other: &BakeStats) {
        self.candidates += other.candidates;
        self.culled_view += other.culled_view;
        self.culled_empty += other.culled_empty;
        self.baked += other.baked;
    }

    /// The voxel counts with one plan's (`old`) replaced by another's (`new`).
    pub fn replace_counts(&mut self, old: &BakeStats, new: &BakeStats) {
        self.candidates = self.candidates - old.candidates + new.candidates;
        self.culled_view = self.culled_view - old.culled_view + new.culled_view;
        self.culled_empty = self.culled_empty - old.culled_empty + new.culled_empty;
        self.baked = self.baked - old.baked + new.baked;
    }
}

impl CacheParams {
    /// The Simpson step toward the lights in world units.
    pub fn single_step(&self, density: &Volume<f32>) -> f64 {
        self.step * density.transform().voxel_size().min_element()
    }

    /// Li_multiple's voxel edge in density voxels.
    pub fn multiple_scale(&self) -> f64 {
        self.multiple_scale.unwrap_or(self.cache_scale)
    }

    /// Whether single scattering is asked for and can be non-zero.
    pub fn bakes_single(&self) -> bool {
        self.single && !self.medium.is_non_scattering() && !self.lights.is_empty()
    }

    /// Optical depth past which a tabled ray stops integrating: a hundredth of
    /// `min_transmittance`, so what callers read as black is resolved well past the cut-off.
    pub fn opaque_depth(&self) -> f64 {
        -(self.min_transmittance * 1e-2).max(1e-300).ln()
    }

    /// The lights' tabled optical depths, where the shadows are tabled and something reads
    /// them (single scattering, or paths' next-event estimation); none otherwise. `emits`:
    /// whether the medium emits (the paths then run without lights too).
    pub fn light_depths(&self, medium: DensityMedium, photons: &nimbus_photon::PhotonMap, emits: bool) -> LightDepths {
        match self.light_lattice(photons, emits) {
            Some(lattice) => LightDepths::build(medium, &self.lights, lattice, self.opaque_depth()),
            None => LightDepths::default(),
        }
    }

    /// The lattice [`CacheParams::light_depths`] tables on, where it tables anything (both
    /// backends ask).
    pub fn light_lattice(&self, photons: &nimbus_photon::PhotonMap, emits: bool) -> Option<LightLattice> {
        let reads = !self.lights.is_empty()
            && (self.bakes_single() || (self.bakes_multiple(photons, emits) && matches!(self.estimator, MultipleEstimator::Paths { .. })));
        match self.shadows {
            ShadowMode::Table(lattice) if reads => Some(lattice),
            _ => None,
        }
    }

    /// Whether an environment sends light (then the paths gather it).
    pub fn lit_by_environment(&self) -> bool {
        self.environment.as_ref().is_some_and(|e| !e.is_black())
    }

    /// Whether multiple scattering is asked for and has something to estimate it from:
    /// photons to gather, or light for the paths to gather (lights, an environment, or the
    /// medium's own emission where `emits`: a fire with no lights still lights its smoke).
    pub fn bakes_multiple(&self, photons: &nimbus_photon::PhotonMap, emits: bool) -> bool {
        self.multiple
            && !self.medium.is_non_scattering()
            && match self.estimator {
                MultipleEstimator::Photons => !photons.is_empty(),
                MultipleEstimator::Paths { .. } => !self.lights.is_empty() || emits || self.lit_by_environment(),
            }
    }

    pub fn validate(&self) -> Result<(), CacheError> {
        self.medium.validate().map_err(|e| CacheError::Param(e.to_string()))?;
        let positive = |name: &str, v: f64| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(CacheError::Param(format!("{name} must be positive, got {v}")))
            }
        };
        positive("--step", self.step)?;
        positive("--cache-scale", self.cache_scale)?;
        positive("--multiple-scale", self.multiple_scale())?;
        if let Some(t) = self.single_tolerance {
            if !(t >= 0.0 && t.is_finite()) {
                return Err(CacheError::Param(format!("--single-tolerance must be 0 or more, got {t}")));
            }
        }
        match self.gather {
            Gather::Neighbours { k, max_radius } => {
                if k == 0 {
                    return Err(CacheError::Param("--gather-neighbours must be at least 1".into()));
                }
                positive("gather max radius", max_radius)?;
            }
            Gather::Radius(r) => positive("--radius", r)?,
        }
        if self.estimator == (MultipleEstimator::Paths { per_voxel: 0 }) {
            return Err(CacheError::Param("--paths must be at least 1".into()));
        }
        if let ShadowMode::Table(l) = self.shadows {
            positive("the light lattice's spacing across", l.across)?;
            positive("the light lattice's spacing along", l.along)?;
        }
        if !(0.0..1.0).contains(&self.min_transmittance) {
            return Err(CacheError::Param(format!("--min-transmittance must be in [0,1), got {}", self.min_transmittance)));
        }
        Ok(())
    }
}
