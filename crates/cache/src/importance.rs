//! How much each cache voxel's value moves the camera's image: where the path-traced
//! Li_multiple spends its paths.
//!
//! The march adds, per camera-ray sample x, `T (1 - exp(-sigma_t dt)) albedo Li(x)`, with
//! Li(x) interpolated trilinearly from the cache. So pixel p depends on voxel v's value
//! linearly, with derivative `a_pv = albedo * sum over p's samples of T (1 - exp(-sigma_t dt))
//! w_v(x)` (w_v the trilinear weight). A voxel estimated from n_v paths of per-path variance
//! s_v^2 adds `G_v s_v^2 / n_v` to the image's summed squared error, `G_v = sum_p a_pv^2`;
//! for a fixed number of paths that is least with n_v proportional to `sqrt(G_v) s_v`. The
//! per-path spread s_v is not known before tracing and is taken as equal (a pilot pass that
//! measured it per brick, and the paths' cost, bought nothing over this on the bundled cloud
//! at equal CPU time), so the paths go as sqrt(G_v). That follows the transmittance toward the
//! eye (what a voxel's value is seen through), the density around the voxel (a voxel in thin
//! air beside a cloud is read with small weights) and how many pixels read it at all (a
//! coarse image reads a fine lattice only along its rays).

use glam::{DVec3, IVec3};
use nimbus_optics::{Camera, Rng};
use nimbus_volume::{lattice_cell, MajorantGrid, Volume};
use rayon::prelude::*;

use std::sync::atomic::{AtomicU64, Ordering};

use crate::plan::VoxelIndex;
use crate::{CacheParams, CachePlan};

/// One in G's fixed point. A pixel's derivative is at most 1 (its opacity), so each term is
/// at most 1 and G at most the rays' count ([`IMPORTANCE_RAYS`] < 2^24), well within 64 bits;
/// terms under 2^-40 (derivatives under 1e-6) are too small to earn a path anyway.
const G_FIXED_ONE: f64 = (1u64 << 40) as f64;

/// At most this many camera rays estimate the importance: through the march's default
/// samples of each pixel ([`pixel_samples_per_side`]) while the image is small, then fewer a
/// pixel, then through every s-th pixel's centre each way. G_v is a smooth function of the
/// image, and only its proportions matter; but the paths' origins lie along these rays, and
/// Li_multiple's lattice bias is estimated along them, so they must read the volume where the
/// march does. One ray at the centre of pixels 2.5 voxels wide, which the march reads at 4 x 4
/// samples, left voxels between the rays with paths from their node and a bias the estimate
/// could not see (`nimbus-scene --random 20261207044`: 5.3% off the reference, darker as the
/// lattice was refined; issue #47). Where pixels are narrower than a quarter voxel (the
/// bundled scenes, the Cloud1-class frame) that is one ray a pixel, as it always was.
pub const IMPORTANCE_RAYS: usize = 1 << 16;

/// Most optical depth an importance step holds before it is cut ([`ImportanceRays`]).
const IMPORTANCE_STEP_DEPTH: f64 = 0.25;

/// Most pieces a dense importance step is cut into.
const MAX_IMPORTANCE_STEP_CUTS: f64 = 256.0;

/// Most samples per pixel side [`pixel_samples_per_side`] takes (64 samples a pixel). The
/// march's cost does not grow with the footprint beyond a quarter voxel: the pixels that
/// cover the volume fall as the footprint's square and the samples grow as it, so any frame
/// costs at most what the volume costs at 4 x 4 samples a voxel, and the cap binds only at
/// footprints of 2 voxels and more. There 4 x 4 samples, 0.62 voxels apart on pixels 2.5
/// voxels wide (`nimbus-scene --random 20261207044`), left 1.3% of the chain's 2.1% against
/// the reference (1.6% at 8 x 8).
pub const MAX_SAMPLES_PER_PIXEL_SIDE: u32 = 8;

/// How many samples the march takes per pixel side by default for `camera` over `density`
/// (`vdbmarch`'s `--spp` is its square): n x n stratified samples, n enough that a pixel's
/// samples lie at most a quarter of a density voxel apart at the distance of the volume's
/// centre (n = ceil(4 x pixel footprint / thinnest voxel width), 1 to
/// [`MAX_SAMPLES_PER_PIXEL_SIDE`]). The pixel is a box filter and its n x n samples a
/// quadrature of it, whose error goes as the square of their spacing over the density's
/// detail, the voxel: a ball of particles each about a voxel wide, pixels 0.77 voxels wide,
/// is 1.2% off the path-traced reference at 2 x 2 (samples 0.38 voxels apart, the old rule's
/// choice), 0.55% at 3 x 3, 0.36% at 4 x 4 (0.19 apart, this rule's; docs/benchmarks.md,
/// "Dense media"); half a voxel apart had been measured only where the cap decides (the
/// bundled plume at 128 x 72: 2.2% at one sample, 1.3% at 16). Where pixels are a quarter of
/// a voxel or narrower one sample is all it takes (the Cloud1-class scene at 1024 x 576, the
/// bundled cloud at 960 x 540: one). The bake's importance rays read each pixel at the same
/// samples ([`IMPORTANCE_RAYS`]).
pub fn pixel_samples_per_side(camera: &Camera, density: &Volume<f32>) -> u32 {
    let Some((lo, hi)) = density.world_bounds() else { return 1 };
    let distance = (0.5 * (lo + hi) - camera.eye()).length();
    let footprint = camera.pixel_width_at(distance);
    let voxel = density.transform().voxel_widths().min_element();
    let n = (4.0 * footprint / voxel).ceil();
    if n.is_finite() {
        (n as u32).clamp(1, MAX_SAMPLES_PER_PIXEL_SIDE)
    } else {
        1
    }
}

/// Random-number domain of the path origins' draws ("CAOR").
const ORIGINS_DOMAIN: u32 = 0x4341_4f52;

/// G_v per planned voxel, in plan order ([`CachePlan::voxel_positions`]), up to one common
/// factor; and W_v, the summed weight of the march's samples that read the voxel.
pub struct CameraImportance {
    pub g: Vec<f64>,
    /// W_v in fixed point ([`G_FIXED_ONE`]), summed sample by sample: the total the path
    /// origins are drawn along.
    pub weight: Vec<u64>,
    /// Per importance pixel, in pixel order: the voxels its samples read, each with its
    /// samples' summed fixed-point weight (the terms of W_v), sorted by voxel.
    reads: Vec<Vec<(u32, u64)>>,
}

/// Most origins a voxel's paths start from: path j of a voxel starts at its origin j modulo
/// their number. Sixteen stratified draws of the image's weight over the voxel's footprint
/// resolve its spread; drawing one per path (a million paths a second) had made the draw
/// and its sort a fifth of the Cloud1-class bake.
pub const MAX_ORIGINS_PER_VOXEL: u32 = 16;

/// Where the paths of a `--paths` bake start: `counts[v]` paths for planned voxel v, cycling
/// over its origins `origins[first[v]..first[v] + min(counts[v], MAX_ORIGINS_PER_VOXEL)]`.
pub struct PathPlan {
    pub counts: Vec<u32>,
    pub first: Vec<usize>,
    pub origins: Vec<DVec3>,
    /// Per origin, the octant about its voxel's node it lies in ([`octant`]): the paths'
    /// spread within the footprint, which estimates the lattice's bias (multiple_lattice.rs).
    pub octants: Vec<u8>,
    /// G_v per voxel (the module doc): what a voxel's noise adds to the image's squared error.
    pub importance: Vec<f64>,
    /// W_v per voxel: what its value adds to the image's summed level.
    pub read_weight: Vec<f64>,
    /// Importance rays that read any voxel: the pixels G and W are summed over.
    pub covered_rays: usize,
}

impl PathPlan {
    /// The origins of voxel `v`'s paths (at most [`MAX_ORIGINS_PER_VOXEL`]).
    pub fn origins_of(&self, v: usize) -> &[DVec3] {
        &self.origins[self.first[v]..self.first[v] + origin_count(self.counts[v]) as usize]
    }

    /// Their octants ([`PathPlan::octants`]).
    pub fn octants_of(&self, v: usize) -> &[u8] {
        &self.octants[self.first[v]..self.first[v] + origin_count(self.counts[v]) as usize]
    }

    pub fn total(&self) -> u64 {
        self.counts.iter().map(|&n| n as u64).sum()
    }

    /// More paths for the same voxels: `extra[v]` for voxel v, from its origins (repeated
    /// where it now has more paths than origins; the shaders and the CPU cycle through
    /// min(count, [`MAX_ORIGINS_PER_VOXEL`]) of them). Only the paths: the image's weights
    /// stay with `self`, which predicts the noise of both passes (budget.rs).
    pub fn more(&self, extra: Vec<u32>) -> PathPlan {
        let mut first = Vec::with_capacity(extra.len());
        let (mut origins, mut octants) = (Vec::new(), Vec::new());
        for (v, &n) in extra.iter().enumerate() {
            first.push(origins.len());
            let own = self.first[v]..self.first[v] + origin_count(self.counts[v]) as usize;
            for j in 0..origin_count(n) as usize {
                let k = own.start + j % own.len().max(1);
                origins.push(self.origins[k]);
                octants.push(self.octants[k]);
            }
        }
        PathPlan { counts: extra, first, origins, octants, importance: Vec::new(), read_weight: Vec::new(), covered_rays: 0 }
    }

    /// Voxel `v`'s paths per half (even and odd path index) and octant: the counts behind
    /// [`PathMoments::halves`](crate::PathMoments::halves), index `8 * half + octant`. Path j
    /// starts from origin j mod m (m origins), so origin k serves paths k, k + m, k + 2m, ...:
    /// all of k's parity where m is even, alternating from it where m is odd.
    pub fn half_octant_counts(&self, v: usize) -> [u32; 16] {
        let (n, m) = (self.counts[v], origin_count(self.counts[v]));
        let mut counts = [0u32; 16];
        for (k, &o) in self.octants_of(v).iter().enumerate() {
            let k = k as u32;
            let paths = (n - k).div_ceil(m);
            let own = if m % 2 == 0 { paths } else { paths.div_ceil(2) };
            let parity = (k & 1) as usize;
            counts[8 * parity + o as usize] += own;
            counts[8 * (1 - parity) + o as usize] += paths - own;
        }
        counts
    }

    /// Voxels no path starts in: no camera ray reads them or any neighbour.
    pub fn unseen(&self) -> u64 {
        self.counts.iter().filter(|&&n| n == 0).count() as u64
    }
}

/// The camera rays the importance is estimated along, and how the march weighs its samples.
pub(crate) struct ImportanceRays<'a> {
    camera: &'a Camera,
    density: &'a Volume<f32>,
    majorant: &'a MajorantGrid,
    extinction: f64,
    min_transmittance: f64,
    /// Pixels per ray, each way.
    stride: usize,
    /// Rays per pixel, each way, where `stride` is 1: the march's samples of the pixel.
    sub: usize,
    /// Pixels with rays per row and column.
    sw: usize,
    sh: usize,
    step: f64,
}

/// Pixels between neighbouring importance rays on each axis: 1 up to [`IMPORTANCE_RAYS`]
/// pixels, then enough to keep the rays within it.
pub(crate) fn importance_stride(camera: &Camera) -> usize {
    let pixels = camera.width() as f64 * camera.height() as f64;
    (pixels / IMPORTANCE_RAYS as f64).sqrt().ceil().max(1.0) as usize
}

/// Importance rays per pixel side: the march's default samples
/// ([`pixel_samples_per_side`]) while all of them fit within [`IMPORTANCE_RAYS`], as many as
/// do beyond that, one where the rays are strided.
pub(crate) fn importance_rays_per_pixel_side(camera: &Camera, density: &Volume<f32>) -> usize {
    let pixels = camera.width() as usize * camera.height() as usize;
    let fit = ((IMPORTANCE_RAYS / pixels.max(1)) as f64).sqrt().floor().max(1.0) as usize;
    (pixel_samples_per_side(camera, density) as usize).min(fit)
}

/// How far apart the importance rays pass at the volume's centre, in the density's thinnest
/// voxel widths: a path-traced lattice finer than this has voxels no importance ray reads,
/// which get their paths from the node alone and not from where the image reads them.
pub(crate) fn importance_ray_spacing(camera: &Camera, density: &Volume<f32>) -> f64 {
    let Some((lo, hi)) = density.world_bounds() else { return 0.0 };
    let distance = (0.5 * (lo + hi) - camera.eye()).length();
    let pitch = importance_stride(camera) as f64 / importance_rays_per_pixel_side(camera, density) as f64;
    let spacing = camera.pixel_width_at(distance) * pitch / density.transform().voxel_widths().min_element();
    if spacing.is_finite() { spacing } else { 0.0 }
}

impl<'a> ImportanceRays<'a> {
    pub(crate) fn new(plan: &CachePlan, density: &'a Volume<f32>, majorant: &'a MajorantGrid, extinction: f32, camera: &'a Camera, min_transmittance: f64) -> Self {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let stride = importance_stride(camera);
        ImportanceRays {
            camera,
            density,
            majorant,
            extinction: extinction as f64,
            min_transmittance,
            stride,
            sub: if stride == 1 { importance_rays_per_pixel_side(camera, density) } else { 1 },
            sw: w.div_ceil(stride),
            sh: h.div_ceil(stride),
            step: 0.5 * plan.transform.voxel_size().min_element(),
        }
    }

    pub(crate) fn pixels(&self) -> usize {
        self.sw * self.sh
    }

    /// Which of `k` x `k` tiles of the image pixel `p` lies in (row-major).
    pub(crate) fn tile(&self, p: usize, k: usize) -> usize {
        (p % self.sw) * k / self.sw + k * ((p / self.sw) * k / self.sh)
    }

    /// Marches pixel `p`'s rays as `vdbmarch` does (step: half the plan's voxel edge, cut
    /// where it is optically thick) and
    /// calls `f(x, w)` at each sample, w its weight in the pixel's value,
    /// `T (1 - exp(-sigma_t dt))` over the pixel's rays ([`ImportanceRays::sub`] squared,
    /// through the centres of the strata the march jitters its samples in).
    pub(crate) fn march_pixel(&self, p: usize, mut f: impl FnMut(DVec3, f64)) {
        let (px, py) = ((p % self.sw * self.stride) as f64, (p / self.sw * self.stride) as f64);
        let sub = self.sub;
        // Through the centre of the pixel (or of the stride's block), or of each stratum.
        let pitch = self.stride as f64 / sub as f64;
        let share = 1.0 / (sub * sub) as f64;
        for s in 0..sub * sub {
            let (jx, jy) = ((s % sub) as f64 + 0.5, (s / sub) as f64 + 0.5);
            self.march_ray(px + jx * pitch, py + jy * pitch, |x, w| f(x, share * w));
        }
    }

    fn march_ray(&self, px: f64, py: f64, mut f: impl FnMut(DVec3, f64)) {
        let step = self.step;
        let transform = self.density.transform();
        let (origin, dir) = self.camera.ray(px, py);
        let (o, d) = (transform.to_index(origin), transform.dir_to_index(dir));
        let mut tr = 1.0f64;
        for seg in self.majorant.walk(o, d, 0.0, f64::INFINITY) {
            if seg.majorant.is_nan() || seg.majorant <= 0.0 || seg.t_end.is_infinite() {
                continue;
            }
            let mut k = (seg.t_start / step - 0.5).ceil();
            loop {
                let t = (k + 0.5) * step;
                if t >= seg.t_end {
                    break;
                }
                k += 1.0;
                let x = origin + dir * t;
                let sigma_t = self.extinction * self.density.sample_world(x).max(0.0) as f64;
                if !(sigma_t > 0.0) {
                    continue;
                }
                // A step denser than IMPORTANCE_STEP_DEPTH is cut so that its weight lands
                // where the medium's skin is, not at its middle: in a shell of 18 optical
                // depths a voxel a step of one voxel put the paths' origins anywhere in the
                // first voxel while the image reads the first twentieth of it, and
                // Li_multiple's lattice bias (4%) was estimated at 1.6% (`nimbus-scene
                // --random 20261207035`). The ray ends within ln(1 / min_transmittance) /
                // IMPORTANCE_STEP_DEPTH of the cut steps, so this costs a bounded few.
                let cuts = (sigma_t * step / IMPORTANCE_STEP_DEPTH).ceil().min(MAX_IMPORTANCE_STEP_CUTS);
                if cuts <= 1.0 {
                    let step_transmittance = (-sigma_t * step).exp();
                    f(x, tr * (1.0 - step_transmittance));
                    tr *= step_transmittance;
                } else {
                    let dt = step / cuts;
                    for j in 0..cuts as u32 {
                        let x = origin + dir * (t - 0.5 * step + (j as f64 + 0.5) * dt);
                        let sigma_t = self.extinction * self.density.sample_world(x).max(0.0) as f64;
                        let step_transmittance = (-sigma_t * dt).exp();
                        if sigma_t > 0.0 {
                            f(x, tr * (1.0 - step_transmittance));
                        }
                        tr *= step_transmittance;
                        if tr < self.min_transmittance {
                            return;
                        }
                    }
                }
                if tr < self.min_transmittance {
                    return;
                }
            }
        }
    }
}

impl CameraImportance {
    /// Marches the camera's rays through the density as `vdbmarch` does and sums each
    /// pixel's derivatives per voxel of `plan`.
    pub fn new(plan: &CachePlan, density: &Volume<f32>, majorant: &MajorantGrid, extinction: f32, camera: &Camera, min_transmittance: f64) -> CameraImportance {
        let index = plan.voxel_index();
        let rays = ImportanceRays::new(plan, density, majorant, extinction, camera, min_transmittance);
        // Summed in fixed point, so G (and the paths, and the cache) does not depend on the
        // order the threads add in.
        let fixed: Vec<AtomicU64> = (0..plan.stats.baked).map(|_| AtomicU64::new(0)).collect();
        let reads: Vec<Vec<(u32, u64)>> = (0..rays.pixels())
            .into_par_iter()
            .map_init(Vec::<(u32, f64, u64)>::new, |derivs, p| {
                derivs.clear();
                rays.march_pixel(p, |x, w| spread(&index, plan.transform.to_index(x), w, derivs));
                // One pixel's derivative per voxel is the sum over its samples; G adds
                // their squares. W sums the samples' fixed-point weights, as the origins'
                // draw walks them again sample by sample.
                derivs.sort_unstable_by_key(|d| d.0);
                derivs
                    .chunk_by(|a, b| a.0 == b.0)
                    .map(|run| {
                        let a: f64 = run.iter().map(|d| d.1).sum();
                        fixed[run[0].0 as usize].fetch_add(to_fixed(a * a), Ordering::Relaxed);
                        (run[0].0, run.iter().map(|d| d.2).sum::<u64>())
                    })
                    .collect()
            })
            .collect();
        let g = fixed.into_iter().map(|f| f.into_inner() as f64 / G_FIXED_ONE).collect();
        let mut weight = vec![0u64; plan.stats.baked as usize];
        for &(v, w) in reads.iter().flatten() {
            weight[v as usize] += w;
        }
        CameraImportance { g, weight, reads }
    }

    /// The paths of a `--paths per_voxel` bake over `plan`: the one plan both backends trace.
    ///
    /// Counts by [`CameraImportance::paths`]. Each path starts at a point the camera's rays
    /// sample within the voxel's trilinear footprint, drawn with probability proportional to
    /// that sample's weight in the image (march weight times the voxel's trilinear weight).
    /// So the voxel estimates the average of Li over what the image reads through it, not Li
    /// at its centre: summed over the image, every sample's Li then counts with its own
    /// weight (the trilinear weights of a point add up to one), and a lattice coarser than
    /// the medium's light gradients blurs the image but does not darken it, where centre
    /// values inside a thick cloud, far darker than its lit surface, did. Voxels read by no
    /// sample start their paths at their centre; voxels that neither they nor any neighbour
    /// are read get none.
    pub fn path_plan(plan: &CachePlan, density: &Volume<f32>, majorant: &MajorantGrid, params: &CacheParams, per_voxel: u32) -> PathPlan {
        let importance = CameraImportance::new(plan, density, majorant, params.medium.extinction, &params.camera, params.min_transmittance);
        let seen = importance.seen_or_beside(plan);
        let counts = importance.paths(per_voxel, &seen);
        let first: Vec<usize> = counts
            .iter()
            .scan(0usize, |next, &n| {
                let start = *next;
                *next += origin_count(n) as usize;
                Some(start)
            })
            .collect();
        let total = counts.iter().map(|&n| origin_count(n) as usize).sum();
        let positions = plan.voxel_positions();
        let mut origins = vec![DVec3::NAN; total];
        // Who reads each voxel, in pixel order: the per-pixel lists transposed.
        let mut by_voxel_start = vec![0usize; counts.len() + 1];
        for &(v, _) in importance.reads.iter().flatten() {
            by_voxel_start[v as usize + 1] += 1;
        }
        for v in 0..counts.len() {
            by_voxel_start[v + 1] += by_voxel_start[v];
        }
        let mut fill = by_voxel_start.clone();
        let mut by_voxel = vec![(0u32, 0u64); by_voxel_start[counts.len()]];
        for (p, list) in importance.reads.iter().enumerate() {
            for &(v, w) in list {
                by_voxel[fill[v as usize]] = (p as u32, w);
                fill[v as usize] += 1;
            }
        }
        // Stratified targets along each voxel's total weight: origin j of voxel v is the
        // sample where the running weight passes (j + u_j) / n_v of W_v (n_v its origins);
        // each target is found here to its pixel and the weight left within it.
        let mut targets: Vec<(u32, u32, u64, u32)> = (0..counts.len())
            .into_par_iter()
            .flat_map_iter(|v| {
                let (n, w) = (origin_count(counts[v]) as u64, importance.weight[v]);
                let readers = &by_voxel[by_voxel_start[v]..by_voxel_start[v + 1]];
                let mut rng = Rng::with_domain(params.seed, v as u64, ORIGINS_DOMAIN);
                let (mut r, mut before) = (0usize, 0u64);
                (0..if w == 0 { 0 } else { n })
                    .map(move |j| {
                        let u = (((j as f64 + rng.next_f64()) / n as f64) * w as f64).min((w - 1) as f64) as u64;
                        while before + readers[r].1 <= u {
                            before += readers[r].1;
                            r += 1;
                        }
                        (readers[r].0, v as u32, u - before, j as u32)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        targets.par_sort_unstable();
        // Each pixel with targets marched again, its samples in the order W summed them.
        let index = plan.voxel_index();
        let rays = ImportanceRays::new(plan, density, majorant, params.medium.extinction, &params.camera, params.min_transmittance);
        let found: Vec<(usize, DVec3)> = targets
            .par_chunk_by(|a, b| a.0 == b.0)
            .flat_map_iter(|group| {
                let mut out = Vec::with_capacity(group.len());
                // Per voxel with targets here (sorted by voxel): the weight run so far and its
                // next target; the group is sorted by voxel, then by the weight left.
                let mut running: Vec<(u32, u64, usize)> = Vec::new();
                for (i, t) in group.iter().enumerate() {
                    if running.last().is_none_or(|r| r.0 != t.1) {
                        running.push((t.1, 0, i));
                    }
                }
                let mut derivs = Vec::new();
                rays.march_pixel(group[0].0 as usize, |x, w| {
                    derivs.clear();
                    spread(&index, plan.transform.to_index(x), w, &mut derivs);
                    for &(v, _, c) in &derivs {
                        let Ok(k) = running.binary_search_by_key(&v, |r| r.0) else { continue };
                        let (_, sum, next) = &mut running[k];
                        *sum += c;
                        while *next < group.len() && group[*next].1 == v && group[*next].2 < *sum {
                            out.push((first[v as usize] + group[*next].3 as usize, x));
                            *next += 1;
                        }
                    }
                });
                out
            })
            .collect();
        for (i, x) in found {
            origins[i] = x;
        }
        // Voxels no sample reads (and, within rounding, any target not met) start at the centre.
        for (v, &p) in positions.iter().enumerate() {
            for o in &mut origins[first[v]..first[v] + origin_count(counts[v]) as usize] {
                if o.is_nan() {
                    *o = p;
                }
            }
        }
        let mut octants = vec![0u8; origins.len()];
        for (v, &p) in positions.iter().enumerate() {
            let node = plan.transform.to_index(p);
            for k in first[v]..first[v] + origin_count(counts[v]) as usize {
                octants[k] = octant(plan.transform.to_index(origins[k]) - node) as u8;
            }
        }
        let covered_rays = importance.reads.iter().filter(|r| !r.is_empty()).count();
        let read_weight = importance.weight.iter().map(|&w| w as f64 / G_FIXED_ONE).collect();
        PathPlan { counts, first, origins, octants, importance: importance.g, read_weight, covered_rays }
    }

    /// Whether each voxel or one of its 26 neighbours is read by an importance sample: the
    /// importance rays are strided over large images, so a voxel between two of them may
    /// still be read by the pixels in between.
    fn seen_or_beside(&self, plan: &CachePlan) -> Vec<bool> {
        let index = plan.voxel_index();
        let positions = plan.voxel_positions();
        (0..self.g.len())
            .into_par_iter()
            .map(|v| {
                if self.g[v] > 0.0 {
                    return true;
                }
                let c = plan.transform.to_index(positions[v]).round().as_ivec3();
                (0..27).any(|n| {
                    let o = IVec3::new(n % 3 - 1, n / 3 % 3 - 1, n / 9 - 1);
                    index.get(c + o).is_some_and(|u| self.g[u] > 0.0)
                })
            })
            .collect()
    }

    /// Paths per voxel, `per_voxel` times the voxels in all: one each for the voxels `seen`
    /// marks (so every voxel the image may read holds an estimate), none for the others, and
    /// the rest in proportion to sqrt(G_v), rounded along the running sum so the total is
    /// exact. Where the camera sees nothing, `per_voxel` each.
    pub fn paths(&self, per_voxel: u32, seen: &[bool]) -> Vec<u32> {
        let total: f64 = self.g.iter().map(|g| g.sqrt()).sum();
        if !(total > 0.0 && total.is_finite()) {
            return vec![per_voxel; self.g.len()];
        }
        let kept = seen.iter().filter(|&&s| s).count() as f64;
        let rest = (per_voxel.max(1) as f64 * self.g.len() as f64 - kept).max(0.0);
        let (mut running, mut given) = (0.0f64, 0u64);
        self.g
            .iter()
            .zip(seen)
            .map(|(g, &seen)| {
                running += g.sqrt();
                let due = (rest * (running / total)).round() as u64;
                let n = due.saturating_sub(given);
                given += n;
                (seen as u64 + n).min(u32::MAX as u64) as u32
            })
            .collect()
    }
}

/// The octant of an offset from a node (lattice index units): bit 2 x >= 0, bit 1 y, bit 0 z.
pub(crate) fn octant(rel: DVec3) -> usize {
    (rel.x >= 0.0) as usize * 4 + (rel.y >= 0.0) as usize * 2 + (rel.z >= 0.0) as usize
}

/// The origins of a voxel with `paths` paths.
fn origin_count(paths: u32) -> u32 {
    paths.min(MAX_ORIGINS_PER_VOXEL)
}

fn to_fixed(x: f64) -> u64 {
    (x * G_FIXED_ONE).round() as u64
}

/// Adds `weight` times each trilinear corner weight at cache index `c` (as
/// `Volume::sample_index` interpolates) to `out`, for the corners `index` plans.
pub(crate) fn spread(index: &VoxelIndex<'_>, c: DVec3, weight: f64, out: &mut Vec<(u32, f64, u64)>) {
    let Some((b, f)) = lattice_cell(c) else { return };
    for corner in 0..8 {
        let o = IVec3::new((corner >> 2) & 1, (corner >> 1) & 1, corner & 1);
        let pick = |bit: i32, f: f64| if bit == 1 { f } else { 1.0 - f };
        let w = pick(o.x, f.x) * pick(o.y, f.y) * pick(o.z, f.z);
        if w > 0.0 {
            if let Some(i) = index.get(b + o) {
                out.push((i as u32, weight * w, to_fixed(weight * w)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_octant_counts_are_the_paths_by_parity_and_origin_octant() {
        // Voxels of 5 (odd: 5 origins), 20 and 37 paths (16 origins each), path j from
        // origin j mod m, origin k in octant k mod 8.
        let counts = vec![5u32, 20, 37];
        let first: Vec<usize> = vec![0, 5, 21];
        let octants: Vec<u8> = (0..37).map(|k| (k % 8) as u8).collect();
        let plan = PathPlan { counts: counts.clone(), first, origins: vec![DVec3::ZERO; 37], octants, importance: Vec::new(), read_weight: Vec::new(), covered_rays: 0 };
        for (v, &n) in counts.iter().enumerate() {
            let mut expected = [0u32; 16];
            let m = n.min(MAX_ORIGINS_PER_VOXEL);
            for j in 0..n {
                expected[8 * (j as usize & 1) + plan.octants_of(v)[(j % m) as usize] as usize] += 1;
            }
            assert_eq!(plan.half_octant_counts(v), expected, "voxel {v}");
            assert_eq!(expected.iter().sum::<u32>(), n);
        }
    }

    #[test]
    fn paths_add_up_exactly_and_follow_the_square_root_of_importance() {
        // Importance 0 (unseen), 1, 4, 16, 100 times over: the rest goes as 0:1:2:4.
        let g: Vec<f64> = [0.0, 1.0, 4.0, 16.0].iter().copied().cycle().take(400).collect();
        let seen = vec![true; g.len()];
        let paths = CameraImportance { g: g.clone(), weight: vec![0; g.len()], reads: Vec::new() }.paths(8, &seen);
        assert_eq!(paths.iter().map(|&n| n as u64).sum::<u64>(), 8 * 400, "N per voxel on average, exactly");
        assert!(paths.iter().all(|&n| n >= 1), "every voxel keeps an estimate");
        let mean = |k: usize| paths.iter().skip(k).step_by(4).map(|&n| n as f64).sum::<f64>() / 100.0;
        assert_eq!(mean(0), 1.0, "voxels beside seen ones get their one path only");
        // The 7 x 400 paths beyond the first go 1:2:4 over sqrt(G) = 1, 2, 4.
        let unit = 7.0 * 400.0 / (100.0 * 7.0);
        for (k, share) in [(1, 1.0), (2, 2.0), (3, 4.0)] {
            assert!((mean(k) - 1.0 - share * unit).abs() < 0.01, "sqrt(G) = {share}: {} paths", mean(k));
        }
    }

    #[test]
    fn a_camera_that_sees_nothing_gets_n_paths_everywhere() {
        let of = |g: Vec<f64>, seen: Vec<bool>, n: u32| CameraImportance { weight: vec![0; g.len()], g, reads: Vec::new() }.paths(n, &seen);
        assert_eq!(of(vec![0.0; 5], vec![false; 5], 3), vec![3; 5]);
        assert_eq!(of(vec![], vec![], 3), Vec::<u32>::new());
        assert_eq!(of(vec![2.0, 0.0], vec![true, true], 1), vec![1, 1]);
    }

    #[test]
    fn unseen_voxels_get_no_paths_and_their_share_goes_to_the_seen() {
        let g = vec![1.0, 0.0, 4.0, 0.0];
        let paths = CameraImportance { weight: vec![0; 4], g, reads: Vec::new() }.paths(3, &[true, false, true, true]);
        assert_eq!(paths.iter().sum::<u32>(), 12, "the budget is kept");
        assert_eq!(paths[1], 0, "unseen: no path");
        assert_eq!(paths[3], 1, "beside a seen voxel: one path");
        assert_eq!((paths[0] - 1) * 2, paths[2] - 1, "the rest by sqrt(G)");
    }
}
