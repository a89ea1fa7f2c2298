//! A grid of upper bounds on a scalar volume's interpolated value, and the 3D DDA that walks
//! it along a ray. Cells whose bound is zero are empty space a ray can step over; the bound is
//! the majorant that delta and ratio tracking sample free paths against.
//!
//! Why two cell sizes: a brick is only storage granularity, and a brick-sized bound is as
//! loose as the brick's one densest voxel. Delta tracking pays majorant x distance in null
//! collisions, so a photon crossing the empty part of a brick holding one voxel of density 1e9
//! took ~1e8 of them; [`MajorantGrid::for_tracking`] therefore refines the cells of optically
//! huge media, down to one voxel. Finer cells cost a DDA step each (which the GPU's
//! software-adapter guard counts) and memory (one f32 per cell of the data's bounding box,
//! uploaded whole to the GPU, hence `MAX_CELLS`); on ordinary media they cost more than they
//! save (two-voxel cells made photon tracing 1.4-1.6x slower on the bench scenes and the
//! march 6-9% faster), so skipping and ordinary tracking keep brick cells.
//!
//! Why each bound is the maximum over a cell's voxels plus one layer: trilinear sampling at p
//! reads the voxels floor(p) and floor(p)+1 per axis, so positions in the cell [c*s, c*s+s)
//! read voxel indices [c*s, c*s+s] per axis; the cell's bound is the maximum of those (and of
//! the background wherever they are not stored), and nothing looser, so cells just outside
//! the data's support get the background (zero for density) and are skipped.

use glam::{DVec3, IVec3};
use rayon::prelude::*;

use crate::{brick_local, Volume, BRICK_LOG2, BRICK_VOXELS};

/// Upper bounds of `Volume<f32>::sample_index` over cubic cells of `1 << cell_log2` voxels.
#[derive(Clone, Debug)]
pub struct MajorantGrid {
    cell_log2: u32,
    /// Index coordinate of the lowest corner of cell (0,0,0).
    origin: IVec3,
    dims: IVec3,
    values: Vec<f32>,
    /// Bound outside the grid: the volume's background.
    outside: f32,
}

/// One piece of a ray, `t_start..t_end` in the ray's parameter, with the bound over it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MajorantSegment {
    pub t_start: f64,
    pub t_end: f64,
    pub majorant: f32,
}

/// Most cells a grid may hold before its cells grow: 16 MiB of bounds, the size of a dense
/// 160^3 f32 volume, well inside every GPU's storage-binding limit (128 MiB by default), and
/// enough for one-voxel cells up to about 160^3 voxels of bounding box and two-voxel cells up
/// to 320^3 (the Cloud1-class bench scene, 340 x 40 x 360 voxels, gets two-voxel cells).
const MAX_CELLS: i64 = 1 << 22;

/// Most mean free paths one tracking cell may span at the volume's peak before
/// [`MajorantGrid::for_tracking`] refines the cells: a ray through the empty part of such a cell
/// costs at most about this many null collisions.
pub const MAX_CELL_OPTICAL_DEPTH: f64 = 64.0;

/// log2 of the tracking majorant's cell edge in voxels before refinement
/// ([`MajorantGrid::for_tracking`]).
pub const TRACKING_CELL_LOG2: u32 = 2;

/// Relative headroom on positive bounds. `sample_index` lerps in f32, and a lerp between
/// non-negative values can round one ulp above its larger end (at an exact rounding tie), so
/// three nested lerps can exceed the largest corner by a few ulps; 8 epsilon covers that and
/// leaves zero bounds exactly zero.
const ROUNDING_HEADROOM: f32 = 8.0 * f32::EPSILON;

impl MajorantGrid {
    /// Brick-sized cells (8 voxels), grown by powers of two for very wide boxes: what empty-space
    /// skipping needs (the march, the cache's shadow rays) at the fewest DDA steps.
    pub fn build(volume: &Volume<f32>) -> MajorantGrid {
        Self::with_cell_log2(volume, BRICK_LOG2)
    }

    /// Cells for delta and ratio tracking with `sigma_t = extinction * density`: four voxels
    /// ([`TRACKING_CELL_LOG2`]), halved (down to one voxel) while a cell at the volume's peak
    /// would span more than [`MAX_CELL_OPTICAL_DEPTH`] mean free paths. Null collisions cost
    /// majorant x distance, so an optically huge cell makes every path through its empty part
    /// crawl (a brick with one voxel of density 1e9 took ~1e8 null collisions per crossing);
    /// finer cells cost a DDA step each. Four voxels is the measured balance, by a little:
    /// against brick cells, vdbcache's paths stage took 7% less wall time on the bundled cloud
    /// and plume (alternating pairs of runs; 0-3% less CPU time), photons 0-6% less;
    /// two-voxel cells traced photons 1.4-1.6x slower.
    pub fn for_tracking(volume: &Volume<f32>, extinction: f32) -> MajorantGrid {
        let peak = volume.peak() as f64;
        let edge = volume.transform().voxel_size().max_element();
        let depth = |log2: u32| peak * extinction.max(0.0) as f64 * edge * (1u32 << log2) as f64;
        let mut log2 = TRACKING_CELL_LOG2;
        while log2 > 0 && depth(log2) > MAX_CELL_OPTICAL_DEPTH {
            log2 -= 1;
        }
        Self::with_cell_log2(volume, log2)
    }

    /// Cells of at least `1 << min_cell_log2` voxels, grown like [`MajorantGrid::build`]'s.
    pub fn with_cell_log2(volume: &Volume<f32>, min_cell_log2: u32) -> MajorantGrid {
        let outside = volume.background();
        // Only voxels above the background raise a bound (every cell starts at the
        // background), so the grid spans just their bounding box, and only bricks holding
        // such voxels are visited again.
        let raised: Vec<(usize, IVec3, IVec3)> = volume
            .par_bricks()
            .enumerate()
            .filter_map(|(i, b)| {
                let mut range: Option<(IVec3, IVec3)> = None;
                for (offset, &value) in b.values.iter().enumerate() {
                    if value > outside {
                        let p = b.origin + brick_local(offset);
                        range = Some(range.map_or((p, p), |(l, h)| (l.min(p), h.max(p))));
                    }
                }
                range.map(|(l, h)| (i, l, h))
            })
            .collect();
        let Some((lo, hi)) = raised.iter().map(|&(_, l, h)| (l, h)).reduce(|a, b| (a.0.min(b.0), a.1.max(b.1))) else {
            return MajorantGrid { cell_log2: min_cell_log2, origin: IVec3::ZERO, dims: IVec3::ZERO, values: vec![], outside };
        };
        // A voxel v is read by interpolation at positions [v-1, v+1): the grid covers
        // positions [lo-1, hi+1), i.e. cells from the one holding lo-1 to the one holding hi.
        let lo = lo - 1;
        let mut cell_log2 = min_cell_log2;
        let (origin, dims) = loop {
            let origin = (lo >> cell_log2 as i32) << cell_log2 as i32;
            let dims = ((hi - origin) >> cell_log2 as i32) + 1;
            let cells = dims.x as i64 * dims.y as i64 * dims.z as i64;
            if cells <= MAX_CELLS {
                break (origin, dims);
            }
            cell_log2 += 1;
        };
        let log2 = cell_log2 as i32;
        let mut values = vec![outside; (dims.x * dims.y * dims.z) as usize];
        // In parallel over slabs of x planes of cells; each slab visits the bricks whose
        // voxels reach it and keeps the cells inside it.
        let plane = (dims.y * dims.z) as usize;
        let slab = (dims.x as usize).div_ceil(4 * rayon::current_num_threads()).max(1);
        values.par_chunks_mut(slab * plane).enumerate().for_each(|(n, chunk)| {
            let x_lo = (n * slab) as i32;
            let x_hi = x_lo + (chunk.len() / plane) as i32 - 1;
            for &(i, l, h) in &raised {
                if ((h.x - origin.x) >> log2) < x_lo || ((l.x - 1 - origin.x) >> log2) > x_hi {
                    continue;
                }
                let brick = volume.brick(i);
                debug_assert_eq!(brick.values.len(), BRICK_VOXELS);
                for (offset, &value) in brick.values.iter().enumerate().filter(|&(_, &v)| v > outside) {
                    // Voxel r (relative to the grid) lies in cell r >> log2 and, where it sits
                    // on that cell's lower face, is also the upper layer of the cell below.
                    let r = brick.origin + brick_local(offset) - origin;
                    let c1 = r >> log2;
                    let on_face = (r & IVec3::splat((1 << log2) - 1)).cmpeq(IVec3::ZERO);
                    let c0 = c1 - IVec3::new(on_face.test(0) as i32, on_face.test(1) as i32, on_face.test(2) as i32);
                    let (c0, c1) = (c0.max(IVec3::new(x_lo, 0, 0)), c1.min(IVec3::new(x_hi, dims.y - 1, dims.z - 1)));
                    for x in c0.x..=c1.x {
                        for y in c0.y..=c1.y {
                            let row = ((x - x_lo) * dims.y + y) as usize * dims.z as usize;
                            for z in c0.z..=c1.z {
                                let cell = &mut chunk[row + z as usize];
                                *cell = cell.max(value);
                            }
                        }
                    }
                }
            }
            for v in chunk.iter_mut() {
                if *v > 0.0 {
                    *v += *v * ROUNDING_HEADROOM;
                }
            }
        });
        MajorantGrid { cell_log2, origin, dims, values, outside }
    }

    /// The grid grown by `radius` voxels per axis: each cell bounds every position within
    /// `radius` of it (the box grows to match), for callers that sample the volume at points
    /// displaced from the ray they walk (vdbmarch's offset noise).
    pub fn dilated(&self, radius: DVec3) -> MajorantGrid {
        if self.values.is_empty() {
            return self.clone();
        }
        let s = self.cell_size() as f64;
        let pad = (radius.max(DVec3::ZERO) / s).ceil().as_ivec3();
        if pad == IVec3::ZERO {
            return self.clone();
        }
        let dims = self.dims + 2 * pad;
        let index = |c: IVec3| ((c.x * dims.y + c.y) * dims.z + c.z) as usize;
        let mut values = vec![self.outside; (dims.x * dims.y * dims.z) as usize];
        for x in 0..self.dims.x {
            for y in 0..self.dims.y {
                for z in 0..self.dims.z {
                    values[index(IVec3::new(x, y, z) + pad)] = self.values[((x * self.dims.y + y) * self.dims.z + z) as usize];
                }
            }
        }
        // A separable running maximum, one axis at a time.
        for axis in 0..3 {
            let r = pad[axis];
            if r == 0 {
                continue;
            }
            let before = values.clone();
            for x in 0..dims.x {
                for y in 0..dims.y {
                    for z in 0..dims.z {
                        let c = IVec3::new(x, y, z);
                        let (lo, hi) = ((c[axis] - r).max(0), (c[axis] + r).min(dims[axis] - 1));
                        let mut m = before[index(c)];
                        for k in lo..=hi {
                            let mut n = c;
                            n[axis] = k;
                            m = m.max(before[index(n)]);
                        }
                        values[index(c)] = m;
                    }
                }
            }
        }
        MajorantGrid { cell_log2: self.cell_log2, origin: self.origin - pad * self.cell_size(), dims, values, outside: self.outside }
    }

    pub fn cell_size(&self) -> i32 {
        1 << self.cell_log2
    }

    pub fn cell_log2(&self) -> u32 {
        self.cell_log2
    }

    pub fn origin(&self) -> IVec3 {
        self.origin
    }

    pub fn dims(&self) -> IVec3 {
        self.dims
    }

    /// Bounds in x-major, z-fastest order (the order the GPU backends upload).
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// The index-space lowest corner of the cell whose bound is `values()[i]`.
    pub fn cell_lo(&self, i: usize) -> IVec3 {
        let (ny, nz) = (self.dims.y as usize, self.dims.z as usize);
        let c = IVec3::new((i / (ny * nz)) as i32, (i / nz % ny) as i32, (i % nz) as i32);
        self.origin + c * self.cell_size()
    }

    /// Each cell's index-space lowest corner and bound, in [`MajorantGrid::values`]' order.
    pub fn cells(&self) -> impl Iterator<Item = (IVec3, f32)> + '_ {
        self.values.iter().enumerate().map(|(i, &m)| (self.cell_lo(i), m))
    }

    /// The largest bound anywhere: a global majorant.
    pub fn max(&self) -> f32 {
        self.values.iter().copied().fold(self.outside, f32::max)
    }

    /// The bound at index-space position `p`.
    pub fn at(&self, p: DVec3) -> f32 {
        let c = ((p - self.origin.as_dvec3()) / self.cell_size() as f64).floor();
        if c.cmplt(DVec3::ZERO).any() || c.cmpge(self.dims.as_dvec3()).any() {
            return self.outside;
        }
        let c = c.as_ivec3();
        self.values[((c.x * self.dims.y + c.y) * self.dims.z + c.z) as usize]
    }

    /// The largest bound over cells overlapping the index-space box `[lo, hi]`: zero means
    /// nothing within the box can interpolate to a positive value.
    pub fn max_in_box(&self, lo: DVec3, hi: DVec3) -> f32 {
        let size = self.cell_size() as f64;
        let to_cell = |p: DVec3| ((p - self.origin.as_dvec3()) / size).floor();
        let (c0, c1) = (to_cell(lo), to_cell(hi));
        let mut m = if c0.cmplt(DVec3::ZERO).any() || c1.cmpge(self.dims.as_dvec3()).any() { self.outside } else { f32::MIN };
        let c0 = c0.max(DVec3::ZERO).as_ivec3();
        let c1 = c1.min(self.dims.as_dvec3() - 1.0).as_ivec3();
        for x in c0.x..=c1.x {
            for y in c0.y..=c1.y {
                for z in c0.z..=c1.z {
                    m = m.max(self.values[((x * self.dims.y + y) * self.dims.z + z) as usize]);
                }
            }
        }
        m.max(self.outside)
    }

    /// Walks the ray `origin + t * dir` (both in index space; t is then the same parameter as
    /// for the world-space ray, the map being affine) over `t_min..t_max`. The segments cover
    /// the interval completely and in order; callers skip those whose majorant is zero.
    pub fn walk(&self, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> MajorantWalk<'_> {
        let scale = 1.0 / self.cell_size() as f64;
        let q0 = (origin - self.origin.as_dvec3()) * scale;
        let dq = dir * scale;
        // Slab clip against the grid box [0, dims] in cell units.
        let inv = dq.recip();
        let (mut ta, mut tb) = (t_min, t_max);
        for a in 0..3 {
            if dq[a] == 0.0 {
                if q0[a] < 0.0 || q0[a] >= self.dims[a] as f64 {
                    ta = f64::INFINITY;
                }
            } else {
                let t0 = (0.0 - q0[a]) * inv[a];
                let t1 = (self.dims[a] as f64 - q0[a]) * inv[a];
                ta = ta.max(t0.min(t1));
                tb = tb.min(t0.max(t1));
            }
        }
        let mut walk = MajorantWalk {
            grid: self,
            t: t_min,
            t_max,
            inside_until: f64::NEG_INFINITY,
            cell: IVec3::ZERO,
            step: IVec3::ZERO,
            t_next: DVec3::INFINITY,
            t_delta: DVec3::INFINITY,
            pending_inside_from: f64::INFINITY,
        };
        if ta < tb && self.dims.min_element() > 0 {
            // At the entry point the ray sits on the grid's boundary: clamping puts it in the
            // first cell inside whichever face it came through.
            let cell = (q0 + dq * ta).floor().as_ivec3().clamp(IVec3::ZERO, self.dims - 1);
            let step = IVec3::new(sign(dq.x), sign(dq.y), sign(dq.z));
            let mut t_next = DVec3::INFINITY;
            let mut t_delta = DVec3::INFINITY;
            for a in 0..3 {
                if dq[a] != 0.0 {
                    let boundary = if dq[a] > 0.0 { cell[a] + 1 } else { cell[a] } as f64;
                    t_next[a] = (boundary - q0[a]) * inv[a];
                    t_delta[a] = inv[a].abs();
                }
            }
            walk.cell = cell;
            walk.step = step;
            walk.t_next = t_next;
            walk.t_delta = t_delta;
            walk.pending_inside_from = ta;
            walk.inside_until = tb;
        }
        walk
    }
}

fn sign(x: f64) -> i32 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// Iterator over the [`MajorantSegment`]s of a ray; see [`MajorantGrid::walk`].
#[derive(Clone, Debug)]
pub struct MajorantWalk<'a> {
    grid: &'a MajorantGrid,
    t: f64,
    t_max: f64,
    /// Where the ray enters the grid (infinite once entered or when it never does).
    pending_inside_from: f64,
    /// Where the ray leaves the grid.
    inside_until: f64,
    cell: IVec3,
    step: IVec3,
    t_next: DVec3,
    t_delta: DVec3,
}

impl Iterator for MajorantWalk<'_> {
    type Item = MajorantSegment;

    fn next(&mut self) -> Option<MajorantSegment> {
        while self.t < self.t_max {
            let t = self.t;
            // Before the grid: one segment of the outside bound up to the entry point.
            if t < self.pending_inside_from {
                let end = self.pending_inside_from.min(self.t_max);
                self.t = end;
                if end > t {
                    return Some(MajorantSegment { t_start: t, t_end: end, majorant: self.grid.outside });
                }
                continue;
            }
            self.pending_inside_from = f64::NEG_INFINITY;
            if t < self.inside_until {
                let axis = self.t_next.min_position();
                let end = self.t_next[axis].min(self.inside_until).min(self.t_max);
                let c = self.cell;
                let d = self.grid.dims;
                let majorant = if c.cmpge(IVec3::ZERO).all() && c.cmplt(d).all() {
                    self.grid.values[((c.x * d.y + c.y) * d.z + c.z) as usize]
                } else {
                    self.grid.outside
                };
                self.cell[axis] += self.step[axis];
                self.t_next[axis] += self.t_delta[axis];
                self.t = end.max(t);
                if end > t {
                    return Some(MajorantSegment { t_start: t, t_end: end, majorant });
                }
                continue;
            }
            // After the grid.
            self.t = self.t_max;
            return Some(MajorantSegment { t_start: t, t_end: self.t_max, majorant: self.grid.outside });
        }
        None
    }
}
