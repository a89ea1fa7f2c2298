//! Everything before the per-grid-point work, shared by every backend: choosing h0, the grid,
//! binning the particles into cells (counting sort) and proposing the bricks near particles.
//!
//! The result, [`Prepared`], holds the particles in grid index space as f32 (rebased on the
//! grid, so a 1e6 world offset costs no precision), sorted by cell, ready to upload.

use std::f64::consts::PI;

use glam::{DVec3, IVec3, Vec3};
use nimbus_volume::{Transform, BRICK_DIM};
use rayon::prelude::*;

use crate::kernel::KAPPA;
use crate::params::{DensityParams, HMin, Resolution, H0};
use crate::{DensityError, ParticleSet};

/// Fraction of particles (by count) allowed to live in cells sparser than the density
/// `h0 auto` sizes for; see [`auto_h0`].
pub const AUTO_H0_PERCENTILE: f64 = 0.10;

/// The voxel lattice. Voxel footprints tile the bounds: voxel (i,j,k) covers
/// `low + [i, i+1) * voxel_size` on each axis, and its value sits at the footprint's centre,
/// index (0,0,0) at `low + voxel_size / 2` (as a Blender or Houdini user expects of a fog
/// volume whose bounds they gave).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    pub transform: Transform,
    /// World position of index (0,0,0).
    pub origin: DVec3,
    pub voxel_size: f64,
    /// Voxel counts; indices run over [0, dims).
    pub dims: IVec3,
    /// The bounds the voxels tile, world units.
    pub bounds: (DVec3, DVec3),
    /// Upper bound of the smoothing length (the uniform one for usl), world units.
    pub h0: f64,
    /// Floor of the smoothing length, world units (<= h0).
    pub h_min: f64,
}

impl Grid {
    /// A world position in index space, as f32 relative to the grid: the one conversion every
    /// backend and test uses, so they all see bit-identical particle coordinates.
    #[inline]
    pub fn to_index_f32(&self, p: DVec3) -> Vec3 {
        ((p - self.origin) / self.voxel_size).as_vec3()
    }

    pub fn voxel_count(&self) -> u64 {
        self.dims.as_i64vec3().element_product() as u64
    }
}

/// The uniform cells the particles are sorted into. Cell (cx,cy,cz) covers index-space
/// `origin + [c, c+1) * edge`; its particles are `start[id]..start[id+1]` with
/// id = (cz * dims.y + cy) * dims.x + cx (x fastest, so a row of cells is one range).
#[derive(Clone, Debug, PartialEq)]
pub struct CellGrid {
    pub origin: Vec3,
    pub edge: f32,
    pub dims: IVec3,
    pub start: Vec<u32>,
}

/// `v.floor().as_ivec3()` without libm: the baseline x86-64 target has no rounding
/// instruction, so `floor` is a library call, and binning and marking make millions of them.
/// Exact (the truncation is exact in f32 wherever it differs from floor), saturating like `as`.
#[inline]
pub(crate) fn floor_i(v: Vec3) -> IVec3 {
    let t = v.as_ivec3();
    IVec3::select(t.as_vec3().cmpgt(v), t.saturating_sub(IVec3::ONE), t)
}

/// `v.ceil().as_ivec3()` without libm, as [`floor_i`].
#[inline]
pub(crate) fn ceil_i(v: Vec3) -> IVec3 {
    let t = v.as_ivec3();
    IVec3::select(t.as_vec3().cmplt(v), t.saturating_add(IVec3::ONE), t)
}

/// Index of cell `c` in a dense table of `dims` cells, x fastest (the cells of a
/// [`CellGrid`], the bricks of a grid).
#[inline]
pub(crate) fn dense_index(c: IVec3, dims: IVec3) -> usize {
    ((c.z as usize * dims.y as usize) + c.y as usize) * dims.x as usize + c.x as usize
}

impl CellGrid {
    #[inline]
    pub fn cell_of(&self, p: Vec3) -> IVec3 {
        floor_i((p - self.origin) / self.edge).clamp(IVec3::ZERO, self.dims - 1)
    }

    #[inline]
    pub fn id(&self, c: IVec3) -> usize {
        dense_index(c, self.dims)
    }

    /// Particle index range of the cells cx_lo..=cx_hi in row (cy, cz).
    #[inline]
    pub fn row(&self, cx_lo: i32, cx_hi: i32, cy: i32, cz: i32) -> std::ops::Range<usize> {
        let a = self.id(IVec3::new(cx_lo, cy, cz));
        let b = self.id(IVec3::new(cx_hi, cy, cz));
        self.start[a] as usize..self.start[b + 1] as usize
    }
}

/// Everything a backend needs, in grid index space.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub grid: Grid,
    /// Particle positions in index space, sorted by cell.
    pub positions: Vec<Vec3>,
    /// Masses in the same order (the default mass filled in where the set has none).
    pub masses: Vec<f32>,
    /// Each particle's index in the [`ParticleSet`] it came from (its attributes' index).
    pub source: Vec<u32>,
    pub cells: CellGrid,
    /// Origins of the bricks holding a voxel within kappa*h0 of some particle, sorted.
    pub bricks: Vec<IVec3>,
    /// Particles skipped for a non-finite position or mass.
    pub skipped_nonfinite: u64,
    /// Particles too far outside explicit bounds to touch any voxel.
    pub outside: u64,
}

impl Prepared {
    /// kappa * h0 in voxels: the largest support radius any method uses.
    pub fn support_voxels(&self) -> f32 {
        (KAPPA as f64 * self.grid.h0 / self.grid.voxel_size) as f32
    }
}

/// `h0 auto`: the smoothing length at which a grid point in the sparser occupied regions still
/// finds N* particles within kappa*h0.
///
/// The rule: count particles in cubic cells of edge 2*kappa*h0 (the support's diameter);
/// the number density of a cell is count / edge^3; take n_p, the density below which only
/// [`AUTO_H0_PERCENTILE`] of the particles live (a particle-weighted low percentile, so a few
/// stray particles do not inflate h0); choose h0 with (4/3) pi (kappa h0)^3 n_p = N*.
/// The cell edge depends on h0, so this iterates from an estimate of the mean spacing.
/// h0 never exceeds the set's extent / kappa (a set smaller than N* cannot do better).
/// Returns `None` when the particles span no length (one point). The positions must be finite
/// (as [`plan_grid`] passes them).
pub fn auto_h0(positions: &[DVec3], n_star: u32) -> Option<f64> {
    let (lo, hi) = bounding_box(positions)?;
    let extent = (hi - lo).max_element();
    if extent <= 0.0 {
        return None;
    }
    let n = positions.len() as f64;
    let n_star = n_star as f64;
    let cap = extent / KAPPA as f64;
    if n <= n_star {
        return Some(cap);
    }
    // Start from cells that would hold ~N* particles if the set filled a cube of the extent.
    let mut edge = extent / (n / n_star).cbrt();
    let mut h0 = cap;
    let mut keys: Vec<u64> = Vec::new();
    for _ in 0..4 {
        // Keep cell coordinates within 21 bits per axis for the packed key.
        edge = edge.max(extent / 1.0e6);
        // (p - lo) >= 0, so truncation is the floor.
        let cell = |p: DVec3| ((p - lo) / edge).as_u64vec3();
        let dims = cell(hi) + 1;
        let mut counts: Vec<u64> = if dims.element_product() as f64 <= (4.0 * n).max(65536.0) {
            // Few enough cells for a table: a histogram instead of a sort. One thread: shared
            // atomic counters on so few cells made the threads contend for the same cache
            // lines (about 45 ms of CPU on the Cloud1-class scene, by perf; this takes a few).
            let mut table = vec![0u32; dims.element_product() as usize];
            for &p in positions {
                let c = cell(p);
                table[((c.z * dims.y + c.y) * dims.x + c.x) as usize] += 1;
            }
            table.into_iter().filter(|&c| c > 0).map(u64::from).collect()
        } else {
            positions
                .par_iter()
                .map(|&p| {
                    let c = cell(p);
                    (c.x << 42) | (c.y << 21) | c.z
                })
                .collect_into_vec(&mut keys);
            keys.par_sort_unstable();
            keys.chunk_by(|a, b| a == b).map(|run| run.len() as u64).collect()
        };
        counts.sort_unstable();
        let target = AUTO_H0_PERCENTILE * n;
        let mut cumulative = 0.0;
        let count_p = counts
            .iter()
            .find(|&&c| {
                cumulative += c as f64;
                cumulative >= target
            })
            .copied()
            .unwrap_or(1);
        let n_p = count_p as f64 / edge.powi(3);
        let previous = h0;
        h0 = ((3.0 * n_star / (4.0 * PI * n_p)).cbrt() / KAPPA as f64).min(cap);
        edge = 2.0 * KAPPA as f64 * h0;
        if (h0 - previous).abs() < 0.02 * previous {
            break;
        }
    }
    Some(h0)
}

fn bounding_box(positions: &[DVec3]) -> Option<(DVec3, DVec3)> {
    positions
        .iter()
        .filter(|p| p.is_finite())
        .fold(None, |acc, &p| Some(acc.map_or((p, p), |(a, b): (DVec3, DVec3)| (a.min(p), b.max(p)))))
}

/// Chooses h0, h_min and the grid (design.md section 8 and the rules on [`Grid`]).
pub fn plan_grid(particles: &ParticleSet, params: &DensityParams) -> Result<Grid, DensityError> {
    params.validate()?;
    let finite: Vec<DVec3>;
    let positions = if particles.positions.iter().all(|p| p.is_finite()) {
        &particles.positions[..]
    } else {
        finite = particles.positions.iter().copied().filter(|p| p.is_finite()).collect();
        &finite[..]
    };
    let (plo, phi) = bounding_box(positions).ok_or(DensityError::NoParticles)?;
    let kappa = KAPPA as f64;

    // h0 before the voxel size: padding the bounds by kappa*h0 comes first when the voxel
    // size follows from a voxel count.
    let auto = match params.h0 {
        H0::Fixed(h) => Some(h),
        H0::Auto => auto_h0(positions, params.neighbours),
    };
    let mut h0 = match (auto, params.resolution, params.h_min) {
        (Some(h), ..) => h,
        // One point and no scale: fall back to the one length the user gave.
        (None, Resolution::VoxelSize(v), h_min) => h_min.resolve(params.method, v),
        (None, _, HMin::World(h)) => h,
        (None, ..) => return Err(DensityError::H0Undetermined),
    };

    // Auto h0 is at least h_min; resolving that can change the voxel size (with a voxel
    // count), which changes the default h_min, so iterate to the fixed point (2 rounds do).
    let mut grid = None;
    for _ in 0..3 {
        let (lo, hi) = params.bounds.unwrap_or((plo - kappa * h0, phi + kappa * h0));
        let voxel = match params.resolution {
            Resolution::VoxelSize(v) => v,
            Resolution::Longest(n) => (hi - lo).max_element() / n as f64,
        };
        let h_min = params.h_min.resolve(params.method, voxel);
        grid = Some((lo, hi, voxel, h_min));
        if params.h0 == H0::Auto && h0 < h_min {
            h0 = h_min;
        } else {
            break;
        }
    }
    let (lo, hi, voxel, h_min) = grid.unwrap();
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(DensityError::InvalidParam {
            name: "resolution",
            value: format!("voxel size {voxel}"),
            why: "gives no positive voxel size for these bounds",
        });
    }
    // A voxel count of e.g. 4.0000001 from rounding is 4, not 5.
    let dims_f = ((hi - lo) / voxel - 1e-6).ceil().max(DVec3::ONE);
    if dims_f.max_element() > (i32::MAX / 2) as f64 || dims_f.element_product() > params.max_voxels as f64 {
        return Err(DensityError::TooManyVoxels { dims: dims_f.to_array(), max: params.max_voxels });
    }
    let dims = dims_f.as_ivec3();
    let origin = lo + 0.5 * voxel;
    Ok(Grid {
        transform: Transform::uniform(voxel, origin),
        origin,
        voxel_size: voxel,
        dims,
        bounds: (lo, hi),
        h0,
        h_min: h_min.min(h0),
    })
}

/// Grid set-up, binning and brick proposal: the backend-independent first stage.
pub fn prepare(particles: &ParticleSet, params: &DensityParams) -> Result<Prepared, DensityError> {
    let grid = plan_grid(particles, params)?;
    Ok(bin(particles, params.mass, grid))
}

/// Sorts the particles into cells by counting sort (O(N + cells)) and marks the bricks their
/// supports touch.
pub fn bin(particles: &ParticleSet, default_mass: f32, grid: Grid) -> Prepared {
    let support = (KAPPA as f64 * grid.h0 / grid.voxel_size) as f32;
    let dims = grid.dims;

    // Rebase to index space; keep particles whose support can reach a voxel.
    let lo_keep = Vec3::splat(-support - 1.0);
    let hi_keep = dims.as_vec3() + support;
    // One sequential pass: it is memory-bound, and the parallel form (a per-particle verdict,
    // then counts and an unzip) took 35 ms on 500k particles where this takes a few.
    let (mut positions, mut masses) = (Vec::with_capacity(particles.len()), Vec::with_capacity(particles.len()));
    let mut source = Vec::with_capacity(particles.len());
    let (mut skipped_nonfinite, mut outside) = (0u64, 0u64);
    for (i, &p) in particles.positions.iter().enumerate() {
        let m = particles.mass(i, default_mass);
        if !p.is_finite() || !m.is_finite() {
            skipped_nonfinite += 1;
            continue;
        }
        let q = grid.to_index_f32(p);
        if q.cmplt(lo_keep).any() || q.cmpgt(hi_keep).any() {
            outside += 1;
            continue;
        }
        positions.push(q);
        masses.push(m);
        source.push(i as u32);
    }

    // Cells are only used to gather each brick's candidate particles, so their edge follows
    // the support radius (a brick plus its margin spans a few cells) within 2..16 voxels, and
    // grows further if the cell table would dwarf the particle count.
    let span = hi_keep - lo_keep;
    let mut edge = support.clamp(2.0, 16.0);
    let budget = (4 * positions.len()).max(1 << 16) as f32;
    while (span / edge).ceil().element_product() > budget {
        edge *= 1.5;
    }
    let cell_dims = (span / edge).ceil().as_ivec3().max(IVec3::ONE);
    let mut cells = CellGrid { origin: lo_keep, edge, dims: cell_dims, start: Vec::new() };

    // Counting sort: histogram, exclusive prefix sum, scatter.
    let ids: Vec<u32> = positions.par_iter().map(|&p| cells.id(cells.cell_of(p)) as u32).collect();
    let ncells = cell_dims.as_i64vec3().element_product() as usize;
    let mut start = vec![0u32; ncells + 1];
    for &id in &ids {
        start[id as usize + 1] += 1;
    }
    for c in 0..ncells {
        start[c + 1] += start[c];
    }
    // The scatter writes indices only; positions and masses follow in parallel.
    let mut next = start.clone();
    let mut order = vec![0u32; positions.len()];
    for (i, &id) in ids.iter().enumerate() {
        let slot = &mut next[id as usize];
        order[*slot as usize] = i as u32;
        *slot += 1;
    }
    let sorted_pos: Vec<Vec3> = order.par_iter().map(|&i| positions[i as usize]).collect();
    let sorted_mass: Vec<f32> = order.par_iter().map(|&i| masses[i as usize]).collect();
    let sorted_source: Vec<u32> = order.par_iter().map(|&i| source[i as usize]).collect();
    cells.start = start;

    // Bricks touched by some particle's support box: a dense bit per brick of the grid.
    let brick_dims = (dims + (BRICK_DIM - 1)) / BRICK_DIM;
    // Sequential, skipping a particle whose brick range is its predecessor's: in cell order
    // that is most of them, and parallel marking made the two threads fight over cache lines.
    let mut marked = vec![false; brick_dims.as_i64vec3().element_product() as usize];
    let mut last = (IVec3::MAX, IVec3::MAX);
    for &p in &sorted_pos {
        let lo = ceil_i(p - support).max(IVec3::ZERO);
        let hi = floor_i(p + support).min(dims - 1);
        if lo.cmpgt(hi).any() {
            continue;
        }
        let (blo, bhi) = (lo / BRICK_DIM, hi / BRICK_DIM);
        if (blo, bhi) == last {
            continue;
        }
        last = (blo, bhi);
        for bz in blo.z..=bhi.z {
            for by in blo.y..=bhi.y {
                let row = dense_index(IVec3::new(0, by, bz), brick_dims);
                marked[row + blo.x as usize..=row + bhi.x as usize].fill(true);
            }
        }
    }
    let bricks = marked
        .into_iter()
        .enumerate()
        .filter(|&(_, m)| m)
        .map(|(i, _)| {
            let i = i as i32;
            let (bx, by, bz) = (i % brick_dims.x, (i / brick_dims.x) % brick_dims.y, i / (brick_dims.x * brick_dims.y));
            IVec3::new(bx, by, bz) * BRICK_DIM
        })
        .collect();

    Prepared {
        grid,
        positions: sorted_pos,
        masses: sorted_mass,
        source: sorted_source,
        cells,
        bricks,
        skipped_nonfinite,
        outside,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A floor in voxels follows the voxel size that a voxel count gives (which itself follows
    /// from h0 and so from the floor); a world floor is taken as it is.
    #[test]
    fn h_min_in_voxels_follows_the_grid() {
        let positions = (0..1000).map(|i| DVec3::new((i % 10) as f64, ((i / 10) % 10) as f64, (i / 100) as f64) * 0.3).collect();
        let particles = ParticleSet::new(positions);
        let plan = |h_min| plan_grid(&particles, &DensityParams { resolution: Resolution::Longest(20), h_min, ..Default::default() }).unwrap();
        let grid = plan(HMin::Voxels(1.5));
        assert!((grid.h_min / grid.voxel_size - 1.5).abs() < 1e-12, "{grid:?}");
        assert_eq!(plan(HMin::World(0.2)).h_min, 0.2);
        // The default floor is 0.75 voxel of the grid for ici (the default method, issue #21)
        // and 1.2 for the others (design.md section 8, issue #18).
        let default = plan(DensityParams::default().h_min);
        assert!((default.h_min / default.voxel_size - 0.75).abs() < 1e-12, "{default:?}");
        assert_eq!(plan(HMin::Voxels(0.75)), default);
        let asl3 = |h_min| plan_grid(&particles, &DensityParams { method: crate::Method::Asl3, resolution: Resolution::Longest(20), h_min, ..Default::default() }).unwrap();
        assert!((asl3(HMin::Auto).h_min / asl3(HMin::Auto).voxel_size - 1.2).abs() < 1e-12);
        assert_eq!(asl3(HMin::Voxels(1.2)), asl3(HMin::Auto));
    }
}
