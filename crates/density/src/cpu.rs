//! The CPU backend: bricks in parallel (rayon), each brick's passes done by splatting.
//!
//! Per brick, the particles whose support reaches it are gathered once from the cells. Each
//! pass of the method then visits, for every such particle, the brick's z columns within the
//! square about it that bounds its support (the paper's rectangle drawing, on the CPU): pass
//! cost is the (particle, voxel) pairs within those squares, with no wasted distance tests on
//! a 27-cell neighbourhood. Later passes use the largest radius any voxel of the brick needs,
//! so they get cheaper as the adaptive lengths shrink in dense regions.
//!
//! conserve-mass splits a brick's visit in three (see [`estimate_bricks`]): the method's
//! passes with their lengths kept, the S pass ([`splat_weights`], a density pass without
//! masses that sums per particle instead of per voxel), and the density pass on the kept
//! lengths; each re-gathers the brick's particles rather than keeping them between stages.
//!
//! The density pass on AVX-512 takes two neighbouring z columns (16 voxels, contiguous) per
//! step: a support ~5 voxels across reaches most of both, so it takes ~0.57x the steps of
//! single columns (-20% CPU for usl on the Cloud1-class scene). The counting passes keep
//! single columns: their smaller adaptive radii leave more of a pair empty, and paired they
//! measured slower (again: asl3's passes took 1.7x as long, the 16-lane count loop no longer
//! compiling to a vector compare).
//!
//! Coordinates: particle positions are f32 in grid index space, and offsets are formed as
//! `(voxel index as f32) - p`, exactly as the brute-force reference in tests/ forms them, so counts agree
//! bit for bit and densities to summation order.

use glam::{IVec3, Vec3};
use nimbus_volume::{brick_local, brick_offset, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

use crate::ici::{Lengths, RungSums};
use crate::kernel::{clamp_h, correct_h, ici_ladder, m4_shape, predict_h1, ICI_MAX_RUNGS, KAPPA};
use crate::params::Method;
use crate::setup::Prepared;
use crate::{BrickResult, Keep, PointParams};

/// Reused per-thread buffers.
struct Scratch {
    /// (index-space position, mass) of the particles whose support reaches the brick.
    parts: Vec<(Vec3, f32)>,
    /// Their indices in `Prepared` order (the conserve-mass sums are per particle).
    index: Vec<u32>,
    count: [u32; BRICK_VOXELS],
    /// Per-voxel squared support radius of the pass being run (0 = skip the voxel).
    radius2: [f32; BRICK_VOXELS],
    /// knn: squared distances of each voxel's candidates.
    lists: Vec<Vec<f32>>,
    /// ici: per rung, sum m W and sum (m W)^2; the count within the top rung.
    ladder: Box<Ladder>,
}

/// ici's per-rung sums over a brick ([`splat_ladder`]).
struct Ladder {
    sums: [[f32; BRICK_VOXELS]; ICI_MAX_RUNGS],
    squares: [[f32; BRICK_VOXELS]; ICI_MAX_RUNGS],
    /// Particles within the top rung (h0): whether a voxel is reached, as n0 > 0 is for the
    /// other methods.
    top_count: [u32; BRICK_VOXELS],
}

impl Scratch {
    fn new() -> Scratch {
        Scratch {
            parts: Vec::new(),
            index: Vec::new(),
            count: [0; BRICK_VOXELS],
            radius2: [0.0; BRICK_VOXELS],
            lists: Vec::new(),
            ladder: Box::new(Ladder {
                sums: [[0.0; BRICK_VOXELS]; ICI_MAX_RUNGS],
                squares: [[0.0; BRICK_VOXELS]; ICI_MAX_RUNGS],
                top_count: [0; BRICK_VOXELS],
            }),
        }
    }
}

/// Runs the method over every proposed brick; bricks with no density are dropped.
///
/// With `conserve_mass` the lengths cannot feed the density pass at once: every particle's
/// kernel sum S_q needs the final h of every voxel its support reaches, in other bricks too.
/// So the bricks' lengths are kept, the S pass splats per brick into (particle, partial)
/// lists, the lists are summed per particle in brick order (fixed, so runs are
/// bit-identical), and the density pass then reads the kept lengths and the masses m / S.
pub(crate) fn estimate_bricks(prep: &Prepared, method: Method, conserve_mass: bool, pp: &PointParams, keep: &Keep) -> Vec<BrickResult> {
    let bricks = prep.bricks.len() as u64;
    let density = |masses: &[f32], lengths: Option<&[Option<Lengths>]>| -> Vec<BrickResult> {
        let task = nimbus_progress::task("density", bricks);
        prep.bricks
            .par_iter()
            .enumerate()
            .map_init(Scratch::new, |scratch, (i, &origin)| {
                task.advance(1);
                let known = match lengths {
                    Some(all) => Some(all[i].as_ref()?),
                    None => None,
                };
                let Visit::Sums((rho, h, used)) = brick(prep, method, pp, origin, scratch, Stage::Density(masses, known))? else { unreachable!() };
                keep.brick(i, origin, rho, h, used, pp)
            })
            .flatten()
            .collect()
    };
    // ici's neighbour rule reaches into the next brick: its lengths are all kept first.
    if !conserve_mass && method != Method::Ici {
        return density(&prep.masses, None);
    }
    let lengths: Vec<Option<Lengths>> = if method == Method::Ici {
        let (all, rungs) = ici_ladder(pp.h_min, pp.h0);
        let task = nimbus_progress::task("smoothing lengths", bricks);
        let sums: Vec<Option<Box<RungSums>>> = prep
            .bricks
            .par_iter()
            .inspect(|_| task.advance(1))
            .map_init(Scratch::new, |scratch, &origin| match brick(prep, method, pp, origin, scratch, Stage::Ladder(&all[..rungs]))? {
                Visit::Rungs(r) => Some(r),
                _ => unreachable!(),
            })
            .collect();
        crate::ici::choose_lengths(prep, &all[..rungs], &sums, pp.confidence)
    } else {
        let task = nimbus_progress::task("smoothing lengths", bricks);
        prep.bricks
            .par_iter()
            .inspect(|_| task.advance(1))
            .map_init(Scratch::new, |scratch, &origin| match brick(prep, method, pp, origin, scratch, Stage::Lengths)? {
                Visit::Lengths(h) => Some(h),
                _ => unreachable!(),
            })
            .collect()
    };
    if method == Method::Ici && !conserve_mass {
        return density(&prep.masses, Some(&lengths));
    }
    let task = nimbus_progress::task("mass weights", bricks);
    let partials: Vec<Vec<(u32, f32)>> = prep
        .bricks
        .par_iter()
        .inspect(|_| task.advance(1))
        .zip(&lengths)
        .map_init(Scratch::new, |scratch, (&origin, h)| match brick(prep, method, pp, origin, scratch, Stage::Weights(h.as_ref()?))? {
            Visit::Weights(list) => Some(list),
            _ => unreachable!(),
        })
        .map(Option::unwrap_or_default)
        .collect();
    let mut sums = vec![0.0f64; prep.positions.len()];
    for &(q, partial) in partials.iter().flatten() {
        sums[q as usize] += partial as f64;
    }
    drop(partials);
    drop(task);
    let masses = crate::normalised_masses(prep, pp, &sums);
    density(&masses, Some(&lengths))
}

/// A brick's raw sums: rho, h and used per voxel.
type Sums = (Box<[f32; BRICK_VOXELS]>, Box<[f32; BRICK_VOXELS]>, Box<[u32; BRICK_VOXELS]>);


/// What one visit of a brick does after gathering its particles.
#[derive(Clone, Copy)]
enum Stage<'a> {
    /// The method's passes, then the density with these masses (per particle, `Prepared`
    /// order), from the given lengths instead when they were kept.
    Density(&'a [f32], Option<&'a Lengths>),
    /// The method's passes only, their lengths kept (conserve-mass).
    Lengths,
    /// ici's ladder pass only, at these rungs (index units): every rung's sums, for the rule
    /// over the whole grid.
    Ladder(&'a [f32]),
    /// Each particle's kernel sum over the brick with the kept lengths (conserve-mass).
    Weights(&'a Lengths),
}

/// A visit's result, by [`Stage`].
enum Visit {
    Sums(Sums),
    Lengths(Lengths),
    Rungs(Box<RungSums>),
    /// (particle index, partial S) of the particles with a term in the brick.
    Weights(Vec<(u32, f32)>),
}

/// The voxels of a brick that lie inside the grid: local indices 0..n on each axis.
#[inline]
fn valid_extent(prep: &Prepared, origin: IVec3) -> IVec3 {
    (prep.grid.dims - origin).min(IVec3::splat(BRICK_DIM))
}

const ROW: usize = BRICK_DIM as usize;

/// Visits the (x, y) columns of the brick (valid part) within the square of half-width `r`
/// about `p` (global index space), `L / 8` neighbouring columns in y at a time, calling
/// `f(offset of (x, y, 0), dx^2 + dy^2 of each of those columns)`. The callers then treat the
/// whole z columns (8 voxels each, contiguous) at once, branch-free, testing each voxel's
/// squared distance against its own radius: that is what vectorises (L lanes), and the exact
/// per-voxel test means that rounding in these loop bounds (widened slightly) never drops a
/// voxel, and that a column past the support or the grid (radius 0) adds nothing.
///
/// A square, not the support's disc: the disc's rows each need a square root and a rounding,
/// and their varying lengths a branch the CPU mispredicts. The square's y range is the same
/// for every row of a visit, and on the Cloud1-class scene its extra, all-masked columns cost
/// far less than the disc's bookkeeping (usl passes 0.62 -> 0.42 s).
#[inline(always)]
fn for_columns_near<const L: usize>(p: Vec3, r: f32, origin: IVec3, n: IVec3, mut f: impl FnMut(usize, [f32; 2])) {
    const SLACK: f32 = 1e-3;
    let cols = (L / ROW) as i32;
    let local = p - origin.as_vec3();
    let x_lo = ((local.x - r - SLACK).ceil() as i32).max(0);
    let x_hi = ((local.x + r + SLACK).floor() as i32).min(n.x - 1);
    let y_lo = ((local.y - r - SLACK).ceil() as i32).max(0);
    let y_hi = ((local.y + r + SLACK).floor() as i32).min(n.y - 1);
    let y_lo = y_lo - y_lo % cols;
    // Up to y = ROW: single-column steps (cols = 1) still form the pair's second, unused sum.
    let dy2: [f32; ROW + 1] = std::array::from_fn(|i| {
        let dy = (origin.y + i as i32) as f32 - p.y;
        dy * dy
    });
    for x in x_lo..=x_hi {
        let dx = (origin.x + x) as f32 - p.x;
        let dx2 = dx * dx;
        let mut y = y_lo;
        while y <= y_hi {
            let dxy2: [f32; 2] = std::array::from_fn(|c| dx2 + dy2[(y + c as i32) as usize]);
            f(brick_offset(IVec3::new(x, y, 0)), dxy2);
            y += cols;
        }
    }
}

/// dz^2 for the brick's 8 z planes: the same for every column a particle touches (repeated
/// for each of the L / 8 columns of a step).
#[inline(always)]
fn dz2_column<const L: usize>(p: Vec3, origin: IVec3) -> [f32; L] {
    std::array::from_fn(|i| {
        let dz = (origin.z + (i % ROW) as i32) as f32 - p.z;
        dz * dz
    })
}

/// Each column's dx^2 + dy^2 on its 8 lanes.
#[inline(always)]
fn spread<const L: usize>(dxy2: [f32; 2]) -> [f32; L] {
    std::array::from_fn(|i| if i < ROW { dxy2[0] } else { dxy2[1] })
}

/// The L voxels from `row` on: L / 8 whole z columns, neighbours in y.
#[inline(always)]
fn column<T, const L: usize>(a: &[T; BRICK_VOXELS], row: usize) -> &[T; L] {
    a[row..row + L].try_into().unwrap()
}

#[inline(always)]
fn column_mut<T, const L: usize>(a: &mut [T; BRICK_VOXELS], row: usize) -> &mut [T; L] {
    (&mut a[row..row + L]).try_into().unwrap()
}

/// Gathers the particles whose support (radius r, index units) reaches the brick's voxels,
/// with their `masses` and their indices.
#[inline(always)]
fn gather(prep: &Prepared, masses: &[f32], origin: IVec3, n: IVec3, r: f32, out: &mut Vec<(Vec3, f32)>, index: &mut Vec<u32>) {
    out.clear();
    index.clear();
    let cells = &prep.cells;
    let lo = origin.as_vec3();
    let hi = (origin + n - 1).as_vec3();
    let c_lo = cells.cell_of(lo - r);
    let c_hi = cells.cell_of(hi + r);
    let r2 = r * r;
    for cz in c_lo.z..=c_hi.z {
        for cy in c_lo.y..=c_hi.y {
            for i in cells.row(c_lo.x, c_hi.x, cy, cz) {
                let p = prep.positions[i];
                // Distance from p to the brick's box of voxel points.
                let d = (lo - p).max(p - hi).max(Vec3::ZERO);
                if d.length_squared() < r2 {
                    out.push((p, masses[i]));
                    index.push(i as u32);
                }
            }
        }
    }
}

/// Counting pass: count[v] += particles with r^2 < radius2[v].
#[inline(always)]
fn splat_count<const L: usize>(parts: &[(Vec3, f32)], r_max: f32, radius2: &[f32; BRICK_VOXELS], origin: IVec3, n: IVec3, count: &mut [u32; BRICK_VOXELS]) {
    count.fill(0);
    for &(p, _) in parts {
        let dz2 = dz2_column::<L>(p, origin);
        for_columns_near::<L>(p, r_max, origin, n, |row, dxy2| {
            let (rad2, c) = (column::<_, L>(radius2, row), column_mut::<_, L>(count, row));
            let dxy2 = spread::<L>(dxy2);
            for i in 0..L {
                c[i] += (dxy2[i] + dz2[i] < rad2[i]) as u32;
            }
        });
    }
}

/// m4_shape(sqrt(r2) * inv_h) where r2 < rad2, else 0, and 1 or 0 for "inside": a bit mask
/// rather than a select, so the loops stay branch-free and vectorise.
#[inline(always)]
fn masked_shape(r2: f32, rad2: f32, inv_h: f32) -> (f32, u32) {
    let inside = ((r2 < rad2) as u32).wrapping_neg();
    let w = m4_shape(r2.sqrt() * inv_h);
    (f32::from_bits(w.to_bits() & inside), inside & 1)
}

/// Density pass: rho[v] += m * m4_shape(r / h[v]) and used[v] += 1 where r^2 < radius2[v].
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the pass's inputs and outputs, each a plain array
fn splat_density<const L: usize>(
    parts: &[(Vec3, f32)],
    r_max: f32,
    radius2: &[f32; BRICK_VOXELS],
    inv_h: &[f32; BRICK_VOXELS],
    origin: IVec3,
    n: IVec3,
    rho: &mut [f32; BRICK_VOXELS],
    used: &mut [u32; BRICK_VOXELS],
) {
    for &(p, m) in parts {
        let dz2 = dz2_column::<L>(p, origin);
        for_columns_near::<L>(p, r_max, origin, n, |row, dxy2| {
            let dxy2 = spread::<L>(dxy2);
            let (rad2, ih) = (column::<_, L>(radius2, row), column::<_, L>(inv_h, row));
            let (rho, used) = (column_mut::<_, L>(rho, row), column_mut::<_, L>(used, row));
            for i in 0..L {
                let (w, inside) = masked_shape(dxy2[i] + dz2[i], rad2[i], ih[i]);
                rho[i] += m * w;
                used[i] += inside;
            }
        });
    }
}

/// ici's ladder pass: for every rung k of `h` (ascending, index units), sums[k][v] += m
/// m4_shape(r / h_k) and squares[k][v] += that term squared where r < kappa*h_k, and
/// top_count[v] += 1 within the top rung. One visit of the widest rung's square per particle: the distance's square root
/// is shared by the rungs, and a column takes only the rungs whose support its nearest voxel
/// lies within (the narrow rungs' discs, not the widest square, bound their work).
///
/// Compiled per target as [`lengths`] is, and kept out of it: inlined there, its closure
/// stayed scalar (Cloud1-class: 6.8 s against usl's 0.5 s).
fn splat_ladder(parts: &[(Vec3, f32)], h: &[f32], origin: IVec3, n: IVec3, ladder: &mut Ladder) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has just been checked for AVX-512F.
        return unsafe { ladder_avx512(parts, h, origin, n, ladder) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has just been checked for AVX2.
        return unsafe { ladder_avx2(parts, h, origin, n, ladder) };
    }
    ladder_impl::<ROW>(parts, h, origin, n, ladder)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn ladder_avx2(parts: &[(Vec3, f32)], h: &[f32], origin: IVec3, n: IVec3, ladder: &mut Ladder) {
    ladder_impl::<ROW>(parts, h, origin, n, ladder)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn ladder_avx512(parts: &[(Vec3, f32)], h: &[f32], origin: IVec3, n: IVec3, ladder: &mut Ladder) {
    ladder_impl::<{ 2 * ROW }>(parts, h, origin, n, ladder)
}

#[inline(always)]
fn ladder_impl<const L: usize>(parts: &[(Vec3, f32)], h: &[f32], origin: IVec3, n: IVec3, ladder: &mut Ladder) {
    let rungs = h.len();
    for k in 0..rungs {
        ladder.sums[k].fill(0.0);
        ladder.squares[k].fill(0.0);
    }
    ladder.top_count.fill(0);
    let top = rungs - 1;
    let radius2: [f32; ICI_MAX_RUNGS] = std::array::from_fn(|k| if k < rungs { (KAPPA * h[k]) * (KAPPA * h[k]) } else { 0.0 });
    let inv_h: [f32; ICI_MAX_RUNGS] = std::array::from_fn(|k| if k < rungs { 1.0 / h[k] } else { 0.0 });
    let r_top = KAPPA * h[rungs - 1];
    for &(p, m) in parts {
        let dz2 = dz2_column::<L>(p, origin);
        // The column's nearest voxel to p: dz^2 is least at the plane nearest p.
        let dz2_min = dz2.iter().take(ROW).fold(f32::INFINITY, |a, &b| a.min(b));
        for_columns_near::<L>(p, r_top, origin, n, |row, dxy2| {
            let nearest = dxy2[0].min(if L > ROW { dxy2[1] } else { dxy2[0] }) + dz2_min;
            let dxy2 = spread::<L>(dxy2);
            let r2: [f32; L] = std::array::from_fn(|i| dxy2[i] + dz2[i]);
            let r: [f32; L] = std::array::from_fn(|i| r2[i].sqrt());
            for k in (0..rungs).rev() {
                if nearest >= radius2[k] {
                    break;
                }
                let (rad2, ih) = (radius2[k], inv_h[k]);
                let (l, at) = (&mut *ladder, row);
                let sums: &mut [f32; L] = (&mut l.sums[k][at..at + L]).try_into().unwrap();
                let squares: &mut [f32; L] = (&mut l.squares[k][at..at + L]).try_into().unwrap();
                for i in 0..L {
                    let inside = ((r2[i] < rad2) as u32).wrapping_neg();
                    let w = m * f32::from_bits(m4_shape(r[i] * ih).to_bits() & inside);
                    sums[i] += w;
                    squares[i] += w * w;
                }
                if k == top {
                    let counts: &mut [u32; L] = (&mut l.top_count[at..at + L]).try_into().unwrap();
                    for i in 0..L {
                        counts[i] += (r2[i] < rad2) as u32;
                    }
                }
            }
        });
    }
}

/// conserve-mass S pass: each particle's sum over the brick's voxels of the density pass's
/// terms without the mass, m4_shape(r / h[v]) * norm[v] (norm = 1 / (pi h^3), index units),
/// pushed as (particle index, partial) where it has any.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the pass's inputs and output, as splat_density's
fn splat_weights<const L: usize>(
    parts: &[(Vec3, f32)],
    index: &[u32],
    r_max: f32,
    radius2: &[f32; BRICK_VOXELS],
    inv_h: &[f32; BRICK_VOXELS],
    norm: &[f32; BRICK_VOXELS],
    origin: IVec3,
    n: IVec3,
    out: &mut Vec<(u32, f32)>,
) {
    for (&(p, _), &q) in parts.iter().zip(index) {
        let dz2 = dz2_column::<L>(p, origin);
        let mut acc = [0.0f32; L];
        for_columns_near::<L>(p, r_max, origin, n, |row, dxy2| {
            let dxy2 = spread::<L>(dxy2);
            let (rad2, ih, c) = (column::<_, L>(radius2, row), column::<_, L>(inv_h, row), column::<_, L>(norm, row));
            for i in 0..L {
                acc[i] += masked_shape(dxy2[i] + dz2[i], rad2[i], ih[i]).0 * c[i];
            }
        });
        let partial: f32 = acc.iter().sum();
        if partial > 0.0 {
            out.push((q, partial));
        }
    }
}

/// The per-brick work, compiled three times: for the baseline target, for AVX2, where each z
/// column of 8 voxels is a single vector op, and for AVX-512 (picked at run time). No FMA
/// contraction happens in any (Rust does not fuse), so all give bit-identical results.
fn brick(prep: &Prepared, method: Method, pp: &PointParams, origin: IVec3, s: &mut Scratch, stage: Stage) -> Option<Visit> {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has just been checked for AVX-512F.
        return unsafe { brick_avx512(prep, method, pp, origin, s, stage) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has just been checked for AVX2.
        return unsafe { brick_avx2(prep, method, pp, origin, s, stage) };
    }
    brick_impl::<ROW>(prep, method, pp, origin, s, stage)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn brick_avx2(prep: &Prepared, method: Method, pp: &PointParams, origin: IVec3, s: &mut Scratch, stage: Stage) -> Option<Visit> {
    brick_impl::<ROW>(prep, method, pp, origin, s, stage)
}

/// The density (and conserve-mass S) pass 16 lanes wide: two z columns, neighbours in y, per
/// step.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn brick_avx512(prep: &Prepared, method: Method, pp: &PointParams, origin: IVec3, s: &mut Scratch, stage: Stage) -> Option<Visit> {
    brick_impl::<{ 2 * ROW }>(prep, method, pp, origin, s, stage)
}

/// Gather, then the stage's passes: the method's (unless the lengths were kept), then the
/// density or the conserve-mass S pass.
#[inline(always)]
fn brick_impl<const L: usize>(prep: &Prepared, method: Method, pp: &PointParams, origin: IVec3, s: &mut Scratch, stage: Stage) -> Option<Visit> {
    let n = valid_extent(prep, origin);
    let masses = match stage {
        Stage::Density(masses, _) => masses,
        _ => &prep.masses,
    };
    gather(prep, masses, origin, n, KAPPA * pp.h0, &mut s.parts, &mut s.index);
    if s.parts.is_empty() {
        return None;
    }
    let (h, reached) = match stage {
        Stage::Ladder(rungs) => {
            splat_ladder(&s.parts, rungs, origin, n, &mut s.ladder);
            let l = &s.ladder;
            let reached = std::array::from_fn(|v| brick_local(v).cmplt(n).all() && l.top_count[v] > 0);
            let k = rungs.len();
            return Some(Visit::Rungs(RungSums::from_sums(rungs, &l.sums[..k], &l.squares[..k], reached)));
        }
        Stage::Density(_, Some(kept)) | Stage::Weights(kept) => {
            let reached: [bool; BRICK_VOXELS] = std::array::from_fn(|v| kept[v] > 0.0);
            (Box::new(std::array::from_fn(|v| if reached[v] { kept[v] } else { pp.h0 })), reached)
        }
        Stage::Density(_, None) | Stage::Lengths => lengths(method, pp, origin, n, s),
    };
    if matches!(stage, Stage::Lengths) {
        return Some(Visit::Lengths(Box::new(std::array::from_fn(|v| if reached[v] { h[v] } else { 0.0 }))));
    }

    // Final pass: the density (or S) with each voxel's h.
    let r_max = set_radii(&h, &reached, &mut s.radius2);
    let inv_h: [f32; BRICK_VOXELS] = std::array::from_fn(|v| 1.0 / h[v]);
    if matches!(stage, Stage::Weights(_)) {
        let norm: [f32; BRICK_VOXELS] = std::array::from_fn(|v| pp.index_norm(h[v]));
        let mut out = Vec::new();
        splat_weights::<L>(&s.parts, &s.index, r_max, &s.radius2, &inv_h, &norm, origin, n, &mut out);
        return Some(Visit::Weights(out));
    }
    let mut rho = Box::new([0.0f32; BRICK_VOXELS]);
    let mut used = Box::new([0u32; BRICK_VOXELS]);
    splat_density::<L>(&s.parts, r_max, &s.radius2, &inv_h, origin, n, &mut rho, &mut used);
    Some(Visit::Sums((rho, h, used)))
}

/// Attribute pass (design.md section 8, [`crate::attributes`]): per voxel of the brick, the
/// sums `sum_q values[q][c] * m4_shape(r / h[v])` of `channels` channels over the particles
/// within kappa*h[v], with each voxel's final length `h` (index units) from the density pass,
/// at the voxels where the density is positive (`reached`); `values` holds `channels` floats
/// per particle in [`Prepared`] order. One kernel evaluation per (particle, voxel) feeds
/// every channel. Sums in gather order within the brick: bit-identical between runs and
/// thread counts.
pub(crate) fn splat_attributes(prep: &Prepared, origin: IVec3, h: &[f32; BRICK_VOXELS], reached: &[bool; BRICK_VOXELS], values: &[f32], channels: usize) -> Vec<[f32; BRICK_VOXELS]> {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has just been checked for AVX-512F.
        return unsafe { attributes_avx512(prep, origin, h, reached, values, channels) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has just been checked for AVX2.
        return unsafe { attributes_avx2(prep, origin, h, reached, values, channels) };
    }
    attributes_impl::<ROW>(prep, origin, h, reached, values, channels)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn attributes_avx2(prep: &Prepared, origin: IVec3, h: &[f32; BRICK_VOXELS], reached: &[bool; BRICK_VOXELS], values: &[f32], channels: usize) -> Vec<[f32; BRICK_VOXELS]> {
    attributes_impl::<ROW>(prep, origin, h, reached, values, channels)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn attributes_avx512(prep: &Prepared, origin: IVec3, h: &[f32; BRICK_VOXELS], reached: &[bool; BRICK_VOXELS], values: &[f32], channels: usize) -> Vec<[f32; BRICK_VOXELS]> {
    attributes_impl::<{ 2 * ROW }>(prep, origin, h, reached, values, channels)
}

#[inline(always)]
fn attributes_impl<const L: usize>(prep: &Prepared, origin: IVec3, h: &[f32; BRICK_VOXELS], reached: &[bool; BRICK_VOXELS], values: &[f32], channels: usize) -> Vec<[f32; BRICK_VOXELS]> {
    let n = valid_extent(prep, origin);
    let mut radius2 = [0.0f32; BRICK_VOXELS];
    let r_max = set_radii(h, reached, &mut radius2);
    let mut sums = vec![[0.0f32; BRICK_VOXELS]; channels];
    if r_max <= 0.0 {
        return sums;
    }
    let (mut parts, mut index) = (Vec::new(), Vec::new());
    gather(prep, &prep.masses, origin, n, r_max, &mut parts, &mut index);
    let inv_h: [f32; BRICK_VOXELS] = std::array::from_fn(|v| 1.0 / h[v]);
    // One channel-major flat array: each channel's column is L contiguous floats, so the
    // update is one vector multiply-add per channel (nested per-channel arrays let the
    // compiler vectorise across channels instead, with scalar lanes: 4x slower at 8).
    let mut flat = vec![0.0f32; channels * BRICK_VOXELS];
    for (&(p, _), &q) in parts.iter().zip(&index) {
        let vals = &values[q as usize * channels..(q as usize + 1) * channels];
        // No weight in any attribute (no mass, or non-finite values): nothing to add.
        if vals.iter().all(|&x| x == 0.0) {
            continue;
        }
        let dz2 = dz2_column::<L>(p, origin);
        for_columns_near::<L>(p, r_max, origin, n, |row, dxy2| {
            let dxy2 = spread::<L>(dxy2);
            let (rad2, ih) = (column::<_, L>(&radius2, row), column::<_, L>(&inv_h, row));
            let w: [f32; L] = std::array::from_fn(|i| masked_shape(dxy2[i] + dz2[i], rad2[i], ih[i]).0);
            for (c, &value) in vals.iter().enumerate() {
                let at = c * BRICK_VOXELS + row;
                let sum: &mut [f32; L] = (&mut flat[at..at + L]).try_into().unwrap();
                for i in 0..L {
                    sum[i] += value * w[i];
                }
            }
        });
    }
    for (c, sum) in sums.iter_mut().enumerate() {
        sum.copy_from_slice(&flat[c * BRICK_VOXELS..(c + 1) * BRICK_VOXELS]);
    }
    sums
}

/// h per voxel (index units), and which voxels any pass evaluates.
type HReached = (Box<[f32; BRICK_VOXELS]>, [bool; BRICK_VOXELS]);

/// The method's passes over a gathered brick. A function of its own, compiled per target as
/// [`brick`] is: inlined into `brick_impl` with the stages' other passes, the counting loops'
/// closures stopped being inlined and ran unvectorised (plume, asl3: passes 0.36 -> 0.60 s).
fn lengths(method: Method, pp: &PointParams, origin: IVec3, n: IVec3, s: &mut Scratch) -> HReached {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has just been checked for AVX-512F.
        return unsafe { lengths_avx512(method, pp, origin, n, s) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has just been checked for AVX2.
        return unsafe { lengths_avx2(method, pp, origin, n, s) };
    }
    lengths_impl(method, pp, origin, n, s)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn lengths_avx2(method: Method, pp: &PointParams, origin: IVec3, n: IVec3, s: &mut Scratch) -> HReached {
    lengths_impl(method, pp, origin, n, s)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn lengths_avx512(method: Method, pp: &PointParams, origin: IVec3, n: IVec3, s: &mut Scratch) -> HReached {
    lengths_impl(method, pp, origin, n, s)
}

#[inline(always)]
fn lengths_impl(method: Method, pp: &PointParams, origin: IVec3, n: IVec3, s: &mut Scratch) -> HReached {
    let r0 = KAPPA * pp.h0;
    // Voxels outside the grid, and voxels with no particle within kappa*h0 (zero density),
    // get radius 0: no pass touches them, and they do not hold a later pass's radius at h0.
    let mut reached: [bool; BRICK_VOXELS] = std::array::from_fn(|v| brick_local(v).cmplt(n).all());
    let mut h = Box::new([pp.h0; BRICK_VOXELS]);

    match method {
        Method::Usl => {}
        Method::Asl2 | Method::Asl3 => {
            // Pass 1: N0 within kappa*h0.
            let r_max = set_radii(&h, &reached, &mut s.radius2);
            splat_count::<ROW>(&s.parts, r_max, &s.radius2, origin, n, &mut s.count);
            let n0 = s.count;
            for v in 0..BRICK_VOXELS {
                h[v] = predict_h1(n0[v], pp.n_star, pp.h0);
                reached[v] &= n0[v] > 0;
            }
            if method == Method::Asl3 {
                // Pass 2: N1 within each voxel's kappa*h1, then the corrector.
                let r_max = set_radii(&h, &reached, &mut s.radius2);
                splat_count::<ROW>(&s.parts, r_max, &s.radius2, origin, n, &mut s.count);
                for v in 0..BRICK_VOXELS {
                    h[v] = correct_h(n0[v], s.count[v], pp.n_star, pp.h0, h[v], pp.relax);
                }
            }
            for hv in h.iter_mut() {
                *hv = clamp_h(*hv, pp.h_min, pp.h0);
            }
        }
        Method::Knn => {
            // The N*-th nearest particle within kappa*h0 (beyond it h would exceed h0 and be
            // clamped to h0 anyway, so the bounded search is exact).
            s.lists.resize_with(BRICK_VOXELS, Vec::new);
            s.lists.iter_mut().for_each(Vec::clear);
            let r0_2 = r0 * r0;
            for &(p, _) in &s.parts {
                let dz2 = dz2_column::<ROW>(p, origin);
                for_columns_near::<ROW>(p, r0, origin, n, |row, dxy2| {
                    for (z, &dz2) in dz2.iter().enumerate().take(n.z as usize) {
                        let r2 = dxy2[0] + dz2;
                        if r2 < r0_2 {
                            s.lists[row + z].push(r2);
                        }
                    }
                });
            }
            let k = pp.n_star as usize;
            for v in 0..BRICK_VOXELS {
                reached[v] &= !s.lists[v].is_empty();
                h[v] = knn_h(&mut s.lists[v], k, pp);
            }
        }
        // Its lengths come from the whole grid's ladder (crate::ici), never a brick alone.
        Method::Ici => unreachable!("ici runs Stage::Ladder"),
    }
    (h, reached)
}

/// Squared support radii kappa*h per voxel (0 where no particle is within kappa*h0: nothing
/// to find there) and the largest radius, which bounds the splat.
#[inline(always)]
fn set_radii(h: &[f32; BRICK_VOXELS], reached: &[bool; BRICK_VOXELS], radius2: &mut [f32; BRICK_VOXELS]) -> f32 {
    let mut r_max = 0.0f32;
    for v in 0..BRICK_VOXELS {
        let r = if reached[v] { KAPPA * h[v] } else { 0.0 };
        radius2[v] = r * r;
        r_max = r_max.max(r);
    }
    r_max
}

/// knn smoothing length from a voxel's candidate squared distances (all within kappa*h0):
/// distance to the k-th nearest / kappa, h0 if fewer than k candidates, clamped.
pub(crate) fn knn_h(list: &mut [f32], k: usize, pp: &PointParams) -> f32 {
    if list.len() < k {
        return pp.h0;
    }
    let (_, kth, _) = list.select_nth_unstable_by(k - 1, f32::total_cmp);
    clamp_h(kth.sqrt() / KAPPA, pp.h_min, pp.h0)
}
