//! ici's rule (issue #21): from every rung's estimate and variance over the whole grid, each
//! voxel's smoothing length. One host function for both backends: the CPU's ladder pass and
//! the GPU's `ladder` entry produce the same [`RungSums`], and the lengths go to the density
//! pass.
//!
//! The error of rung k at a voxel is bias_k^2 + Gamma^2 var_k. Its bias is measured against
//! the shorter rungs j (the next shorter, and the shortest): the squared difference
//! (rho_k - rho_j)^2 less that difference's expected noise, averaged over a box about the
//! voxel of radius 0.75 h_k, extrapolated to the bias of rung k itself by the h^2 law of a
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

use crate::cpu::Lengths;
use crate::kernel::{ici_pair_noise, ici_scales, ICI_MAX_RUNGS};
use crate::Prepared;

/// The bias's averaging box, radius in units of the longer rung of a pair (voxels).
const BIAS_BOX: f32 = 0.75;
/// The rung choice's averaging box, radius in voxels.
const CHOICE_BOX: i32 = 2;

/// A brick's ladder: per rung, the estimate rho_k = sum m W_k and its variance, on the index
/// scale (1/pi dropped: it cancels); whether each voxel is reached (a particle within the top
/// rung; elsewhere nothing is evaluated and the estimates are 0).
pub(crate) struct RungSums {
    pub rho: [[f32; BRICK_VOXELS]; ICI_MAX_RUNGS],
    pub var: [[f32; BRICK_VOXELS]; ICI_MAX_RUNGS],
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
        let mut out = Box::new(RungSums { rho: [[0.0; BRICK_VOXELS]; ICI_MAX_RUNGS], var: [[0.0; BRICK_VOXELS]; ICI_MAX_RUNGS], reached });
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

/// The mean over the (2r+1)^3 box about every voxel (r at most a brick), separably; voxels
/// of bricks that are not proposed count as `fill`.
fn box_mean(field: &Field, near: &[[[Option<u32>; 2]; 3]], r: i32, fill: f32) -> Field {
    const D: usize = BRICK_DIM as usize;
    let r = r.clamp(0, BRICK_DIM) as usize;
    let mut cur = field.clone();
    let fills = [fill; BRICK_VOXELS];
    for axis in 0..3 {
        // brick_offset is x-major, z fastest.
        let stride = [D * D, D, 1][axis];
        let src = cur;
        cur = src
            .par_iter()
            .enumerate()
            .map(|(b, own)| {
                let side = |s: usize| near[b][axis][s].map_or(&fills, |n| &src[n as usize]);
                let (before, after) = (side(0), side(1));
                let mut out = [0.0f32; BRICK_VOXELS];
                for base in (0..BRICK_VOXELS).filter(|&v| (v / stride) % D == 0) {
                    // The line through the three bricks along `axis`, as prefix sums.
                    let mut prefix = [0.0f32; 3 * D + 1];
                    for t in 0..D {
                        let o = base + t * stride;
                        prefix[t + 1] = prefix[t] + before[o];
                    }
                    for t in 0..D {
                        let o = base + t * stride;
                        prefix[D + t + 1] = prefix[D + t] + own[o];
                    }
                    for t in 0..D {
                        let o = base + t * stride;
                        prefix[2 * D + t + 1] = prefix[2 * D + t] + after[o];
                    }
                    for t in 0..D {
                        out[base + t * stride] = prefix[D + t + r + 1] - prefix[D + t - r];
                    }
                }
                out
            })
            .collect();
    }
    let n = ((2 * r + 1) as f32).powi(3);
    cur.par_iter_mut().for_each(|b| b.iter_mut().for_each(|x| *x /= n));
    cur
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
    for k in 1..rungs {
        let mut bias2: Field = vec![[0.0; BRICK_VOXELS]; bricks];
        let shorter: &[usize] = if k >= 2 { &[k - 1, 0] } else { &[0] };
        for &j in shorter {
            let noise = ici_pair_noise(h[k] / h[j]);
            let (hk2, hj2) = (h[k] * h[k], h[j] * h[j]);
            let extrapolate = (hk2 / (hk2 - hj2)).powi(2);
            let raw: Field = sums
                .par_iter()
                .map(|s| match s {
                    Some(s) => std::array::from_fn(|v| {
                        let d = s.rho[k][v] - s.rho[j][v];
                        d * d - noise * s.var[j][v]
                    }),
                    None => [0.0; BRICK_VOXELS],
                })
                .collect();
            let radius = ((BIAS_BOX * h[k]).round() as i32).max(1);
            let mean = box_mean(&raw, &near, radius, 0.0);
            bias2.par_iter_mut().zip(&mean).for_each(|(b, m)| {
                for v in 0..BRICK_VOXELS {
                    b[v] = b[v].max(m[v].max(0.0) * extrapolate);
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
    let smooth = box_mean(&chosen, &near, CHOICE_BOX, top);
    smooth
        .par_iter()
        .enumerate()
        .map(|(b, f)| {
            let s = sums[b].as_ref()?;
            Some(Box::new(std::array::from_fn(|v| {
                if !s.reached[v] {
                    return 0.0;
                }
                let f = f[v].clamp(0.0, top);
                let k = (f.floor() as usize).min(rungs.saturating_sub(2));
                if rungs == 1 {
                    return h[0];
                }
                let u = f - k as f32;
                h[k] * (h[k + 1] / h[k]).powf(u)
            })))
        })
        .collect()
}
