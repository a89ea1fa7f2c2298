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
//! - Step control from the majorant: in a cell whose density bound makes one lattice step
//!   optically thin, one sample stands for a group of up to `max_step_factor` lattice steps
//!   (vdbmarch's `--max-step-factor`, default 1, a fixed step; [`MarchParams::step_factor`], the groups
//!   in `Groups`), its member picked by a second random offset u; 1 is the plain lattice
//!   march. A longer step samples Li_single's voxel-scale shadow edges more sparsely, which
//!   single scattering alone shows, so the default is 1 (docs/benchmarks.md, "Single
//!   scattering against a brute-force march").
//! - `spp` samples per pixel are jittered over the pixel (box filter), stratified on the
//!   largest square grid of cells (`cpu::pixel_jitter`), each with its own xi.
//! - Offset noise (the paper's Perlin jitter) moves each sample position by a smooth vector
//!   fBm field of amplitude `offset_noise` (world units), breaking up the grid look of
//!   coarse volumes: the medium is read at `x + o(x)`. Per-sample fBm is far slower than the
//!   march, so it is baked once per render ([`NoiseEval`]). By default
//!   ([`NoiseEval::Displaced`], the CPU) the displaced medium itself is baked: at each
//!   point of the density's lattice the density and the cache at `x + o(x)`, `o` the exact
//!   fBm there, each point once (in the 8^3 brick that owns it) when a march first reads a
//!   brick holding it (`offsets.rs`), and the march is
//!   the march without noise over it; the price is a resampling of the density (the image
//!   0.3-0.5% from the exact noise's, about 40% of what the noise itself changes). Where the
//!   density's lattice has fewer than 4 points per `noise_scale`, on the GPU, and with
//!   emission or motion blur, the offsets are baked instead ([`NoiseEval::Baked`]; like the
//!   paper's 3D texture of offsets): the exact fBm at the nodes of a lattice anchored in
//!   world space, 4 nodes per `noise_scale` per axis (one per cell of the finest of
//!   vdbmarch's 3 octaves: every octave is kept, the finest one interpolated coarsely),
//!   over the bricks of nodes within the noise's reach of the medium, interpolated
//!   trilinearly at each sample, over a majorant grid of two-voxel cells dilated by the
//!   noise's reach (0.1% from the exact noise's image, at about 3.5x the plain march). See
//!   docs/benchmarks.md ("Offset noise") for the costs and errors against the exact fBm
//!   ([`NoiseEval::Exact`], kept for the tests and that bench). Amplitude 0 costs nothing:
//!   no bake, no dilation.
//! - Rays stop once T < `min_transmittance`; rays that miss every non-empty majorant cell
//!   cost one DDA walk.
//!
//! Emission (issue #19, [`render_cpu_with`] and `march_ray_with` with a [`MediumFields`] holding, an
//! [`EmissionField`]): each sample also adds `T e(x) (1 - exp(-sigma_t dt)) / sigma_t`, e the
//! emitted radiance per unit length, the exact integral of `T e` over the step for e and
//! sigma_t constant over it; it goes to [`RayResult::emission`] (the `emission` layer). So
//! far the CPU runs it in the plain march only (f64 over the sparse volumes, about the speed
//! of [`march_ray`]), not in the layout's fused march; the GPU's march adds it in the same
//! samples ([`render_gpu_with`], `shaders/emission.wgsl`). The reference adds
//! `beta e / sigma_t` at each real collision ([`render_reference_cpu_with`],
//! [`render_reference_gpu_with`]).
//! The emission the medium scatters is not the march's: it comes through the cache's Li
//! (vdbcache's paths gather it, vdbphoton's photons carry it), so the march adds the
//! unscattered emission only and nothing is counted twice.
//!
//! `vdbmarch --reference` renders the same image by an unbiased path tracer over the
//! density alone ([`render_reference_cpu`], [`ReferenceParams`]; see `reference.rs`): the
//! ground truth every accuracy figure is measured against.
//! `vdbmarch --verify` traces a sample of the marched image's blocks with the same
//! tracer and reports the image's error against them ([`verify_cpu`], `verify.rs`).
//!
//! # Backends
//!
//! Both read the same [`MarchParams`], compute one [`RayResult`] per pixel and hand them to
//! the same image assembly ([`Image::from_rays`], through one function).
//!
//! - [`render_cpu`]: bands of 8 x 8 pixel tiles in parallel with rayon, over the march's
//!   own layout of the volume (`layout.rs`: density and cache fused into one lattice of
//!   apron bricks, a dense brick table, each brick's box of cells to visit and a bit per
//!   cell with a corner of positive density, whose samples alone are taken), built once per
//!   render; f32 from each lookup on, eight samples' cells and exponentials at a time, with
//!   an AVX2+FMA copy of the loop picked at run time (`simd.rs`). [`march_ray`] is the same
//!   estimator in its plainest form (f64, the sparse volumes' own lookups), which the
//!   tests hold the layout's march to (1e-4 on lit pixels; 3.5e-6 measured).
//! - [`render_gpu`] / [`render_gpu_with`]: one wgpu invocation per pixel
//!   (`shaders/march.wgsl`, over `shaders/tracking.wgsl` for the majorant DDA and
//!   `shaders/noise.wgsl`, the bit-exact-hash WGSL twin of `nimbus_optics::noise`, for the
//!   exact offset noise; the baked one is the CPU's bake itself, its brick table and nodes
//!   in two storage buffers, interpolated in the CPU's order). Pixel i draws from the same Philox stream as on the CPU, in the same
//!   order (jitter, then the lattice offset xi, per sample; u from its own stream), and
//!   reads the CPU's step factor per majorant cell, so the two images agree to f32
//!   rounding (the tests hold lit pixels to 1e-4 relative). The density is the default
//!   volume of the brick atlas, sampled exactly; `Li_single` and `Li_multiple` are two more
//!   atlas volumes, read by hardware-filtered lookups where the device filters float
//!   textures ([`CacheLookup::Filtered`], the default: within ~1/256 of Li's local range
//!   of the exact value) or exactly ([`CacheLookup::Exact`]). Positions are f32 relative to
//!   the eye, exact-noise positions split into a lattice point and a remainder, baked-noise
//!   ones the eye's position in the offset lattice plus the sample's offset from the eye, so
//!   far-from-origin scenes keep their precision. Across adjacent non-empty majorant segments both carry
//!   the group start over instead of recomputing it from the segment start, so a lattice
//!   point lying on a boundary within f32 rounding is taken exactly once; `1 - exp(-sigma_t dt)` is evaluated
//!   without cancellation in thin media.

// The unit tests share tests/common, which names this crate.
#[cfg(test)]
extern crate self as nimbus_march;

mod cpu;
mod gpu;
mod image;
mod layout;
mod offsets;
mod reference;
mod samples;
mod simd;
mod verify;
mod view;

pub use cpu::{march_ray, render_cpu, render_cpu_with, RayResult, MOTION_DOMAIN};
pub use nimbus_tracking::{EmissionField, Motion, MotionBlur};
pub use gpu::{render_gpu, render_gpu_with, CacheLookup, GpuMarchOptions, MARCH_WGSL, NOISE_WGSL};
pub use image::{Image, ImageError};
pub use view::ViewTransform;
pub use samples::{default_spp, default_step, step_subdivision, MAX_DEFAULT_SAMPLES_PER_SIDE, MAX_STEP_SUBDIVISION};
pub use verify::{estimate, verify_cpu, BlockSample, Estimate, Verification, VerifyParams, VERIFY_SEED};
pub use reference::{reference_tile_pixels, render_reference_cpu, render_reference_cpu_with, render_reference_gpu, render_reference_gpu_with, ReferenceParams, REFERENCE_WGSL};

/// What the medium holds beyond its density, for the renders that take it (`render_cpu_with`
/// and its twins): its emission and its motion over the shutter. The default is neither: the
/// plain render.
#[derive(Clone, Copy, Default)]
pub struct MediumFields<'a> {
    /// The emission field; none emits.
    pub emission: Option<&'a EmissionField<'a>>,
    /// Eulerian motion blur: the velocity grid and the shutter.
    pub motion: Option<&'a MotionBlur<'a>>,
    /// Single scattering by shadow rays at each sample instead of the cache's Li_single
    /// (the CPU march only: [`DirectSingle`]).
    pub direct_single: Option<&'a DirectSingle<'a>>,
}

/// Single scattering evaluated at each march sample (issue #47): `sum over lights
/// p E T_light(x)` by a Simpson shadow ray toward each light through the trilinear density
/// (`nimbus_cache::li_single` with no light tables, what vdbcache bakes at its nodes with
/// `--shadows rays`), in place of the cache's Li_single where no lattice of it would do
/// (`nimbus_cache::SingleLattice::direct`: the sun's transmittance bending within a quarter
/// voxel at a rim lit from behind). Its cost is a shadow ray per sample and light.
pub struct DirectSingle<'a> {
    pub lights: &'a [nimbus_optics::Light],
    /// The density's majorant, which the shadow rays skip empty space by.
    pub majorant: MajorantGrid,
    /// Simpson step toward the lights, world units.
    pub step: f64,
    tables: nimbus_tracking::LightDepths,
}

impl<'a> DirectSingle<'a> {
    /// The shadow rays' Simpson step in voxel edges: one. The panels split at voxel
    /// boundaries, within which the trilinear density along a line is a cubic, which
    /// Simpson's rule integrates exactly: a finer step (a tiny `vdbcache --step`) would only
    /// cost time, a shadow ray at every sample.
    pub const STEP: f64 = 1.0;

    /// For `lights` over `density`, shadow rays in Simpson steps of [`DirectSingle::STEP`].
    pub fn new(density: &Volume<f32>, lights: &'a [nimbus_optics::Light]) -> DirectSingle<'a> {
        let step = Self::STEP * density.transform().voxel_size().min_element();
        DirectSingle { lights, majorant: MajorantGrid::build(density), step, tables: nimbus_tracking::LightDepths { per_light: lights.iter().map(|_| None).collect() } }
    }

    /// Li_single at `x` toward `w_out` for `medium`'s optics, transmittance below `cutoff`
    /// counting as none.
    pub fn li(&self, density: &Volume<f32>, optics: &Medium, x: DVec3, w_out: Vec3, cutoff: f64) -> Vec3 {
        let medium = nimbus_tracking::DensityMedium { density, majorant: &self.majorant, extinction: optics.extinction, motion: None };
        nimbus_cache::li_single(medium, optics, self.lights, &self.tables, x, w_out, self.step, cutoff)
    }
}

/// The image from per-pixel ray results (pixel 0 top-left, rows top to bottom): what every
/// backend ends with.
pub(crate) fn assemble(params: &MarchParams, pixels: &[RayResult]) -> Image {
    Image::from_rays(params.camera.width(), params.camera.height(), pixels, constant_background(params.background, params.visible_environment()), params.aovs)
}

/// The background every escaping camera ray sees alike: `background`, or a uniform sky in
/// its place. A map varies with the direction: [`RayResult::behind`] carries it instead.
pub(crate) fn constant_background(background: Vec3, visible: Option<&Environment>) -> Vec3 {
    match visible {
        Some(Environment::Uniform(c)) => *c,
        Some(Environment::Map { .. }) => Vec3::ZERO,
        None => background,
    }
}

/// The map camera rays see where they leave the volume, if they see one: what each sample
/// adds as `T L_env(dir)` ([`RayResult::behind`]).
pub(crate) fn visible_map(visible: Option<&Environment>) -> Option<&Environment> {
    visible.filter(|e| matches!(e, Environment::Map { .. }))
}

use glam::{DVec3, Vec3};
use nimbus_optics::{Camera, Environment, Medium};
use nimbus_volume::{MajorantGrid, Volume};

/// Everything a render depends on; the CPU and GPU backends read the same struct.
#[derive(Clone, Debug)]
pub struct MarchParams {
    pub medium: Medium,
    pub camera: Camera,
    /// Step along camera rays, world units: where the density is thin, lengthened up to
    /// `max_step_factor` times ([`MarchParams::step_factor`]; see the crate doc).
    pub step: f64,
    /// Most a step may be lengthened in optically thin majorant cells (1: a fixed step).
    pub max_step_factor: u32,
    /// Samples per pixel.
    pub spp: u32,
    pub background: Vec3,
    /// The sky or map the cache was lit by: camera rays that leave the volume see it in
    /// place of `background` where `environment_visible` (vdbmarch without --background).
    pub environment: Option<Environment>,
    pub environment_visible: bool,
    /// Amplitude of the sample-position jitter field, world units (0: off).
    pub offset_noise: f64,
    /// Feature size of the jitter field, world units.
    pub noise_scale: f64,
    pub noise_octaves: u32,
    /// How the jitter field is evaluated: baked on a world-anchored lattice (the default)
    /// or exactly at every sample.
    pub noise_eval: NoiseEval,
    pub min_transmittance: f64,
    pub seed: u64,
    /// Keep the single, multiple, transmittance and depth layers.
    pub aovs: bool,
}

/// How the march evaluates the offset noise (design.md section 9): a function of the
/// sample's world position either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseEval {
    /// The fBm baked once per render at the nodes of a lattice anchored in world space,
    /// `nodes` per `noise_scale` along each axis, over the cells the march can visit, and
    /// interpolated trilinearly at each sample. Where that spacing would be under half the
    /// density's voxel (a noise scale under two voxels at 4 nodes), more nodes than samples,
    /// the fBm is evaluated at each sample instead, on both backends.
    Baked { nodes: u32 },
    /// The default: the displaced medium baked, the density and the cache read at
    /// `x + o(x)` at each point `x` of the density's lattice, `o` the exact fBm there, so
    /// that the CPU marches it as it marches a medium without noise (`offsets.rs`,
    /// [`render_cpu`]); the image is the exact noise's within the figures of
    /// docs/benchmarks.md ("Offset noise"). Where the density's lattice has fewer than
    /// [`NoiseEval::DISPLACED_POINTS_PER_SCALE`] points per noise scale along an axis, on
    /// the GPU, and in the CPU's emission and motion-blur march, the offsets are read at
    /// each sample instead, as [`NoiseEval::Baked`] with [`NoiseEval::BAKED_NODES`].
    Displaced,
    /// The fBm evaluated at every sample: the definition, kept for the tests and the bench
    /// that measure the baked field against it (tens of times the march's cost).
    Exact,
}

impl NoiseEval {
    pub const DEFAULT: NoiseEval = NoiseEval::Displaced;

    /// Nodes per noise scale of the offset lattice read per sample where
    /// [`NoiseEval::Displaced`] does not apply.
    pub const BAKED_NODES: u32 = 4;

    /// The fewest density lattice points per noise scale along each axis with which
    /// [`NoiseEval::Displaced`] bakes the displaced medium: as many as
    /// [`NoiseEval::BAKED_NODES`], so that it resolves the noise as finely.
    pub const DISPLACED_POINTS_PER_SCALE: f64 = 4.0;

    /// The offset lattice's nodes per noise scale where the offsets are baked and read per
    /// sample (as [`NoiseEval::Displaced`] is where it does not apply).
    pub fn nodes(self) -> Option<u32> {
        match self {
            NoiseEval::Baked { nodes } => Some(nodes),
            NoiseEval::Displaced => Some(Self::BAKED_NODES),
            NoiseEval::Exact => None,
        }
    }
}

impl Default for NoiseEval {
    fn default() -> Self {
        NoiseEval::DEFAULT
    }
}

/// Most optical depth, at its cell's density bound, that a lengthened step may span
/// ([`MarchParams::step_factor`]).
pub const STEP_OPTICAL_DEPTH: f64 = 0.25;

impl MarchParams {
    /// vdbmarch's defaults for `camera` over a density on `transform`: one sample a pixel at
    /// the default step ([`default_step`]), a fixed step
    /// ([`Self::DEFAULT_MAX_STEP_FACTOR`]), no offset noise (its features four voxels, three
    /// octaves), a black background and no environment, rays cut at transmittance 1e-4,
    /// seed 0, no AOVs.
    pub fn new(medium: Medium, camera: Camera, transform: &nimbus_volume::Transform) -> MarchParams {
        MarchParams {
            medium,
            camera,
            step: default_step(transform),
            max_step_factor: Self::DEFAULT_MAX_STEP_FACTOR,
            spp: 1,
            background: Vec3::ZERO,
            environment: None,
            environment_visible: false,
            offset_noise: 0.0,
            noise_scale: 4.0 * transform.voxel_size().max_element(),
            noise_octaves: 3,
            noise_eval: NoiseEval::DEFAULT,
            min_transmittance: 1e-4,
            seed: 0,
            aovs: false,
        }
    }

    /// The environment escaping camera rays see, if any.
    pub fn visible_environment(&self) -> Option<&Environment> {
        self.environment.as_ref().filter(|_| self.environment_visible)
    }

    /// vdbmarch's `--max-step-factor`: 1, a fixed step. The optical-depth bound keeps the
    /// transmittance right, but a lengthened step also samples the cache more sparsely, and
    /// Li_single varies at the voxel scale (shadow edges) however thin the medium: at 2, the
    /// bundled plume's single scattering was 0.51% off a brute-force march (0.31% at 1) and
    /// the cloud's 0.34% (0.25%), for 15% of the Cloud1-class march's time (0.84 -> 0.72 s).
    pub const DEFAULT_MAX_STEP_FACTOR: u32 = 1;

    /// How many lattice steps one sample stands for in a majorant cell whose density stays
    /// below `majorant`: the largest whole factor up to `max_step_factor` that keeps such a
    /// step's optical depth at the bound within [`STEP_OPTICAL_DEPTH`], and 1 wherever one
    /// lattice step is thicker. Step control from the majorant: in the Cloud1-class scene
    /// most samples fall in cells whose bound is below 1/64 of an optical depth per step.
    pub fn step_factor(&self, majorant: f32) -> u32 {
        let depth = self.medium.extinction as f64 * majorant as f64 * self.step;
        let factor = (STEP_OPTICAL_DEPTH / depth).floor();
        // NaN (no bound) keeps the lattice step.
        if factor >= 1.0 {
            factor.min(self.max_step_factor as f64) as u32
        } else {
            1
        }
    }
}

/// Which samples a march takes along a ray, the same in every march (`cpu.rs`, mirrored by
/// `shaders/march.wgsl`).
///
/// The lattice `t_k = (k + xi) dt` is split into groups of consecutive lattice points, each
/// as long as the step factor of the majorant cell its first point lies in; a group's
/// sample is its member `floor(u g)` (g its size, u in [0, 1) per ray like xi) and stands
/// for its g steps. Groups tile the lattice across adjacent non-empty cells (the group
/// start carries over), and start afresh after skipped empty space. With factor 1 every
/// lattice point is a sample: the plain lattice march. A group may reach past its cell: its
/// sample is then looked up wherever it falls (empty space reads zero), which keeps the
/// tiling whole, so coarser steps add no noise where the factor changes: restarting the
/// lattice per cell instead doubled the opacity error against the path-traced reference.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Groups {
    /// The first lattice point of the next group, and where the last cell ended.
    next: f64,
    end: f64,
}

/// The groups starting in one cell ([`Groups::cell`]): group j's sample is lattice point
/// `first + j * size`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CellGroups {
    pub first: f64,
    pub count: usize,
    pub size: u32,
}

impl Groups {
    pub fn new() -> Groups {
        Groups { next: f64::NEG_INFINITY, end: f64::NAN }
    }

    /// The groups starting in the cell `[t_start, t_end)` of step factor `factor`, whose
    /// first members are the lattice points there from the carried group start (or the first
    /// point in the cell after a gap), `factor` apart; their samples, member `floor(u
    /// factor)` of each.
    #[inline(always)]
    pub fn cell(&mut self, t_start: f64, t_end: f64, dt: f64, xi: f64, u: f64, factor: u32) -> CellGroups {
        let (g, per_dt) = (factor as f64, 1.0 / dt);
        // After a gap, the first lattice point in the cell, unless the last group reached
        // past it.
        let start = if t_start == self.end { self.next } else { (t_start * per_dt - xi).ceil().max(self.next) };
        // Groups j >= 0 with (start + j g + xi) dt < t_end: estimated, then settled by
        // that very test.
        let starts = |j: f64| (start + j * g + xi) * dt < t_end;
        let mut count = ((t_end * per_dt - xi - start) * (1.0 / g)).ceil().max(0.0);
        while starts(count) {
            count += 1.0;
        }
        while count > 0.0 && !starts(count - 1.0) {
            count -= 1.0;
        }
        // The start may lie past this cell already (a group longer than the cell).
        self.next = start + count * g;
        self.end = t_end;
        CellGroups { first: start + (u * g).floor().min(g - 1.0), count: count as usize, size: factor }
    }
}

/// Random-number domain of the group members' u (its own stream per pixel, so the jitter
/// and lattice draws stay as they were).
pub(crate) const GROUP_DOMAIN: u32 = 0x5354_4550; // "STEP"

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
        if self.max_step_factor == 0 {
            return Err(MarchError::Param("--max-step-factor must be at least 1".into()));
        }
        if !(self.offset_noise >= 0.0 && self.offset_noise.is_finite()) {
            return Err(MarchError::Param(format!("--offset-noise must be >= 0, got {}", self.offset_noise)));
        }
        if self.offset_noise > 0.0 && !(self.noise_scale > 0.0 && self.noise_scale.is_finite()) {
            return Err(MarchError::Param(format!("--noise-scale must be positive, got {}", self.noise_scale)));
        }
        if self.noise_eval.nodes() == Some(0) {
            return Err(MarchError::Param("the baked offset noise needs at least one node per noise scale".into()));
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
