//! ici's rule (issue #21): from every rung's estimate and variance over the whole grid, each
//! voxel's smoothing length. One host function for both backends: the CPU's ladder pass and
//! the GPU's `ladder` entry produce the same [`RungSums`], and the lengths go to the density
//! pass.
//!
//! The error of rung k at a voxel is bias_k^2 + Gamma^2 var_k. Its bias is measured against
//! the shorter rungs j (the next shorter, and the shortest): the squared difference
//! (rho_k - rho_j)^2 less that difference's expected noise, averaged over a box about the
//! voxel of radius h_k, extrapolated to the bias of rung k itself by the h^2 law of a
//! kernel's bias (rho_k - rho_j = b (h_k^2 - h_j^2) where rho_k = rho + b h_k^2). The average
//! is what makes this work where a per-voxel test fails: a voxel's own differences are
//! dominated by noise exactly where the bias matters (a thin shell, the flank of a knot), but
//! the noise of the debiased square averages out over the box while the bias does not. The
//! voxel takes the rung of least error; the rung indices are then averaged over the 5^3 voxels
//! about it and the length interpolated geometrically between rungs, so neighbouring voxels
//! do not jump between rungs (per-voxel choices cost Cloud1-class 10% in the lab).

use glam::IVec3;
use nimbus_volume::{BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

use crate::kernel::{ici_pair_noise, ici_scales};
use crate::Prepared;

/// A brick's final smoothing lengths (index units), what ici's rule chooses and the density
/// passes read, kept between the conserve-mass passes: 0 at voxels no pass evaluates
/// (outside the grid, or no particle within kappa*h0).
pub(crate) type Lengths = Box<[f32; BRICK_VOXELS]>;

/// The bias's averaging box, radius in units of the longer rung of a pair (voxels): 0.5,
/// 0.75 and 1 measured 0.2325, 0.2223, 0.2188 on the shell (Cloud1-class 0.1377, 0.1361,
/// 0.1363), at Gamma 1 and rung ratio 1.4.
const BIAS_BOX: f32 = 1.0;
/// The rung choice's averaging box, radius in voxels: 1 and 3 measured 0.2270 and 0.2222 on
/// the shell against 2's 0.2223 (Cloud1-class 0.1372, 0.1357, 0.1361), at Gamma 1, bias box
/// 0.75 and rung ratio 1.4.
const CHOICE_BOX: i32 = 2;

/// A brick's ladder: per rung, the estimate rho_k = sum m W_k and its variance, on the index
/// scale (1/pi dropped: it cancels); whether each voxel is reached (a particle within the top
/// rung; elsewhere nothing is evaluated and the estimates are 0).
pub(crate) struct RungSums {
    pub rho: Vec<[f32; BRICK_VOXELS]>,
    pub var: Vec<[f32; BRICK_VOXELS]>,
    pub reached: [bool; BRICK_VOXELS],
}

impl RungSums {
    /// From a ladder pass's raw sums per rung k of `h` (index units): `sums[k]` = sum m
    /// m4_shape(r / h_k), `squares[k]` = sum of those terms squared. The variance of a small
    /// rung holding no or one particle says nothing (0 in an empty ball: a confident zero), so
    /// it is floored by its expectation from the top rung, which scales with the ball's volume.
    pub fn from_sums(h: &[f32], sums: &[[f32; BRICK_VOXELS]], squares: &[[f32; BRICK_VOXELS]], reached: [bool; BRICK_VOXELS]) -> Box<RungSums> {
        let (scale, volume) = ici_scales(h);
        let top = h.len() - 1;
        let mut out = Box::new(RungSums { rho: vec![[0.0; BRICK_VOXELS]; h.len()], var: vec![[0.0; BRICK_VOXELS]; h.len()], reached });
        for k in 0..h.len() {
            let c = scale[k];
            for v in 0..BRICK_VOXELS {
                if reached[v] {
                    out.rho[k][v] = c * sums[k][v];
                    out.var[k][v] = c * c * squares[k][v].max(squares[top][v] * volume[k]);
                }
            }
        }
        out
    }
}

type Field = Vec<[f32; BRICK_VOXELS]>;

/// The bricks next to each proposed brick along each axis (-, +), where proposed.
fn neighbours(prep: &Prepared) -> Vec<[[Option<u32>; 2]; 3]> {
    let (slot, brick_id) = crate::brick_slots(prep);
    let dims = prep.grid.dims;
    prep.bricks
        .iter()
        .map(|&origin| {
            std::array::from_fn(|axis| {
                std::array::from_fn(|side| {
                    let o = origin + IVec3::AXES[axis] * BRICK_DIM * if side == 0 { -1 } else { 1 };
                    if o.cmplt(IVec3::ZERO).any() || o.cmpge(dims).any() {
                        return None;
                    }
                    let s = slot[brick_id(o)];
                    (s != u32::MAX).then_some(s)
                })
            })
        })
        .collect()
}

/// The sum over the (2r+1)^3 box about every voxel (r at most a brick), separably, in place
/// (`tmp` is scratch of the same size); voxels of bricks that are not proposed count as
/// `fill`. Returns the box's voxel count.
fn box_sum(field: &mut Field, tmp: &mut Field, near: &[[[Option<u32>; 2]; 3]], r: i32, fill: f32) -> f32 {
    let r = r.clamp(0, BRICK_DIM) as usize;
    let fills = [fill; BRICK_VOXELS];
    for axis in 0..3 {
        let src: &Field = field;
        tmp.par_iter_mut().enumerate().for_each(|(b, out)| {
            let side = |s: usize| near[b][axis][s].map_or(&fills, |n| &src[n as usize]);
            window_sums(&[side(0), &src[b], side(1)], axis, r, out);
        });
        std::mem::swap(field, tmp);
    }
    ((2 * r + 1) as f32).powi(3)
}

/// One brick's sums over the 2r+1 voxels along `axis` about each voxel, from the line of
/// three bricks (before, own, after) through it. Compiled for AVX-512 or AVX2 where the CPU
/// has them, as the splat passes are (cpu.rs): the slabs across the axis are 64 or 8 lanes
/// wide.
fn window_sums(line: &[&[f32; BRICK_VOXELS]; 3], axis: usize, r: usize, out: &mut [f32; BRICK_VOXELS]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has just been checked for AVX-512F.
        return unsafe { window_sums_avx512(line, axis, r, out) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has just been checked for AVX2.
        return unsafe { window_sums_avx2(line, axis, r, out) };
    }
    window_sums_impl(line, axis, r, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn window_sums_avx2(line: &[&[f32; BRICK_VOXELS]; 3], axis: usize, r: usize, out: &mut [f32; BRICK_VOXELS]) {
    window_sums_impl(line, axis, r, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn window_sums_avx512(line: &[&[f32; BRICK_VOXELS]; 3], axis: usize, r: usize, out: &mut [f32; BRICK_VOXELS]) {
    window_sums_impl(line, axis, r, out)
}

#[inline(always)]
fn window_sums_impl(line: &[&[f32; BRICK_VOXELS]; 3], axis: usize, r: usize, out: &mut [f32; BRICK_VOXELS]) {
    const D: usize = BRICK_DIM as usize;
    // brick_offset is x-major, z fastest: along `axis` a brick is `outer` blocks of D slabs
    // of `lanes` voxels; a running sum slides over whole slabs.
    let lanes = [D * D, D, 1][axis];
    let outer = BRICK_VOXELS / (D * lanes);
    // Slab t of the line (t in -D..2D, 0 the own brick's first) of block `block`.
    let slab = |t: isize, block: usize| -> &[f32] {
        let u = (t + D as isize) as usize;
        let at = block + (u % D) * lanes;
        &line[u / D][at..at + lanes]
    };
    let mut acc = [0.0f32; D * D];
    let acc = &mut acc[..lanes];
    for o in 0..outer {
        let block = o * D * lanes;
        acc.fill(0.0);
        for t in -(r as isize)..=(r as isize) {
            for (a, x) in acc.iter_mut().zip(slab(t, block)) {
                *a += x;
            }
        }
        out[block..block + lanes].copy_from_slice(acc);
        for t in 1..D as isize {
            let (enter, leave) = (slab(t + r as isize, block), slab(t - 1 - r as isize, block));
            for l in 0..lanes {
                acc[l] += enter[l] - leave[l];
            }
            let at = block + t as usize * lanes;
            out[at..at + lanes].copy_from_slice(acc);
        }
    }
}

/// Every brick's lengths (index units; 0 where no pass evaluates a voxel) from its ladder
/// `sums` (None: not reached anywhere) at the rungs `h` (index units, ascending) with noise
/// allowance `gamma` (crate docs and the module's).
pub(crate) fn choose_lengths(prep: &Prepared, h: &[f32], sums: &[Option<Box<RungSums>>], gamma: f32) -> Vec<Option<Lengths>> {
    let rungs = h.len();
    let near = neighbours(prep);
    let bricks = sums.len();
    let reached = |b: usize, v: usize| sums[b].as_ref().is_some_and(|s| s.reached[v]);
    let g2 = gamma * gamma;
    let top = (rungs - 1) as f32;
    // The rung of least estimated error so far, and that error; rung 0 has no bias estimate.
    let mut chosen: Field = vec![[0.0; BRICK_VOXELS]; bricks];
    let mut least: Field = sums.iter().map(|s| s.as_ref().map_or([0.0; BRICK_VOXELS], |s| std::array::from_fn(|v| g2 * s.var[0][v]))).collect();
    let (mut work, mut tmp, mut bias2): (Field, Field, Field) = (vec![[0.0; BRICK_VOXELS]; bricks], vec![[0.0; BRICK_VOXELS]; bricks], vec![[0.0; BRICK_VOXELS]; bricks]);
    for k in 1..rungs {
        bias2.par_iter_mut().for_each(|b| b.fill(0.0));
        let shorter: &[usize] = if k >= 2 { &[k - 1, 0] } else { &[0] };
        for &j in shorter {
            let noise = ici_pair_noise(h[k] / h[j]);
            let (hk2, hj2) = (h[k] * h[k], h[j] * h[j]);
            let extrapolate = (hk2 / (hk2 - hj2)).powi(2);
            work.par_iter_mut().zip(sums).for_each(|(w, s)| match s {
                Some(s) => {
                    for v in 0..BRICK_VOXELS {
                        let d = s.rho[k][v] - s.rho[j][v];
                        w[v] = d * d - noise * s.var[j][v];
                    }
                }
                None => w.fill(0.0),
            });
            let radius = ((BIAS_BOX * h[k]).round() as i32).max(1);
            let scale = extrapolate / box_sum(&mut work, &mut tmp, &near, radius, 0.0);
            bias2.par_iter_mut().zip(&work).for_each(|(b, m)| {
                for v in 0..BRICK_VOXELS {
                    b[v] = b[v].max(m[v].max(0.0) * scale);
                }
            });
        }
        chosen.par_iter_mut().zip(&mut least).zip(&bias2).enumerate().for_each(|(b, ((c, l), b2))| {
            let Some(s) = &sums[b] else { return };
            for v in 0..BRICK_VOXELS {
                let error = b2[v] + g2 * s.var[k][v];
                // On a tie the longer rung: the same estimated error with more particles.
                if error <= l[v] {
                    c[v] = k as f32;
                    l[v] = error;
                }
            }
        });
    }
    // Voxels nothing reaches hold the top rung: a rim voxel's sparse side widens it.
    for (b, c) in chosen.iter_mut().enumerate() {
        for v in 0..BRICK_VOXELS {
            if !reached(b, v) {
                c[v] = top;
            }
        }
    }
    let count = box_sum(&mut chosen, &mut tmp, &near, CHOICE_BOX, top);
    let ln_ratio: Vec<f32> = h.windows(2).map(|w| (w[1] / w[0]).ln()).collect();
    chosen
        .par_iter()
        .enumerate()
        .map(|(b, f)| {
            let s = sums[b].as_ref()?;
            Some(Box::new(std::array::from_fn(|v| {
                if !s.reached[v] {
                    return 0.0;
                }
                let f = (f[v] / count).clamp(0.0, top);
                let k = (f.floor() as usize).min(rungs.saturating_sub(2));
                if rungs == 1 {
                    return h[0];
                }
                let u = f - k as f32;
                h[k] * (ln_ratio[k] * u).exp()
            })))
        })
        .collect()
}
