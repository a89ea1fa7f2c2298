//! The CPU backend: pixels in parallel with rayon; [`march_ray`] is the estimator in its
//! plainest form (f64, the sparse volumes' own lookups), [`render_cpu`] the same over the
//! march's layout of the volume (`layout.rs`).

use glam::{DVec3, Vec3, Vec4};
use nimbus_cache::IlluminationCache;
use nimbus_optics::noise::fbm3_vec;
use nimbus_optics::Rng;
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use crate::layout::{DensityPoint, Lattice, Layer, MarchVolume, BRICK_VALUES, CELL_OF_POINT};
use crate::offsets::Offsets;
#[cfg(target_arch = "x86_64")]
use crate::simd::Fused;
use crate::simd::{Arith, Unfused, LANES, OUTSIDE};
use crate::{assemble, DirectSingle, Groups, Image, MarchError, MarchParams, MediumFields, NoiseEval, GROUP_DOMAIN};
use nimbus_tracking::{EmissionField, Motion, MotionBlur};

/// Random-number domain of camera samples.
pub(crate) const MARCH_DOMAIN: u32 = 0x4d41_5243; // "MARC"
/// The stream of each pixel's (or reference sample's) time in the shutter.
pub const MOTION_DOMAIN: u32 = 0x4d4f_5445; // "MOTE"

/// What one camera ray gathered.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayResult {
    pub single: Vec3,
    pub multiple: Vec3,
    pub transmittance: f32,
    /// Distance to the first sample where opacity passed 1%, or infinity.
    pub depth: f32,
    /// The medium's own emission, attenuated (issue #19).
    pub emission: Vec3,
    /// The environment map seen through the volume, `T L_env(dir)` (a uniform background
    /// is added from `transmittance` when the image is assembled).
    pub behind: Vec3,
}

/// Marches one camera ray. `xi` in [0,1) places the step lattice, `u` in [0,1) the sample
/// in each group of lattice steps (see the crate doc); offset noise, if any, is evaluated
/// exactly at each sample (the renders bake it).
#[allow(clippy::too_many_arguments)]
pub fn march_ray(
    density: &Volume<f32>,
    majorant: &MajorantGrid,
    cache: &IlluminationCache,
    params: &MarchParams,
    origin: DVec3,
    dir: DVec3,
    xi: f64,
    u: f64,
) -> RayResult {
    march_ray_with(density, majorant, cache, params, origin, dir, xi, u, None, None, None, None)
}

/// [`march_ray`] with what the medium holds beyond its density. `emission`: each sample
/// adds `T e(x) (1 - exp(-sigma_t dt)) / sigma_t`, the exact integral of `T(t) e` over its
/// step for e and sigma_t constant over it (`T e dt` where sigma_t is 0 would be the limit,
/// but nothing emits there: the medium carries the emission, [`EmissionField`]); emitted
/// radiance is per unit length: no albedo, no sigma_s. `motion`: a time in the shutter
/// (Eulerian motion blur): every lookup, the density, the cache's Li and the emission, at the
/// sample's position moved back along the velocity ([`Motion::back`]); `majorant` must bound
/// the moved density ([`MotionBlur::majorant_radius`]).
/// `offsets`: the baked offset noise where given, else the noise (if any) is evaluated
/// exactly at each sample ([`offset`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn march_ray_with(
    density: &Volume<f32>,
    majorant: &MajorantGrid,
    cache: &IlluminationCache,
    params: &MarchParams,
    origin: DVec3,
    dir: DVec3,
    xi: f64,
    u: f64,
    emission: Option<&EmissionField>,
    motion: Option<Motion>,
    offsets: Option<&Offsets>,
    direct: Option<&DirectSingle>,
) -> RayResult {
    let transform = density.transform();
    let (o, d) = (transform.to_index(origin), transform.dir_to_index(dir));
    let extinction = params.medium.extinction;
    let albedo = params.medium.albedo;
    let jitter = params.offset_noise > 0.0;
    let mut r = RayResult { transmittance: 1.0, depth: f32::INFINITY, ..RayResult::default() };
    let mut tr = 1.0f64;
    for (t, step) in lattice_samples(majorant, params, o, d, xi, u) {
        let mut x = origin + dir * t;
        if jitter {
            x += displacement(params, offsets, Unfused, x);
        }
        if let Some(m) = motion {
            x = m.back(x);
        }
        let sigma_t = extinction as f64 * density.sample_world(x).max(0.0) as f64;
        if sigma_t <= 0.0 {
            continue;
        }
        let step_transmittance = (-sigma_t * step).exp();
        // 1 - exp(-tau) without cancellation in thin media.
        let absorbed = -(-sigma_t * step).exp_m1();
        let weight = (tr * absorbed) as f32;
        if let Some(e) = emission {
            r.emission += e.at(x) * (tr * absorbed / sigma_t) as f32;
        }
        if let Some(direct) = direct {
            r.single += weight * albedo * direct.li(density, &params.medium, x, -dir.as_vec3(), params.min_transmittance);
        } else if let Some(li) = &cache.li_single {
            r.single += weight * albedo * li.sample_world(x);
        }
        if let Some(li) = &cache.li_multiple {
            r.multiple += weight * albedo * li.sample_world(x);
        }
        tr *= step_transmittance;
        if r.depth.is_infinite() && tr < 0.99 {
            r.depth = t as f32;
        }
        if tr < params.min_transmittance {
            r.transmittance = 0.0;
            return r;
        }
    }
    r.transmittance = tr as f32;
    r
}

/// The samples of the ray `o + t d` (index space) over the non-empty cells of `majorant`,
/// as `(t, the ray length each stands for)`, grouped by step factor ([`Groups`]).
fn lattice_samples<'a>(majorant: &'a MajorantGrid, params: &'a MarchParams, o: DVec3, d: DVec3, xi: f64, u: f64) -> impl Iterator<Item = (f64, f64)> + 'a {
    let dt = params.step;
    let mut groups = Groups::new();
    majorant
        .walk(o, d, 0.0, f64::INFINITY)
        .filter(|seg| seg.majorant > 0.0 && seg.t_end.is_finite())
        .flat_map(move |seg| {
            let cell = groups.cell(seg.t_start, seg.t_end, dt, xi, u, params.step_factor(seg.majorant));
            (0..cell.count as u32).map(move |j| ((cell.first + (j * cell.size) as f64 + xi) * dt, cell.size as f64 * dt))
        })
}

/// The offset noise's displacement of a sample at world position `x`, exactly: the fBm
/// the baked field ([`Offsets`]) holds at its nodes.
pub(crate) fn offset(params: &MarchParams, x: DVec3) -> DVec3 {
    fbm3_vec(x / params.noise_scale, params.noise_octaves, params.seed as u32).as_dvec3() * params.offset_noise
}

/// The displacement at `x`: interpolated from `offsets` where baked, else exact.
#[inline(always)]
fn displacement<A: Arith>(params: &MarchParams, offsets: Option<&Offsets>, arith: A, x: DVec3) -> DVec3 {
    match offsets {
        Some(o) => o.at(arith, x),
        None => offset(params, x),
    }
}

/// The majorant grid both backends march. Offset noise samples the density up to its
/// displacement away from the ray being walked, so each cell must also bound the cells within
/// that distance (index space, per axis) or the march would skip segments whose displaced
/// samples see density: the grid is dilated by it. The fBm's components stay within about
/// [-1, 1]; twice the amplitude is a generous bound ([`NOISE_REACH`]). Motion blur moves the
/// medium too, by up to [`MotionBlur::majorant_radius`] within the shutter.
///
/// With offset noise the cells are two voxels rather than a brick ([`NOISE_CELL_LOG2`]): a
/// ray then walks empty space within about the noise's reach of the medium, not within a
/// brick of it.
pub(crate) fn march_majorant(density: &Volume<f32>, params: &MarchParams, motion: Option<&MotionBlur>) -> MajorantGrid {
    noise_dilated(density, moved_majorant(density, params, motion), params)
}

/// [`march_majorant`] and the baked offset noise the march reads over it (none without
/// offset noise or where it is evaluated exactly, [`NoiseEval`]). A lattice finer than
/// [`FINEST_OFFSET_NODES`] of a voxel would hold more nodes than the march takes samples
/// (at the default step, about two a voxel along a ray) and grow with the cube of the
/// noise's frequency: there the fBm is evaluated at each sample instead.
pub(crate) fn march_grids(density: &Volume<f32>, params: &MarchParams, motion: Option<&MotionBlur>) -> (MajorantGrid, Option<Offsets>) {
    let moved = moved_majorant(density, params, motion);
    let offsets = baked_offsets(density, &moved, params);
    (noise_dilated(density, moved, params), offsets)
}

/// The baked offset noise over `moved` (the medium's majorant grid, not dilated for the
/// noise), where [`march_grids`] bakes it.
fn baked_offsets(density: &Volume<f32>, moved: &MajorantGrid, params: &MarchParams) -> Option<Offsets> {
    let voxel = density.transform().voxel_size().min_element();
    match params.noise_eval.nodes() {
        Some(nodes) if params.offset_noise > 0.0 && params.noise_scale / nodes as f64 >= FINEST_OFFSET_NODES * voxel => Some(Offsets::bake(density, moved, params, nodes)),
        _ => None,
    }
}

/// The finest spacing of the baked offset noise's nodes, in voxels ([`march_grids`]).
pub(crate) const FINEST_OFFSET_NODES: f64 = 0.5;

/// A bound on the offset noise's displacement per world axis, in amplitudes.
pub(crate) const NOISE_REACH: f64 = 2.0;

/// log2 of the majorant grid's cell edge in voxels with offset noise ([`march_majorant`]).
pub(crate) const NOISE_CELL_LOG2: u32 = 1;

/// The density's majorant grid (two-voxel cells with offset noise, else brick cells),
/// dilated by how far motion blur moves the medium.
fn moved_majorant(density: &Volume<f32>, params: &MarchParams, motion: Option<&MotionBlur>) -> MajorantGrid {
    let grid = match params.offset_noise > 0.0 {
        true => MajorantGrid::with_cell_log2(density, NOISE_CELL_LOG2),
        false => MajorantGrid::build(density),
    };
    match motion {
        Some(m) => grid.dilated(m.majorant_radius(density)),
        None => grid,
    }
}

/// `grid` dilated by the offset noise's reach, where there is noise.
fn noise_dilated(density: &Volume<f32>, grid: MajorantGrid, params: &MarchParams) -> MajorantGrid {
    if !(params.offset_noise > 0.0) {
        return grid;
    }
    grid.dilated(index_reach(&density.transform().world_to_index(), NOISE_REACH * params.offset_noise))
}

/// How far, per index axis of `world_to_index`, a world displacement whose components stay
/// within `reach` can move a point.
pub(crate) fn index_reach(world_to_index: &glam::DAffine3, reach: f64) -> DVec3 {
    let m = world_to_index.matrix3;
    // Index axis j moves by at most sum_i |m[i][j]| times a world displacement's largest component.
    let rows = DVec3::new(m.row(0).abs().element_sum(), m.row(1).abs().element_sum(), m.row(2).abs().element_sum());
    rows * reach
}

/// Where in the pixel sample `s` of `spp` looks, from two uniform numbers: jittered within
/// its cell of an n x n grid over the pixel (n = floor(sqrt(spp))), anywhere for the samples
/// past n^2. A pixel's sub-pixel detail (the plume's wisps at 128x72) then averages out as
/// about spp^-0.75 rather than spp^-0.5: with 4 purely random samples the bench's plume came
/// out worse than with the one centre sample. `shaders/march.wgsl` mirrors it.
pub(crate) fn pixel_jitter(s: u32, spp: u32, u: f64, v: f64) -> (f64, f64) {
    let n = spp.isqrt();
    if s < n * n {
        (((s % n) as f64 + u) / n as f64, ((s / n) as f64 + v) / n as f64)
    } else {
        (u, v)
    }
}

/// Renders the image on the CPU: [`march_ray`]'s estimator over the march's own layout
/// of the volume (`layout.rs`, built once), in f32 where f64 buys nothing (positions
/// and the step lattice stay f64), pixels in 8 x 8 tiles so that neighbouring rays, which
/// read the same bricks, run back to back on one core.
pub fn render_cpu(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams) -> Result<Image, MarchError> {
    params.validate()?;
    let voxel = density.transform().voxel_size().max_element();
    let noise = if !(params.offset_noise > 0.0) {
        Noise::None
    } else if params.noise_eval == NoiseEval::Displaced && params.noise_scale >= NoiseEval::DISPLACED_POINTS_PER_SCALE * voxel {
        Noise::Displaced
    } else {
        Noise::PerSample(march_grids(density, params, None))
    };
    let pixels = match params.aovs {
        true => render_layout::<[Vec4; 2]>(density, cache, params, noise),
        false => render_layout::<Vec4>(density, cache, params, noise),
    };
    Ok(assemble(params, &pixels))
}

/// What [`render_cpu`] does about the offset noise.
enum Noise {
    None,
    /// The displaced medium baked ([`NoiseEval::Displaced`]).
    Displaced,
    /// The offsets read at each sample, over the dilated majorant grid ([`march_grids`]).
    PerSample((MajorantGrid, Option<Offsets>)),
}

/// [`render_cpu`] over the layout with density points `T` or, where the layout does not
/// apply, [`march_ray`] itself (with the offsets read at each sample).
fn render_layout<T: DensityPoint>(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams, noise: Noise) -> Vec<RayResult> {
    let Some(volume) = MarchVolume::<T>::new(density, cache, params.medium.albedo) else {
        let (majorant, offsets) = match noise {
            Noise::None => (None, None),
            Noise::Displaced => {
                let (majorant, offsets) = march_grids(density, params, None);
                (Some(majorant), offsets)
            }
            Noise::PerSample((majorant, offsets)) => (Some(majorant), offsets),
        };
        return render_plain(density, cache, params, majorant, offsets.as_ref());
    };
    match noise {
        Noise::None => render_tiles(params, &Fast { volume: &volume, majorant: None, offsets: None, params }),
        Noise::Displaced => render_tiles(params, &Fast { volume: &volume.displaced(params), majorant: None, offsets: None, params }),
        Noise::PerSample((majorant, offsets)) => render_tiles(params, &Fast { volume: &volume, majorant: Some(&majorant), offsets: offsets.as_ref(), params }),
    }
}

/// [`render_cpu`] with what the medium holds beyond its density ([`MediumFields`]): with
/// emission, [`march_ray_with`] per sample over the sparse volumes (the plain march; the
/// layout's fused march does not carry emission yet); with motion blur each camera sample
/// takes a time in the shutter (uniform, from its own stream, [`MOTION_DOMAIN`]) and marches
/// the medium as it is then, over the majorant dilated by how far it moves. With neither it
/// is [`render_cpu`].
pub fn render_cpu_with(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams, fields: MediumFields) -> Result<Image, MarchError> {
    let MediumFields { emission, motion, direct_single } = fields;
    let emission = emission.filter(|e| e.params.is_active());
    if emission.is_none() && motion.is_none() && direct_single.is_none() {
        return render_cpu(density, cache, params);
    }
    params.validate()?;
    let (majorant, offsets) = march_grids(density, params, motion);
    let pixels = render_tiles(params, &Extras { density, majorant: &majorant, cache, params, emission, motion: motion.copied(), offsets: offsets.as_ref(), direct_single });
    Ok(assemble(params, &pixels))
}

/// [`march_ray_with`] per sample: emission and/or motion blur.
struct Extras<'a> {
    density: &'a Volume<f32>,
    majorant: &'a MajorantGrid,
    cache: &'a IlluminationCache,
    params: &'a MarchParams,
    emission: Option<&'a EmissionField<'a>>,
    motion: Option<MotionBlur<'a>>,
    offsets: Option<&'a Offsets>,
    direct_single: Option<&'a DirectSingle<'a>>,
}

impl Marcher for Extras<'_> {
    fn march<A: Arith>(&self, _: A, origin: DVec3, dir: DVec3, xi: f64, u: f64, shutter: f64) -> RayResult {
        let motion = self.motion.map(|m| m.at(shutter));
        march_ray_with(self.density, self.majorant, self.cache, self.params, origin, dir, xi, u, self.emission, motion, self.offsets, self.direct_single)
    }
}

/// [`march_ray`] itself over the image, where the layout does not apply.
fn render_plain(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams, majorant: Option<MajorantGrid>, offsets: Option<&Offsets>) -> Vec<RayResult> {
    let majorant = majorant.unwrap_or_else(|| march_majorant(density, params, None));
    render_tiles(params, &Plain { density, majorant: &majorant, cache, params, offsets })
}

/// Pixel edge of the square tiles the CPU marches one after another.
const TILE: usize = 8;

/// One camera ray's march from `origin` along `dir` with lattice offset `xi`: what
/// [`render_tiles`] runs per sample (a trait rather than a closure so that the march is
/// inlined into the FMA copy of the tile loop, and compiled for it).
trait Marcher: Sync {
    /// `shutter`: the sample's time as a fraction of the shutter (read with motion blur only).
    fn march<A: Arith>(&self, arith: A, origin: DVec3, dir: DVec3, xi: f64, u: f64, shutter: f64) -> RayResult;
}

/// [`march_ray`] itself, where the layout does not apply.
struct Plain<'a> {
    density: &'a Volume<f32>,
    majorant: &'a MajorantGrid,
    cache: &'a IlluminationCache,
    params: &'a MarchParams,
    /// The baked offset noise, if any (else exact, where there is noise).
    offsets: Option<&'a Offsets>,
}

impl Marcher for Plain<'_> {
    fn march<A: Arith>(&self, _: A, origin: DVec3, dir: DVec3, xi: f64, u: f64, _: f64) -> RayResult {
        march_ray_with(self.density, self.majorant, self.cache, self.params, origin, dir, xi, u, None, None, self.offsets, None)
    }
}

struct Fast<'a, T: DensityPoint> {
    volume: &'a MarchVolume<T>,
    /// The dilated majorant grid, with offset noise.
    majorant: Option<&'a MajorantGrid>,
    /// The baked offset noise, if any (else exact, where there is noise).
    offsets: Option<&'a Offsets>,
    params: &'a MarchParams,
}

impl<T: DensityPoint> Marcher for Fast<'_, T> {
    #[inline(always)]
    fn march<A: Arith>(&self, arith: A, origin: DVec3, dir: DVec3, xi: f64, u: f64, _: f64) -> RayResult {
        match self.majorant {
            Some(majorant) => self.volume.march_displaced(arith, majorant, self.offsets, self.params, origin, dir, xi, u),
            None => self.volume.march(arith, self.params, origin, dir, xi, u),
        }
    }
}

/// Every pixel's average over its `spp` samples of `march`, in bands of [`TILE`] rows in
/// parallel, each band tile by tile.
fn render_tiles<M: Marcher>(params: &MarchParams, march: &M) -> Vec<RayResult> {
    let camera = &params.camera;
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let mut pixels = vec![RayResult::default(); w * h];
    #[cfg(target_arch = "x86_64")]
    let fused = Fused::detect();
    let task = nimbus_progress::task("march", h as u64);
    pixels.par_chunks_mut(w * TILE).enumerate().inspect(|(_, rows)| task.advance((rows.len() / w.max(1)) as u64)).for_each(|(band, rows)| {
        #[cfg(target_arch = "x86_64")]
        if let Some(fused) = fused {
            // SAFETY: `Fused` exists only where the CPU has AVX2 and FMA.
            return unsafe { band_fma(fused, params, march, band * TILE, rows) };
        }
        render_band(Unfused, params, march, band * TILE, rows)
    });
    pixels
}

/// [`render_band`] compiled for AVX2 and FMA: floor is an instruction, and the lerps and
/// the exponential's polynomial are chains of fused multiply-adds.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn band_fma<M: Marcher>(fused: Fused, params: &MarchParams, march: &M, y0: usize, rows: &mut [RayResult]) {
    render_band(fused, params, march, y0, rows)
}

/// The rows from `y0` that `rows` holds, tile by tile.
#[inline(always)]
fn render_band<A: Arith, M: Marcher>(arith: A, params: &MarchParams, march: &M, y0: usize, rows: &mut [RayResult]) {
    let camera = &params.camera;
    let w = camera.width() as usize;
    let spp = params.spp;
    let map = crate::visible_map(params.visible_environment());
    for x0 in (0..w).step_by(TILE) {
        for y in 0..rows.len() / w {
            for x in x0..(x0 + TILE).min(w) {
                let index = (y0 + y) * w + x;
                let (px, py) = (x as f64, (y0 + y) as f64);
                let mut rng = Rng::with_domain(params.seed, index as u64, MARCH_DOMAIN);
                let mut members = Rng::with_domain(params.seed, index as u64, GROUP_DOMAIN);
                // The samples' times in the shutter: a stream of their own, so the other draws
                // stay what they are without motion blur.
                let mut times = Rng::with_domain(params.seed, index as u64, MOTION_DOMAIN);
                let mut sum = RayResult::default();
                let mut depth = f32::INFINITY;
                for s in 0..spp {
                    // One sample at the pixel centre when spp = 1, so a 1-spp image is not noisy
                    // in its edges; stratified over the pixel otherwise.
                    let (jx, jy) = if spp == 1 { (0.5, 0.5) } else { pixel_jitter(s, spp, rng.next_f64(), rng.next_f64()) };
                    let (xi, u) = (rng.next_f64(), members.next_f64());
                    let (origin, dir) = camera.ray(px + jx, py + jy);
                    let r = march.march(arith, origin, dir, xi, u, times.next_f64());
                    sum.single += r.single;
                    sum.multiple += r.multiple;
                    sum.emission += r.emission;
                    sum.transmittance += r.transmittance;
                    if let Some(env) = map {
                        sum.behind += env.radiance(dir.as_vec3()) * r.transmittance;
                    }
                    depth = depth.min(r.depth);
                }
                let inv = 1.0 / spp as f32;
                rows[y * w + x] = RayResult {
                    single: sum.single * inv,
                    multiple: sum.multiple * inv,
                    transmittance: sum.transmittance * inv,
                    depth,
                    emission: sum.emission * inv,
                    behind: sum.behind * inv,
                };
            }
        }
    }
}

/// Up to [`LANES`] samples looked up, not yet composited: their exponentials are computed
/// together (vectorised), then the serial part, transmittance and sums, runs.
struct Batch {
    /// Each sample's distance along the ray.
    t: [f64; LANES],
    /// Optical depth over the sample's step.
    tau: [f32; LANES],
    /// albedo * Li (xyz) per sample, single (or the sum) and multiple.
    single: [Vec4; LANES],
    multiple: [Vec4; LANES],
}

impl Batch {
    fn new() -> Self {
        Batch { t: [0.0; LANES], tau: [0.0; LANES], single: [Vec4::ZERO; LANES], multiple: [Vec4::ZERO; LANES] }
    }
}

/// A ray's sums so far.
struct Composite<T> {
    r: RayResult,
    single: Vec4,
    multiple: Vec4,
    tr: f32,
    min_transmittance: f32,
    /// The layout, whose [`DensityPoint::SPLIT`] says whether multiple is kept apart.
    layout: std::marker::PhantomData<T>,
}

impl<T: DensityPoint> Composite<T> {
    fn new(min_transmittance: f32) -> Self {
        Composite {
            r: RayResult { depth: f32::INFINITY, ..RayResult::default() },
            single: Vec4::ZERO,
            multiple: Vec4::ZERO,
            tr: 1.0,
            min_transmittance,
            layout: std::marker::PhantomData,
        }
    }

    /// Composites the first `n` samples of `b` in order; false once the transmittance fell
    /// below the threshold (the samples after the one that took it there add nothing).
    #[inline(always)]
    fn add<A: Arith>(&mut self, arith: A, b: &Batch, n: usize) -> bool {
        let c = arith.composite(self.tr, &b.tau, n, self.min_transmittance);
        let end = if c.below != 0 { c.below.trailing_zeros() as usize + 1 } else { n };
        let deep = c.deep & ((1 << end) - 1);
        if self.r.depth.is_infinite() && deep != 0 {
            self.r.depth = b.t[deep.trailing_zeros() as usize % LANES] as f32;
        }
        for i in 0..end.min(LANES) {
            let w = Vec4::splat(c.weight[i]);
            self.single = arith.fma4(w, b.single[i], self.single);
            if T::SPLIT {
                self.multiple = arith.fma4(w, b.multiple[i], self.multiple);
            }
        }
        self.tr = c.tr;
        c.below == 0
    }

    /// The result, `done` when the ray stopped early (its transmittance is then 0).
    #[inline(always)]
    fn finish(mut self, done: bool) -> RayResult {
        self.r.single = self.single.truncate();
        self.r.multiple = self.multiple.truncate();
        self.r.transmittance = if done { 0.0 } else { self.tr };
        self.r
    }
}

impl<T: DensityPoint> MarchVolume<T> {
    /// Each other lattice's ray, in its own index space.
    #[inline(always)]
    fn other_rays(&self, origin: DVec3, dir: DVec3) -> [(DVec3, DVec3); 2] {
        let mut rays = [(DVec3::ZERO, DVec3::ZERO); 2];
        for (ray, (lattice, _)) in rays.iter_mut().zip(&self.others) {
            let m = lattice.world_to_index();
            *ray = (m.transform_point3(origin), m.transform_vector3(dir));
        }
        rays
    }

    /// Lane `j` of `b`: the sample at `t` over a step of optical depth `dtau` per unit of
    /// density, whose density-lattice point is `v`, reading the
    /// other lattices along their rays, displaced by `shift` (world), where it has
    /// extinction. A sample without adds nothing and leaves T as it is (its cache values,
    /// never read by [`march_ray`], are not read here either).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn take<A: Arith>(&self, arith: A, b: &mut Batch, j: usize, dtau: f32, t: f64, v: T, rays: &[(DVec3, DVec3); 2], shift: Option<DVec3>) {
        let tau = dtau * v.density().max(0.0);
        let lit = tau > 0.0;
        let (mut single, mut multiple) = if lit { (v.single(), v.multiple()) } else { (Vec4::ZERO, Vec4::ZERO) };
        if lit && !self.others.is_empty() {
            for ((lattice, layer), &(o, d)) in self.others.iter().zip(rays) {
                let m = lattice.world_to_index();
                let li = lattice.sample(arith, o + d * t + shift.map_or(DVec3::ZERO, |s| m.transform_vector3(s)));
                match layer {
                    Layer::Multiple if T::SPLIT => multiple += li,
                    _ => single += li,
                }
            }
        }
        // j < LANES (callers fill at most a batch); the mask spares the bounds checks.
        let j = j % LANES;
        (b.t[j], b.tau[j], b.single[j]) = (t, tau, single);
        if T::SPLIT {
            b.multiple[j] = multiple;
        }
    }

    /// [`march_ray`] over this layout without offset noise: the same samples, in f32 from
    /// each sample's lattice lookup on, bricks found by the layout's own DDA, once per
    /// brick rather than once per sample, and a brick's samples [`LANES`] at a time. Within
    /// a brick the position is f32 relative to the brick's first sample (the offset from
    /// it at most a brick's diagonal, so within about 1e-6 voxels), and the lattice index k
    /// carries over between adjacent bricks (as on the GPU), so a sample on a boundary
    /// within rounding is taken exactly once.
    #[inline(always)]
    fn march<A: Arith>(&self, arith: A, params: &MarchParams, origin: DVec3, dir: DVec3, xi: f64, u: f64) -> RayResult {
        let to_index = self.density.world_to_index();
        let (o, d) = (to_index.transform_point3(origin), to_index.transform_vector3(dir));
        let rays = self.other_rays(origin, dir);
        let mut c = Composite::<T>::new(params.min_transmittance as f32);
        let mut b = Batch::new();
        let dt = params.step;
        let mut groups = Groups::new();
        for span in self.density.bricks_along(o, d, 0.0) {
            // Groups over the whole brick, as every march takes them; only the samples in the
            // box of cells to visit, and the last group's when it reaches past the brick,
            // can read density.
            let cell = groups.cell(span.start, span.end, dt, xi, u, params.step_factor(span.majorant));
            let step = cell.size as f64 * dt;
            let dtau = step as f32 * params.medium.extinction;
            let t0 = (cell.first + xi) * dt;
            // (u32 converts to f64 in one instruction, usize does not.)
            let at = |j: usize| t0 + (j as u32) as f64 * step;
            let (count, per_step) = ((cell.count as u32) as f64, 1.0 / step);
            let within = |t: f64| ((t - t0) * per_step).ceil().clamp(0.0, count) as usize;
            // The last group's sample may lie past the brick: in the next brick, or empty space.
            let past = cell.count > 0 && at(cell.count - 1) >= span.end;
            let (lo, hi) = if (span.visit_start, span.visit_end) == (span.start, span.end) {
                (0, cell.count - past as usize)
            } else {
                (within(span.visit_start), within(span.visit_end).max(within(span.visit_start)))
            };
            // Samples `step` apart from the first, relative to the brick.
            let (first, advance) = ((o - span.origin + d * t0).as_vec3a(), (d * step).as_vec3a());
            let mut t = at(lo);
            for from in (lo..hi).step_by(LANES) {
                let cells = arith.cells(first, advance, (from as u32) as f32);
                let m = LANES.min(hi - from);
                // Samples in cells with no corner of positive density are left out: they
                // would add no optical depth and no light.
                let mut n = 0;
                for j in 0..m {
                    let v = match cells.index[j] {
                        OUTSIDE => self.density.sample(arith, o + d * t),
                        i if {
                            let cell = CELL_OF_POINT[i as usize % BRICK_VALUES];
                            span.occupied[(cell >> 6) as usize % 8] >> (cell & 63) & 1 == 0
                        } =>
                        {
                            t += step;
                            continue;
                        }
                        i => Lattice::interpolate_at(arith, span.points, i as usize, cells.w[0][j], cells.w[1][j], cells.w[2][j]),
                    };
                    self.take(arith, &mut b, n, dtau, t, v, &rays, None);
                    n += 1;
                    t += step;
                }
                if n > 0 && !c.add(arith, &b, n) {
                    return c.finish(true);
                }
            }
            if past {
                let t = at(cell.count - 1);
                let v = self.density.sample(arith, o + d * t);
                self.take(arith, &mut b, 0, dtau, t, v, &rays, None);
                if !c.add(arith, &b, 1) {
                    return c.finish(true);
                }
            }
        }
        c.finish(false)
    }

    /// [`march_ray`] over this layout with offset noise, over the dilated majorant grid.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn march_displaced<A: Arith>(&self, arith: A, majorant: &MajorantGrid, offsets: Option<&Offsets>, params: &MarchParams, origin: DVec3, dir: DVec3, xi: f64, u: f64) -> RayResult {
        let to_index = self.density.world_to_index();
        let (o, d) = (to_index.transform_point3(origin), to_index.transform_vector3(dir));
        let rays = self.other_rays(origin, dir);
        let mut c = Composite::<T>::new(params.min_transmittance as f32);
        let (mut b, mut n) = (Batch::new(), 0);
        // The ray in the baked field's lattice.
        let along = offsets.map(|f| (f, f.to_lattice(origin), dir * f.per_world));
        for (t, step) in lattice_samples(majorant, params, o, d, xi, u) {
            let shift = match along {
                Some((f, q, dq)) => f.at_lattice(arith, q + dq * t),
                None => offset(params, origin + dir * t),
            };
            let v = self.density.sample(arith, o + d * t + to_index.transform_vector3(shift));
            self.take(arith, &mut b, n, step as f32 * params.medium.extinction, t, v, &rays, Some(shift));
            n += 1;
            if n == LANES {
                if !c.add(arith, &b, n) {
                    return c.finish(true);
                }
                n = 0;
            }
        }
        let done = !c.add(arith, &b, n);
        c.finish(done)
    }
}

/// The test scenes of `tests/` (clouds, caches, cameras).
#[cfg(test)]
#[path = "../tests/common/mod.rs"]
pub(crate) mod scenes;

#[cfg(test)]
pub(crate) mod tests {
    use super::scenes::{cache_for, cache_on_density_lattice, camera, cloud, params};
    use super::*;
    use nimbus_optics::{Emission, Medium};

    /// The march over the layout against `march_ray` on the same rays and lattices: the
    /// worst relative difference of the colour, single and multiple over lit pixels (as
    /// the GPU agreement tests measure it) and of alpha.
    fn layout_against_plain(density: &Volume<f32>, cache: &IlluminationCache, params: &MarchParams) -> (f32, f32) {
        let fast = render_cpu(density, cache, params).unwrap();
        if params.min_transmittance > 0.0 {
            let stopped = fast.rgba.iter().filter(|p| p.w == 1.0).count();
            assert!(stopped > 10, "rays stop early: {stopped}");
        }
        let (majorant, offsets) = march_grids(density, params, None);
        let plain = assemble(params, &render_tiles(params, &Plain { density, majorant: &majorant, cache, params, offsets: offsets.as_ref() }));
        let lum = |p: Vec3| p.element_sum();
        let max = plain.rgba.iter().map(|p| lum(p.truncate())).fold(0.0, f32::max);
        assert!(max > 0.0, "the scene is lit");
        let floor = Vec3::splat(1e-3 * max / 3.0);
        let rel = |a: Vec3, b: Vec3| ((a - b).abs() / b.abs().max(floor)).max_element();
        let (mut worst, mut alpha, mut lit) = (0.0f32, 0.0f32, 0);
        for (i, (f, p)) in fast.rgba.iter().zip(&plain.rgba).enumerate() {
            alpha = alpha.max((f.w - p.w).abs());
            if lum(p.truncate()) > 1e-3 * max {
                lit += 1;
                worst = worst.max(rel(f.truncate(), p.truncate()));
                if let (Some(fa), Some(pa)) = (&fast.aovs, &plain.aovs) {
                    worst = worst.max(rel(fa.single[i], pa.single[i])).max(rel(fa.multiple[i], pa.multiple[i]));
                }
            }
        }
        assert!(lit > fast.rgba.len() / 4, "{lit} lit pixels");
        (worst, alpha)
    }

    #[test]
    fn the_layout_marches_as_march_ray_does() {
        let density = cloud(24, 3.0, DVec3::new(0.3, -0.2, 0.1));
        let base = MarchParams { max_step_factor: 3, ..params(camera(DVec3::new(0.3, -0.2, 0.1), 40, 30)) };
        // Step control is at work: thin cells take longer steps, which change the image.
        let factors: Vec<u32> = MajorantGrid::build(&density).values().iter().filter(|&&m| m > 0.0).map(|&m| base.step_factor(m)).collect();
        assert!(factors.contains(&1) && factors.contains(&3), "{factors:?}");
        let plain_lattice = render_cpu(&density, &cache_for(&density), &MarchParams { max_step_factor: 1, ..base.clone() }).unwrap();
        assert_ne!(plain_lattice, render_cpu(&density, &cache_for(&density), &base).unwrap());
        // vdbcache's layouts (fused into the density lattice, also the whole-point shift of
        // a coarser lattice) and lattices of their own.
        let caches = [
            ("scale 1 and 4", cache_on_density_lattice(&density, 1.0, 4.0)),
            ("scale 2 and 2", cache_on_density_lattice(&density, 2.0, 2.0)),
            ("offset lattices", cache_for(&density)),
            ("single only", IlluminationCache { li_single: cache_on_density_lattice(&density, 1.0, 1.0).li_single, li_multiple: None, ..Default::default() }),
        ];
        for (name, cache) in &caches {
            for aovs in [true, false] {
                let cases = [
                    ("1 spp", MarchParams { aovs, ..base.clone() }),
                    ("4 spp", MarchParams { aovs, spp: 4, ..base.clone() }),
                    // The offsets read at each sample (the displaced medium is baked, and held to
                    // the exact noise in offsets.rs).
                    ("offset noise", MarchParams { aovs, offset_noise: 0.05, noise_scale: 0.2, noise_eval: NoiseEval::Baked { nodes: 4 }, ..base.clone() }),
                    ("early termination", MarchParams { aovs, min_transmittance: 1e-3, medium: Medium { extinction: 6.0, ..base.medium }, ..base.clone() }),
                ];
                for (case, p) in cases {
                    let (rgb, alpha) = layout_against_plain(&density, cache, &p);
                    eprintln!("{name}, aovs {aovs}, {case}: max rel diff {rgb:.2e}, alpha {alpha:.2e}");
                    assert!(rgb <= 1e-4, "{name}, aovs {aovs}, {case}: rgb {rgb}");
                    // A ray stopping a sample earlier or later leaves up to the threshold.
                    assert!(alpha <= 1e-5f32.max(2.0 * p.min_transmittance as f32), "{name}, aovs {aovs}, {case}: alpha {alpha}");
                }
            }
        }
    }

    /// A uniform slab of unit density, 8 voxels of 0.1 thick along z (voxels z = 0..=7; the
    /// trilinear ramps at its faces make its density integral exactly 8 voxels), wide in x
    /// and y, with an emission grid of the same shape, seen face-on from above through a
    /// narrow lens; and the closed form `S c / sigma_a (1 - exp(-sigma_a d))`, d = 0.8.
    pub(crate) fn emitting_slab() -> (Volume<f32>, Emission, Vec3) {
        let slab = super::scenes::filled(0.1, glam::IVec3::new(-24, -24, 0), glam::IVec3::new(24, 24, 7), |_| true);
        let emission = Emission { grid: Some("flame".into()), strength: 2.0, color: Vec3::new(1.0, 0.5, 0.25), ..Emission::default() };
        let sigma = 3.0f64;
        let expect = Vec3::new(1.0, 0.5, 0.25) * (2.0 / sigma * (1.0 - (-sigma * 0.8).exp())) as f32;
        (slab, emission, expect)
    }

    pub(crate) fn slab_camera() -> nimbus_optics::Camera {
        nimbus_optics::Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::new(0.0, 0.0, 0.35), DVec3::Y, 2.0, 6, 6).unwrap()
    }

    #[test]
    fn an_emitting_absorbing_slab_marches_to_its_closed_form() {
        let (slab, emission, expect) = emitting_slab();
        let field = EmissionField { grid: Some(&slab), temperature: None, params: &emission };
        let medium = Medium { extinction: 3.0, albedo: Vec3::ZERO, g: 0.0 };
        let cache = IlluminationCache::default();
        for (step, spp) in [(0.5, 1), (1.0 / 3.0, 4), (1.0, 4)] {
            let p = MarchParams { medium, step: step * 0.1, spp, background: Vec3::ZERO, ..params(slab_camera()) };
            let image = render_cpu_with(&slab, &cache, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }).unwrap();
            let worst = image.rgba.iter().map(|c| ((c.truncate() - expect) / expect).abs().max_element()).fold(0.0, f32::max);
            let alpha = 1.0 - (-3.0f32 * 0.8).exp();
            let alpha_err = image.rgba.iter().map(|c| (c.w - alpha).abs()).fold(0.0, f32::max);
            eprintln!("slab, step {step:.3} voxel, {spp} spp: worst relative error {worst:.2e}, alpha {alpha_err:.2e}");
            // The march's emission telescopes to (S c / sigma)(1 - T_march) here (e / sigma_t
            // is constant where the slab is), so its error is the march's transmittance
            // error, from sampling the faces' one-voxel ramps on the step lattice.
            // Measured 5e-5 at every step: the oblique rays of the 2-degree lens (up to 0.8
            // degrees off the axis cross 1e-4 more slab) dominate what the ramps leave.
            assert!(worst < 5e-4, "step {step}: {worst}");
            // The colour sums to the emission layer, nothing scattered.
            let aovs = image.aovs.as_ref().unwrap();
            assert!(aovs.single.iter().chain(&aovs.multiple).all(|v| *v == Vec3::ZERO));
        }
        // One ray through march_ray_with itself, and without emission nothing.
        let p = MarchParams { medium, step: 0.05, background: Vec3::ZERO, ..params(slab_camera()) };
        let majorant = march_majorant(&slab, &p, None);
        let r = march_ray_with(&slab, &majorant, &cache, &p, DVec3::new(0.01, 0.02, 3.0), DVec3::NEG_Z, 0.3, 0.5, Some(&field), None, None, None);
        assert!(((r.emission - expect) / expect).abs().max_element() < 2e-3, "{} vs {expect}", r.emission);
        let r = march_ray(&slab, &majorant, &cache, &p, DVec3::new(0.01, 0.02, 3.0), DVec3::NEG_Z, 0.3, 0.5);
        assert_eq!(r.emission, Vec3::ZERO);
    }

    #[test]
    fn the_portable_march_agrees_with_the_avx2_one() {
        // render_cpu takes the AVX2+FMA copy where the CPU has it; the portable one runs
        // everywhere else.
        let density = cloud(24, 3.0, DVec3::ZERO);
        for (cache, aovs) in [(cache_on_density_lattice(&density, 1.0, 4.0), false), (cache_for(&density), true)] {
            let p = MarchParams { max_step_factor: 3, spp: 2, aovs, ..params(camera(DVec3::ZERO, 32, 24)) };
            let fast = render_cpu(&density, &cache, &p).unwrap();
            fn portable<T: DensityPoint>(density: &Volume<f32>, cache: &IlluminationCache, p: &MarchParams) -> Image {
                let volume = MarchVolume::<T>::new(density, cache, p.medium.albedo).unwrap();
                let mut pixels = vec![RayResult::default(); (p.camera.width() * p.camera.height()) as usize];
                render_band(Unfused, p, &Fast { volume: &volume, majorant: None, offsets: None, params: p }, 0, &mut pixels);
                assemble(p, &pixels)
            }
            let portable = if aovs { portable::<[Vec4; 2]>(&density, &cache, &p) } else { portable::<Vec4>(&density, &cache, &p) };
            let max = fast.rgba.iter().map(|c| c.truncate().element_sum()).fold(0.0, f32::max);
            for (a, b) in fast.rgba.iter().zip(&portable.rgba) {
                assert!((*a - *b).abs().max_element() <= 1e-5 * max, "{a} vs {b}");
            }
        }
    }

    #[test]
    fn groups_tile_the_lattice_and_restart_after_gaps() {
        use crate::Groups;
        let (dt, xi) = (0.3, 0.37);
        for u in [0.0, 0.4, 0.99] {
            // Adjacent cells of assorted factors and lengths (some shorter than a group),
            // then a gap.
            let cells = [(1.0, 2.9, 1), (2.9, 3.0, 4), (3.0, 5.2, 3), (5.2, 7.7, 2), (7.7, 8.0, 4), (9.5, 11.0, 2)];
            let mut groups = Groups::new();
            let mut covered = vec![];
            for &(a, b, f) in &cells {
                let c = groups.cell(a, b, dt, xi, u, f);
                for j in 0..c.count {
                    let sample = c.first + (j as u32 * f) as f64;
                    let start = sample - (u * f as f64).floor();
                    // Each group starts in its cell and its sample is one of its members.
                    assert!((start + xi) * dt >= a - 1e-12 && (start + xi) * dt < b, "cell {a}..{b}: group at {start}");
                    covered.extend((0..f).map(|m| (start + m as f64) as i64));
                }
            }
            // Lattice points from the first cell's first to where the groups end before the
            // gap, each once; after the gap, afresh from the first point in the cell.
            let first = (1.0f64 / dt - xi).ceil() as i64;
            let after_gap = (9.5f64 / dt - xi).ceil() as i64;
            let before: Vec<i64> = covered.iter().copied().filter(|&k| k < after_gap).collect();
            assert_eq!(before, (first..first + before.len() as i64).collect::<Vec<_>>(), "u {u}");
            assert!(((before.len() as i64 + first) as f64 + xi) * dt >= 8.0, "the groups reach the gap");
            assert_eq!(covered.iter().copied().find(|&k| k >= after_gap), Some(after_gap));
        }
    }

    #[test]
    fn step_factors_keep_a_step_thin() {
        let p = MarchParams { max_step_factor: 4, step: 0.5, medium: Medium { extinction: 2.0, ..params(camera(DVec3::ZERO, 4, 4)).medium }, ..params(camera(DVec3::ZERO, 4, 4)) };
        // One lattice step at bound m spans 2 * 0.5 * m = m optical depths.
        for (m, f) in [(0.3, 1), (0.25, 1), (0.125, 2), (0.1, 2), (0.08, 3), (0.0625, 4), (1e-6, 4), (0.0, 4), (f32::NAN, 1)] {
            assert_eq!(p.step_factor(m), f, "bound {m}");
        }
        assert_eq!(MarchParams { max_step_factor: 1, ..p }.step_factor(1e-6), 1);
    }

    #[test]
    fn samples_take_one_cell_each_of_the_largest_square_grid() {
        for spp in [2u32, 4, 5, 9, 16, 17] {
            let n = spp.isqrt();
            let mut seen = vec![0; (n * n) as usize];
            for s in 0..spp {
                for (u, v) in [(0.0, 0.0), (0.999, 0.5), (0.3, 0.999)] {
                    let (x, y) = pixel_jitter(s, spp, u, v);
                    assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y), "spp {spp}, sample {s}: ({x}, {y})");
                    if s < n * n {
                        let cell = ((y * n as f64) as u32 * n + (x * n as f64) as u32) as usize;
                        assert_eq!(cell, s as usize, "spp {spp}: sample {s} left its cell");
                    } else {
                        assert_eq!((x, y), (u, v), "past n^2 a sample may fall anywhere");
                    }
                }
                if s < n * n {
                    seen[s as usize] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "spp {spp}: every cell once");
        }
    }
}
