//! nimbus-density: particles in, a sparse density volume out — the engine of `particles2vdb`.
//!
//! ```text
//! read_particles / read_path        PLY (ascii, binary LE/BE), CSV/TSV      particles.rs
//!        |  ParticleSet (f64 world positions, optional f32 masses) + ReadReport
//! prepare(particles, params)        backend-independent set-up              setup.rs
//!        |  h0 (fixed or auto), grid, particles rebased to index space as f32,
//!        |  counting sort into cells, bricks within kappa*h0 of a particle
//! estimate_cpu | estimate_gpu       rayon splat per brick | wgpu gather per   cpu.rs, gpu.rs
//!        |                          voxel (shaders/density.wgsl)
//!        |  per voxel: h from the method, rho = sum m W(|x - x_q|, h)       kernel.rs
//! attributes (when asked)           rho at the particles, then an SPH       attributes.rs, cpu.rs,
//!        |                          sum of every requested attribute with   gpu.rs
//!        |                          the voxels' h
//! finish                            noise, threshold, volumes, stats        lib.rs, optics::noise
//!        v  DensityOutput { density: Volume<f32>, smoothing_length?, neighbour_count?,
//!                           attributes (float or vec3 volumes), stats }
//! ```
//!
//! # The mathematics (design.md section 8)
//!
//! Kernel: cubic spline M4, support kappa*h with kappa = 2 ([`kernel`]). Methods ([`Method`]):
//! `usl` h = h0; `asl2` h = h1 from the count N0 within kappa*h0; `asl3` corrects h1 with the
//! count N1 within kappa*h1; `knn` h = distance to the N*-th nearest / kappa (exact
//! reference); `ici` (issue #21, the default) h from a ladder by the local error, below.
//! Every h is clamped to [h_min, h0], h_min defaulting to 1.2 voxels (0.75 for ici). The
//! per-grid-point functions ([`kernel::predict_h1`], [`kernel::correct_h`],
//! [`kernel::clamp_h`], [`kernel::m4_shape`]) are pure f32 so a WGSL backend can mirror them.
//!
//! # Decisions a user can see
//!
//! - Grid: voxel footprints tile the bounds; index (0,0,0) is the voxel at the bounds' low
//!   corner, its value at that voxel's centre, `low + voxel/2` ([`Grid`]). Bounds default to
//!   the particles' box padded by kappa*h0, so density reaches zero inside the grid.
//!   `Resolution::Longest(n)` puts n voxels on the longest axis of the bounds.
//! - `h0 auto` ([`auto_h0`]): (4/3) pi (kappa h0)^3 n_p = N*, n_p the number density below
//!   which only 10% of the particles live (histogram over cells of edge 2 kappa h0); never
//!   below h_min.
//! - Active voxels: rho > `active_tolerance` (default 1e-6) times the maximum density. The
//!   kernel has compact support, so this only drops rounding dust and far-tail values; each
//!   dropped voxel loses at most tolerance * max * voxel volume of mass.
//! - Noise: `rho * max(0, 1 + amp * fbm(x / L))` at the world position x, so the pattern stays
//!   fixed in the world when bounds change between frames; or, with
//!   [`DensityParams::noise_rest`], at the rest position interpolated from a vec3 particle
//!   attribute (Houdini's `rest`) as the attributes are, so it moves and deforms with the
//!   particles (a translated particle set with the same rest positions gives the same
//!   density, translated).
//! - Attributes ([`DensityParams::attributes`], [`AttributeOutput`], issue #20): a float or
//!   vec3 per-particle attribute A becomes
//!   `A(x) = sum_q V_q A_q W(|x - x_q|, h(x)) / sum_q V_q W(|x - x_q|, h(x))`, V_q = m_q / rho_q,
//!   with each voxel's final h(x) and rho_q the density grid (before noise and threshold)
//!   read trilinearly at the particle. Normalised (Shepard) wherever the kernel sum is
//!   positive, i.e. wherever the density is: a constant stays that constant out to the rim,
//!   values never leave the particles' range, and where the density is 0 the attribute is 0
//!   and inactive. Non-finite values are left out of their attribute's sums and counted.
//!   Measured (tests/attributes.rs): against a direct f64 sum over all particles within 2e-5
//!   relative; a linear field on a jittered lattice within 0.076 |grad v| h inside and 0.40
//!   |grad v| h in the one-sided rim. Both backends run it over the same channel values:
//!   the CPU splats per brick (`cpu::splat_attributes`), the GPU gathers per voxel
//!   (`gpu::AttributePass`, eight channels a dispatch), within 6e-6 of the direct sum and
//!   3e-7 of the CPU (crates/density/tests/attributes.rs). On the CPU: one kernel
//!   evaluation per (particle, voxel) for every channel (a kernel sum shared by the attributes without non-finite values, then the
//!   components; its cost is in docs/benchmarks.md). The readers' naming rule
//!   (vec3 from `vx vy vz`, `v_x ..`, `v.x ..`, `v[0] ..`; aliases `vel`, `Cd`/`color`) is in
//!   [`available_attributes`] and [`find_attribute`].
//! - Stats ([`DensityStats`]): over grid points whose voxel footprint holds at least one
//!   particle, mean and std of the particles used (within kappa*h) — the paper's Table 2.
//!
//! # How the work is organised (and where it departs from the paper's wording)
//!
//! - Binning: particles are counting-sorted into uniform cells (edge ~kappa*h0, kept within
//!   2..16 voxels). The per-grid-point queries are batched per 8^3 brick: a brick gathers the
//!   particles of the cells overlapping it plus a kappa*h0 margin once, and every pass then
//!   splats each particle onto the brick's z columns inside the square that bounds its
//!   support, one column of 8 voxels at a time (vectorised, each voxel tested against its own
//!   radius; the density pass takes two columns per step on AVX-512). That is the paper's
//!   rectangle drawing done per brick: each pass costs the (particle, voxel) pairs within
//!   those squares, O(N) for bounded h0, with no 27-cell candidate waste. (Squares, not the
//!   support's discs: the discs' per-row square roots and varying row lengths cost more than
//!   the squares' masked corners.)
//!   Only bricks within kappa*h0 of some particle are proposed.
//! - ici, the default (issue #21, [`kernel::ici_ladder`], `ici.rs`): a ladder of lengths
//!   h_1 < .. < h_K from h_min (0.75 voxel by default, [`ICI_H_MIN_VOXELS`]) to h0,
//!   geometric, at most 1.5 apart, at most 8. One splat pass over the widest rung's square
//!   per particle sums, per rung, m W and (m W)^2 (a column takes only the rungs whose
//!   support its nearest voxel lies in; the distance's square root is shared). Then the rule
//!   over the whole grid (`ici.rs`, one host function for both backends): each rung's bias
//!   from its debiased squared differences from the next shorter rung and the shortest,
//!   averaged over a box of radius h_k about the voxel and extrapolated by the h^2 law, the
//!   rung of least bias^2 + Gamma^2 var (Gamma = 0.8, [`DEFAULT_ICI_CONFIDENCE`]), the rung
//!   index averaged over 5^3 voxels and the length interpolated between rungs; then the
//!   density pass at those lengths, as conserve-mass's does. The GPU's `ladder` pass
//!   (shaders/density.wgsl) returns the rung sums to the host. Until session 28 the rule was
//!   per voxel (Goldenshluger-Lepski's, Gamma 1.75, then the least rung among 27
//!   neighbours; docs/benchmarks.md has that rule's measurements): a voxel's own
//!   differences are noise-dominated exactly where the bias matters, which the box mean of
//!   the debiased squares is not.
//! - knn: the N*-th nearest is selected (select_nth) among the particles within kappa*h0 of the
//!   voxel; beyond that h would exceed h0 and be clamped to h0, so the bounded search is exact.
//! - Mass: usl conserves mass to discretisation error. The adaptive methods are gather
//!   estimates with h varying between grid points, which is not exactly mass conserving where
//!   density contrasts are steep (a sparse point's wide kernel reaches into a dense knot):
//!   by a few percent on the analytic test scenes (docs/benchmarks.md; tests/reference.rs
//!   `mass_is_conserved` holds the bound).
//!   `conserve_mass` (`--conserve-mass`, off by default) makes it exact at the cost of one more
//!   kernel pass once h(x) is final: each particle's kernel summed over the grid as the density
//!   pass will weigh it, S_q = sum_x W(|x - x_q|, h(x)) dV, and rho(x) = sum_q (m_q / S_q)
//!   W(|x - x_q|, h(x)), so sum_x rho dV = sum_q m_q to rounding ([`normalised_masses`] has the
//!   rule for particles near the grid's edge). On the CPU the S pass splats per brick like the
//!   others and the per-(brick, particle) partials are summed in brick order (bit-identical
//!   between runs); the GPU gathers per particle over the grid points of its support box.
//!
//! # Accuracy and mass: what the tests hold
//!
//! The measurements (relative L2 against analytic densities by method, N* and h_min; mass;
//! speed; how ici's rule was found) are in docs/benchmarks.md, reproduced by
//! `examples/accuracy.rs` and `benches/estimate.rs`. What the crate promises:
//!
//! - asl3 is as good as knn at the same N* (the predictor-corrector against the exact
//!   neighbour search); both are far better than usl with h0 off by 2x.
//! - The defaults: ici, which is at or below the best-tuned usl on every analytic test scene
//!   with no per-scene setting; asl3 at N* = [`DEFAULT_NEIGHBOURS`] and h_min =
//!   [`DEFAULT_H_MIN_VOXELS`] (issue #18 chose accuracy over exact mass and speed).
//! - usl conserves mass to discretisation error; the adaptive methods do not exactly (see
//!   "Mass" above), and tests/reference.rs `mass_is_conserved` bounds their excess;
//!   `conserve_mass` makes it exact to the active threshold's dust.
//!

//! # Backends
//!
//! [`estimate_cpu`] and [`estimate_gpu`] take the same [`DensityParams`] and run the same
//! pipeline: [`prepare`] (h0, grid, counting sort into cells, brick proposal), the method's
//! passes on the backend, then one shared path for the results (world normalisation of the
//! per-brick sums, the Table 2 occupancy) and the finishing step (noise, threshold, volumes,
//! stats). The passes differ only in how they walk the (particle, voxel) pairs: the CPU splats
//! per brick (above); the GPU (`shaders/density.wgsl`, one invocation per voxel and pass)
//! gathers from the cells its support overlaps, since WGSL has no float atomics for a
//! scatter. knn on the GPU keeps the N* nearest in a private sorted list up to N* = 64 and
//! bisects on the bits of the squared distance with counting passes above that (exact, slower).
//! Both use the [`kernel`] functions' f32 arithmetic, so they agree with each other and with a
//! brute-force reference to float tolerance (tests/reference.rs).

pub mod analytic;
mod attributes;
mod cpu;
mod gpu;
mod ici;
pub mod kernel;
mod params;
mod particles;
mod setup;

use std::time::{Duration, Instant};

use glam::{DVec3, IVec3, Vec3};
use nimbus_gpu::{GpuContext, GpuError};
use nimbus_volume::{brick_local, brick_offset, BrickMask, Transform, Volume, Voxel, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

/// Seeded Perlin/fBm noise, shared with the renderer's offset noise (it began here).
pub use nimbus_optics::noise;
pub use params::{DensityParams, HMin, Method, NoiseParams, Resolution, DEFAULT_H_MIN_VOXELS, DEFAULT_ICI_CONFIDENCE, DEFAULT_NEIGHBOURS, H0, ICI_H_MIN_VOXELS};
pub use attributes::{AttributeOutput, AttributeVolume};
pub use particles::{
    attribute_aliases, available_attributes, find_attribute, read_particles, read_particles_with, read_path, write_ply, Attribute, Format, ParticleSet, ReadError, ReadReport,
};
pub use setup::{auto_h0, bin, plan_grid, prepare, CellGrid, Grid, Prepared, AUTO_H0_PERCENTILE};

#[derive(Debug, thiserror::Error)]
pub enum DensityError {
    #[error("no particles to estimate a density from")]
    NoParticles,
    #[error("invalid {name} {value}: {why}")]
    InvalidParam { name: &'static str, value: String, why: &'static str },
    #[error("grid of {dims:?} voxels exceeds the budget of {max} voxels (use a larger voxel size or a lower resolution)")]
    TooManyVoxels { dims: [f64; 3], max: u64 },
    #[error("cannot choose h0 automatically: the particles span no volume (give h0 or a voxel size)")]
    H0Undetermined,
    #[error("no particle attribute `{name}` (available: {available})")]
    UnknownAttribute { name: String, available: String },
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// The per-grid-point parameters in index (voxel) units: what the passes read, and the
/// uniform block a GPU backend uploads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointParams {
    /// N* as f32.
    pub n_star: f32,
    pub h0: f32,
    pub h_min: f32,
    pub relax: f32,
    /// ici's Gamma.
    pub confidence: f32,
    /// World voxel edge, to turn index-unit kernels into world densities.
    pub voxel_size: f64,
}

impl PointParams {
    pub fn new(grid: &Grid, params: &DensityParams) -> PointParams {
        PointParams {
            n_star: params.neighbours as f32,
            h0: (grid.h0 / grid.voxel_size) as f32,
            h_min: (grid.h_min / grid.voxel_size) as f32,
            relax: params.relax,
            confidence: params.confidence,
            voxel_size: grid.voxel_size,
        }
    }

    /// 1 / (pi h^3) for h in index units, as a world-space kernel normalisation.
    #[inline]
    pub fn world_norm(&self, h_index: f32) -> f32 {
        let h = h_index as f64 * self.voxel_size;
        (1.0 / (std::f64::consts::PI * h * h * h)) as f32
    }

    /// 1 / (pi h^3) for h in index units, in index units: W dV with dV = one voxel, the
    /// weight of a kernel term in the conserve-mass sums S_q.
    #[inline]
    pub fn index_norm(&self, h_index: f32) -> f32 {
        let h = h_index as f64;
        (1.0 / (std::f64::consts::PI * h * h * h)) as f32
    }
}

/// conserve-mass: the masses the density pass uses, m_q / S_q, from each particle's kernel
/// sum over the grid S_q = sum_x m4_shape(|x - x_q| / h(x)) / (pi h(x)^3) (index units, so
/// dV = 1), as the backends accumulated it.
///
/// Only a particle whose whole support (radius kappa*h0, h0 bounding every h(x)) reaches no
/// grid point outside the grid is normalised: one that explicit bounds cut keeps its mass,
/// or the grid would pull the mass of its outside part inside. With the default bounds
/// (padded by kappa*h0) every particle qualifies. A sum that is not positive and finite
/// (no grid point within reach) leaves the mass as it is.
pub(crate) fn normalised_masses(prep: &Prepared, pp: &PointParams, sums: &[f64]) -> Vec<f32> {
    let r0 = kernel::KAPPA * pp.h0;
    let dims = prep.grid.dims.as_vec3();
    prep.positions
        .iter()
        .zip(&prep.masses)
        .zip(sums)
        .map(|((&p, &m), &s)| {
            // Grid points lie at integer indices 0..dims-1, and the support is open (r < r0).
            let interior = (p - r0).cmpgt(Vec3::splat(-1.0)).all() && (p + r0).cmplt(dims).all();
            if interior && s.is_finite() && s > 0.0 {
                (m as f64 / s) as f32
            } else {
                m
            }
        })
        .collect()
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Timings {
    /// h0, grid, binning and brick proposal ([`prepare`]).
    pub prepare: Duration,
    /// The method's passes.
    pub estimate: Duration,
    /// Noise, threshold, building the volumes, statistics.
    pub finish: Duration,
    /// The attribute pass (density at the particles, the splat, normalisation; its volumes
    /// are built in `finish`).
    pub attributes: Duration,
}

impl Timings {
    pub fn total(&self) -> Duration {
        self.prepare + self.estimate + self.attributes + self.finish
    }
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct DensityStats {
    /// Particles binned (finite, near the grid).
    pub particles: u64,
    pub skipped_nonfinite: u64,
    /// Particles too far outside explicit bounds to matter.
    pub outside: u64,
    pub cells: u64,
    pub bricks_proposed: u64,
    pub bricks_active: u64,
    pub active_voxels: u64,
    /// Over grid points whose voxel footprint holds >= 1 particle: particles used (within
    /// kappa*h), mean and standard deviation, and how many such points there were.
    pub used_mean: f64,
    pub used_std: f64,
    pub used_points: u64,
    pub max_density: f32,
    /// sum of rho * voxel volume over active voxels: the mass the grid holds.
    pub grid_mass: f64,
    pub timings: Timings,
}

pub struct DensityOutput {
    pub density: Volume<f32>,
    /// h* per active voxel, world units.
    pub smoothing_length: Option<Volume<f32>>,
    /// Particles used per active voxel.
    pub neighbour_count: Option<Volume<f32>>,
    /// The requested attributes ([`DensityParams::attributes`]), in request order.
    pub attributes: Vec<AttributeOutput>,
    pub grid: Grid,
    pub stats: DensityStats,
}

/// Estimates the density on the CPU (rayon over bricks, splat passes): [`prepare`], the
/// method's passes, then the finishing step shared with [`estimate_gpu`].
pub fn estimate_cpu(particles: &ParticleSet, params: &DensityParams) -> Result<DensityOutput, DensityError> {
    estimate_with(
        particles,
        params,
        |prep, pp, keep| Ok(cpu::estimate_bricks(prep, params.method, params.conserve_mass, pp, keep)),
        attributes::splat_cpu,
    )
}

/// Estimates the density on the GPU (one wgpu invocation per voxel and pass, gathering from
/// the same cells, `shaders/density.wgsl`): the same [`prepare`] and finishing step as
/// [`estimate_cpu`], and the same f32 per-point arithmetic, so the two agree to rounding.
pub fn estimate_gpu(ctx: &GpuContext, particles: &ParticleSet, params: &DensityParams) -> Result<DensityOutput, DensityError> {
    estimate_with(
        particles,
        params,
        |prep, pp, keep| Ok(gpu::estimate_bricks(ctx, prep, params.method, params.conserve_mass, pp, keep)?),
        {
            // The particles and their values go up once, on the first slice of bricks.
            let mut pass: Option<gpu::AttributePass> = None;
            move |prep: &Prepared, pp: &PointParams, bricks: &[BrickResult], values: &[f32], channels: usize| {
                let pass = match &mut pass {
                    Some(pass) => pass,
                    None => pass.insert(gpu::AttributePass::new(ctx, prep, pp, values, channels)?),
                };
                Ok(pass.sums(bricks)?)
            }
        },
    )
}

/// The pipeline every backend runs: prepare, the backend's passes (per-brick sums), results
/// (normalisation, occupancy) and finish (noise, threshold, volumes, stats).
fn estimate_with(
    particles: &ParticleSet,
    params: &DensityParams,
    passes: impl FnOnce(&Prepared, &PointParams, &Keep) -> Result<Vec<BrickResult>, DensityError>,
    mut attribute_splat: impl FnMut(&Prepared, &PointParams, &[BrickResult], &[f32], usize) -> Result<Vec<Vec<[f32; BRICK_VOXELS]>>, DensityError>,
) -> Result<DensityOutput, DensityError> {
    let t0 = Instant::now();
    let wanted = attributes::check(particles, &params.attributes)?;
    // The noise's rest positions ride the attribute pass after the requested attributes.
    let rest = match params.noise_rest.as_ref().filter(|_| noise_rest_used(params)) {
        Some(name) => match attributes::check(particles, std::slice::from_ref(name))?[0] {
            a if a.width() == 3 => Some(a),
            _ => return Err(DensityError::InvalidParam { name: "noise rest attribute", value: name.clone(), why: "is not a vec3 attribute" }),
        },
        None => None,
    };
    let interpolated: Vec<&Attribute> = wanted.iter().copied().chain(rest).collect();
    let prep = prepare(particles, params)?;
    if prep.positions.is_empty() {
        return Err(DensityError::NoParticles);
    }
    let keep = Keep::new(&prep, params);
    let t1 = Instant::now();
    let pp = PointParams::new(&prep.grid, params);
    let mut bricks = passes(&prep, &pp, &keep)?;
    let t2 = Instant::now();
    let skipped = if interpolated.is_empty() { Vec::new() } else { attributes::interpolate(&prep, &interpolated, &mut bricks, |b, v, c| attribute_splat(&prep, &pp, b, v, c))? };
    let t3 = Instant::now();
    let widths: Vec<usize> = wanted.iter().map(|a| a.width()).collect();
    let mut out = finish(&prep, params, bricks, &widths);
    for (a, skipped) in out.attributes.iter_mut().zip(skipped) {
        a.skipped_nonfinite = skipped;
    }
    out.stats.timings = Timings { prepare: t1 - t0, estimate: t2 - t1, attributes: t3 - t2, finish: t3.elapsed() };
    Ok(out)
}

/// One brick's results after a backend's passes: world densities, and smoothing lengths
/// (index units) and used counts per voxel where an output asks for them, before noise and
/// thresholding.
pub(crate) struct BrickResult {
    pub origin: IVec3,
    pub rho: Box<[f32; BRICK_VOXELS]>,
    pub h: Option<Box<[f32; BRICK_VOXELS]>>,
    pub used: Option<Box<[u32; BRICK_VOXELS]>>,
    /// (points, sum, sum of squares) of the used counts over the voxels whose footprint holds
    /// at least one particle (the paper's Table 2 population).
    pub used_stats: (u64, f64, f64),
    pub max_rho: f32,
    /// The attribute pass's normalised values: one array per component of each requested
    /// attribute, in request order (empty without attributes).
    pub attributes: Vec<Box<[f32; BRICK_VOXELS]>>,
}

/// What the results keep of each brick's per-voxel sums. Most runs write the density alone,
/// and two more persistent arrays per brick cost more in fresh pages than the statistics
/// they feed, so those are reduced at once.
pub(crate) struct Keep {
    /// Per proposed brick (`Prepared::bricks` order): voxels whose footprint holds a particle.
    occupied: Vec<BrickMask>,
    h: bool,
    used: bool,
}

impl Keep {
    fn new(prep: &Prepared, params: &DensityParams) -> Keep {
        // The attribute pass reads each voxel's final length.
        let attribute_pass = !params.attributes.is_empty() || noise_rest_used(params);
        Keep { occupied: occupancy(prep), h: params.smoothing_length || attribute_pass, used: params.neighbour_count }
    }

    /// From a backend's raw sums for proposed brick `index`, `rho[v] = sum m * m4_shape(r /
    /// h[v])` (index units): applies the world normalisation 1 / (pi h^3). `None` for a brick
    /// with no density.
    pub(crate) fn brick(
        &self,
        index: usize,
        origin: IVec3,
        mut rho: Box<[f32; BRICK_VOXELS]>,
        h: Box<[f32; BRICK_VOXELS]>,
        used: Box<[u32; BRICK_VOXELS]>,
        pp: &PointParams,
    ) -> Option<BrickResult> {
        let mut max_rho = 0.0f32;
        for v in 0..BRICK_VOXELS {
            if rho[v] > 0.0 {
                rho[v] *= pp.world_norm(h[v]);
                max_rho = max_rho.max(rho[v]);
            }
        }
        if max_rho <= 0.0 {
            return None;
        }
        let occupied = &self.occupied[index];
        let mut used_stats = (0u64, 0.0f64, 0.0f64);
        for v in 0..BRICK_VOXELS {
            if occupied[v >> 6] & (1 << (v & 63)) != 0 {
                let u = used[v] as f64;
                used_stats = (used_stats.0 + 1, used_stats.1 + u, used_stats.2 + u * u);
            }
        }
        Some(BrickResult {
            origin,
            rho,
            h: self.h.then_some(h),
            used: self.used.then_some(used),
            used_stats,
            max_rho,
            attributes: Vec::new(),
        })
    }
}

/// A dense table over the grid's bricks (x fastest, then y, z) of each brick's index in
/// `Prepared::bricks` (u32::MAX where none was proposed), and the table entry of the brick
/// holding a voxel.
pub(crate) fn brick_slots(prep: &Prepared) -> (Vec<u32>, impl Fn(IVec3) -> usize) {
    let brick_dims = (prep.grid.dims + (BRICK_DIM - 1)) / BRICK_DIM;
    let brick_id = move |o: IVec3| setup::dense_index(o / BRICK_DIM, brick_dims);
    let mut slot = vec![u32::MAX; brick_dims.as_i64vec3().element_product() as usize];
    for (i, &origin) in prep.bricks.iter().enumerate() {
        slot[brick_id(origin)] = i as u32;
    }
    (slot, brick_id)
}

/// Per proposed brick, the voxels whose footprint holds a particle (its nearest grid point).
fn occupancy(prep: &Prepared) -> Vec<BrickMask> {
    let dims = prep.grid.dims;
    // Dense brick -> proposal table: one O(1) lookup per particle.
    let (slot, brick_id) = brick_slots(prep);
    // Sequential into the masks: a parallel pass through a 500k-entry list of marks cost more
    // than the marking itself.
    let mut occupied = vec![[0u64; 8]; prep.bricks.len()];
    for &p in &prep.positions {
        let nearest = setup::floor_i(p + 0.5);
        if !(nearest.cmpge(IVec3::ZERO).all() && nearest.cmplt(dims).all()) {
            continue;
        }
        let s = slot[brick_id(nearest - nearest % BRICK_DIM)];
        if s != u32::MAX {
            let v = brick_offset(nearest % BRICK_DIM);
            occupied[s as usize][v >> 6] |= 1 << (v & 63);
        }
    }
    occupied
}

/// Whether the density noise is evaluated at interpolated rest positions.
fn noise_rest_used(params: &DensityParams) -> bool {
    params.noise_rest.is_some() && params.noise.amplitude != 0.0
}

/// Noise, activity threshold, volumes and statistics from per-brick results (`widths`: the
/// components of each requested attribute; the noise's rest position follows them).
fn finish(prep: &Prepared, params: &DensityParams, mut bricks: Vec<BrickResult>, widths: &[usize]) -> DensityOutput {
    let grid = prep.grid;
    let noise = params.noise;
    if noise.amplitude != 0.0 {
        let fbm = noise::Fbm::new(noise.octaves, noise.seed);
        let rest = noise_rest_used(params).then(|| widths.iter().sum::<usize>());
        bricks.par_iter_mut().for_each(|b| {
            b.max_rho = 0.0;
            for (v, rho) in b.rho.iter_mut().enumerate() {
                if *rho > 0.0 {
                    let at = match rest {
                        Some(k) => DVec3::new(b.attributes[k][v] as f64, b.attributes[k + 1][v] as f64, b.attributes[k + 2][v] as f64),
                        None => grid.transform.to_world((b.origin + brick_local(v)).as_dvec3()),
                    };
                    *rho *= (1.0 + noise.amplitude * fbm.eval(at / noise.scale)).max(0.0);
                    b.max_rho = b.max_rho.max(*rho);
                }
            }
        });
    }

    let max_density = bricks.iter().map(|b| b.max_rho).fold(0.0f32, f32::max);
    let threshold = params.active_tolerance * max_density;
    let volume = |value: &(dyn Fn(&BrickResult, usize) -> f32 + Sync)| masked_volume(grid.transform, &bricks, threshold, value);
    let density = volume(&|b, v| b.rho[v]);
    let smoothing = params.smoothing_length.then(|| volume(&|b, v| (b.h.as_ref().expect("kept")[v] as f64 * grid.voxel_size) as f32));
    let counts = params.neighbour_count.then(|| volume(&|b, v| b.used.as_ref().expect("kept")[v] as f32));
    // Attribute grids: their components' arrays follow one another in each brick.
    let mut first = 0;
    let attributes: Vec<AttributeOutput> = params
        .attributes
        .iter()
        .zip(widths)
        .map(|(name, &width)| {
            let at = first;
            first += width;
            let volume = if width == 3 {
                AttributeVolume::Vec3(masked_volume(grid.transform, &bricks, threshold, &|b, v| {
                    Vec3::new(b.attributes[at][v], b.attributes[at + 1][v], b.attributes[at + 2][v])
                }))
            } else {
                AttributeVolume::Float(volume(&|b, v| b.attributes[at][v]))
            };
            AttributeOutput { name: name.clone(), volume, skipped_nonfinite: 0 }
        })
        .collect();

    // (points, sum, sum of squares) of the particles used at occupied voxels; active mass.
    let (used_n, used_sum, used_sq, grid_mass) = bricks
        .par_iter()
        .map(|b| {
            let mut acc = (b.used_stats.0, b.used_stats.1, b.used_stats.2, 0.0f64);
            for v in 0..BRICK_VOXELS {
                if b.rho[v] > threshold {
                    acc.3 += b.rho[v] as f64;
                }
            }
            acc
        })
        .reduce(|| (0, 0.0, 0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2, a.3 + b.3));
    let mean = if used_n > 0 { used_sum / used_n as f64 } else { 0.0 };
    let var = if used_n > 0 { (used_sq / used_n as f64 - mean * mean).max(0.0) } else { 0.0 };
    let stats = DensityStats {
        particles: prep.positions.len() as u64,
        skipped_nonfinite: prep.skipped_nonfinite,
        outside: prep.outside,
        cells: (prep.cells.start.len() - 1) as u64,
        bricks_proposed: prep.bricks.len() as u64,
        bricks_active: density.brick_count() as u64,
        active_voxels: density.active_voxel_count(),
        used_mean: mean,
        used_std: var.sqrt(),
        used_points: used_n,
        max_density,
        grid_mass: grid_mass * grid.transform.voxel_volume(),
        timings: Timings::default(),
    };
    DensityOutput { density, smoothing_length: smoothing, neighbour_count: counts, attributes, grid, stats }
}

/// A brick's active voxels: density above the threshold.
fn active_mask(b: &BrickResult, threshold: f32) -> BrickMask {
    let mut mask: BrickMask = [0; 8];
    for v in 0..BRICK_VOXELS {
        mask[v >> 6] |= ((b.rho[v] > threshold) as u64) << (v & 63);
    }
    mask
}

/// A volume over the bricks' active voxels (density above `threshold`) with `value` there:
/// the density grid and every grid beside it share these masks.
fn masked_volume<T: Voxel>(transform: Transform, bricks: &[BrickResult], threshold: f32, value: &(dyn Fn(&BrickResult, usize) -> T + Sync)) -> Volume<T> {
    // Bricks come out in proposal order, sorted by (z, y, x): found again by binary search.
    let origins: Vec<IVec3> = bricks.iter().map(|b| b.origin).collect();
    let find = |o: IVec3| &bricks[origins.binary_search_by_key(&(o.z, o.y, o.x), |b| (b.z, b.y, b.x)).unwrap()];
    Volume::from_brick_fn(transform, T::default(), &origins, |origin, values| {
        let b = find(origin);
        let mask = active_mask(b, threshold);
        for (v, out) in values.iter_mut().enumerate() {
            *out = if mask[v >> 6] & (1 << (v & 63)) != 0 { value(b, v) } else { T::default() };
        }
        mask
    })
}

/// World position of voxel `ijk` of `grid` (convenience for tests and tools).
pub fn voxel_world(grid: &Grid, ijk: IVec3) -> DVec3 {
    grid.transform.to_world(ijk.as_dvec3())
}
