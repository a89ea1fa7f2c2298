//! The march's own layout of the density and the illumination cache, built once per render
//! in O(voxels): what a march step reads, in the fewest loads.
//!
//! A [`Lattice`] stores a [`Point`] (a few f32 channels in SIMD registers) per lattice point
//! in bricks of 8^3 cells, each holding the 9^3 points its cells read (a one-point apron on
//! the upper faces), found through a dense table of brick slots over the bricks' bounding
//! box. A cell therefore never straddles bricks: a sample costs eight 16-byte loads (the
//! brick is found once per brick the ray crosses, by the layout's own DDA), where
//! [`Volume::sample_index`] costs a hash probe per grid (eight at brick borders, a third of
//! the cells).
//!
//! The density lattice also carries the cache, premultiplied by the albedo
//! ([`DensityPoint`]): one `Vec4` (albedo * (Li_single + Li_multiple), density) or, when
//! the single and multiple layers are kept apart, two (albedo * Li_single, density;
//! albedo * Li_multiple). A
//! cache grid whose lattice is the density's coarsened by a whole factor per axis on the
//! same lattice points (vdbcache's `--cache-scale`/`--multiple-scale` N: its points are every
//! N-th density point) is resampled onto the density lattice, and that is exact, not an
//! approximation: each density cell then lies inside one cache cell, the cache's trilinear
//! interpolant is multilinear over it, and trilinear interpolation of a multilinear function
//! from its eight corner values reproduces it. What changes is f32 rounding (the lerps
//! in another order). A cache grid on any other lattice keeps a [`Lattice`] of its own,
//! looked up at each sample as before.
//!
//! Only bricks whose 9^3 points hold positive density are stored in the density lattice:
//! elsewhere every sample interpolates to at most zero, takes no extinction, and reads no
//! cache. So the layout holds exactly what the march can read (it assumes a density
//! background <= 0, checked by [`MarchVolume::new`]).

use glam::{DAffine3, DVec3, IVec3, Vec3, Vec3A, Vec4};
use nimbus_cache::IlluminationCache;
use nimbus_volume::{Voxel, Volume, BRICK_DIM, BRICK_LOG2};
use rayon::prelude::*;
use std::sync::OnceLock;

use crate::simd::{Arith, EDGE};

pub(crate) const BRICK_VALUES: usize = EDGE * EDGE * EDGE;
const EMPTY: u32 = u32::MAX;
/// Offsets of a cell's +x, +y neighbours in a brick's points (z fastest).
const X: usize = EDGE * EDGE;
const Y: usize = EDGE;

/// What one lattice point holds: a few f32 channels in SIMD registers.
pub(crate) trait Point: bytemuck::Zeroable + Copy + Send + Sync + 'static {
    /// `a + (b - a) w`, per channel.
    fn lerp<A: Arith>(arith: A, a: Self, b: Self, w: f32) -> Self;
}

impl Point for Vec4 {
    #[inline(always)]
    fn lerp<A: Arith>(arith: A, a: Self, b: Self, w: f32) -> Self {
        arith.fma4(b - a, Vec4::splat(w), a)
    }
}

impl Point for [Vec4; 2] {
    #[inline(always)]
    fn lerp<A: Arith>(arith: A, a: Self, b: Self, w: f32) -> Self {
        [<Vec4 as Point>::lerp(arith, a[0], b[0], w), <Vec4 as Point>::lerp(arith, a[1], b[1], w)]
    }
}

/// Values of type `T` on a lattice (see the module doc).
pub(crate) struct Lattice<T: Point> {
    world_to_index: DAffine3,
    /// Brick coordinates (voxel index >> 3) of the table's first brick, and its extent.
    lo: IVec3,
    dims: IVec3,
    /// The cells the table covers, [cell_lo, cell_hi) in voxel index, for the range test.
    cell_lo: DVec3,
    cell_hi: DVec3,
    table: Vec<u32>,
    store: Store<T>,
    background: T,
}

/// A lattice's bricks: filled when it is built, or each when a march first reads it.
enum Store<T> {
    Filled {
        values: Vec<T>,
        /// Per slot, what a march needs to know of the brick before sampling it.
        visits: Vec<Visit>,
    },
    /// Per slot, the brick once filled (by the first thread to read it; the others wait),
    /// its voxel origin, and what fills it ([`Lattice::build_lazy`]).
    Lazy { bricks: Vec<OnceLock<(Visit, Box<[T]>)>>, origins: Vec<IVec3>, fill: Box<Fill<T>> },
}

/// What fills a brick: from its voxel origin, its 9^3 points, and what a march needs to know of it.
pub(crate) type Fill<T> = dyn Fn(IVec3, &mut [T]) -> Visit + Send + Sync;

/// What a march needs to know of a brick before sampling it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Visit {
    /// The cells to sample.
    pub cells: CellBox,
    /// For the density lattice, the bound [`MajorantGrid::build`] gives the brick's cell
    /// (the largest density among its 9^3 points, with the same rounding headroom): what
    /// the step is chosen from ([`crate::MarchParams::step_factor`]).
    ///
    /// [`MajorantGrid::build`]: nimbus_volume::MajorantGrid::build
    pub majorant: f32,
    /// Per cell (bit `x * 64 + y * 8 + z` of the eight words), whether it is one to sample
    /// (a corner of positive density): inside [`Visit::cells`]' box a medium can be sparse
    /// (the displaced medium's wisps left 41% of the plume's samples in the boxes reading
    /// zero density, 42% of the cloud's).
    pub occupied: [u64; 8],
}

/// The cell ([`Visit::occupied`]' bit) whose first corner is a brick's point `i` (x-major,
/// z fastest); a point on the brick's last plane starts no cell and maps to cell 0.
pub(crate) const CELL_OF_POINT: [u16; BRICK_VALUES] = {
    let mut table = [0u16; BRICK_VALUES];
    let mut i = 0;
    while i < BRICK_VALUES {
        let (x, y, z) = (i / (EDGE * EDGE), i / EDGE % EDGE, i % EDGE);
        if x < 8 && y < 8 && z < 8 {
            table[i] = (x * 64 + y * 8 + z) as u16;
        }
        i += 1;
    }
    table
};

impl Visit {
    /// Every cell sampled, no bound: a lattice a march reads but never walks (the offsets',
    /// a cache grid on a lattice of its own).
    pub(crate) const ALL: Visit = Visit { cells: CellBox::ALL, majorant: f32::INFINITY, occupied: [u64::MAX; 8] };

    /// The bound of a brick's points, as [`nimbus_volume::MajorantGrid`] rounds it: 8 ulps
    /// above the largest (a lerp can round a few ulps above its larger end).
    pub(crate) fn of(points: &[f32]) -> Visit {
        let max = points.iter().copied().fold(f32::MIN, f32::max);
        let majorant = if max > 0.0 { max + max * (8.0 * f32::EPSILON) } else { max };
        let rows = Rows::of(points, |v| v > 0.0);
        Visit { cells: CellBox::of(&rows), majorant, occupied: rows.occupied() }
    }
}

/// Per row of a brick's points (x, y), a bit per z where the point is kept: what
/// [`CellBox`] and [`Visit::occupied`] are found from.
struct Rows([[u16; EDGE]; EDGE]);

impl Rows {
    fn of<V: Copy>(points: &[V], keep: impl Fn(V) -> bool) -> Rows {
        let mut rows = [[0u16; EDGE]; EDGE];
        for (x, plane) in rows.iter_mut().enumerate() {
            for (y, bits) in plane.iter_mut().enumerate() {
                let row = &points[(x * EDGE + y) * EDGE..][..EDGE];
                *bits = row.iter().enumerate().fold(0u16, |b, (z, &v)| b | (keep(v) as u16) << z);
            }
        }
        Rows(rows)
    }

    /// [`Visit::occupied`]: cell (x, y, z) has a kept corner among points x..=x+1,
    /// y..=y+1, z..=z+1.
    fn occupied(&self) -> [u64; 8] {
        let r = &self.0;
        let mut mask = [0u64; 8];
        for (cx, m) in mask.iter_mut().enumerate() {
            for cy in 0..EDGE - 1 {
                let row = r[cx][cy] | r[cx + 1][cy] | r[cx][cy + 1] | r[cx + 1][cy + 1];
                *m |= (((row | row >> 1) & 0xff) as u64) << (cy * 8);
            }
        }
        mask
    }
}

/// The cells of a brick a march has to visit, `lo..hi` per axis (0..8 for all of them):
/// for the density lattice, those with a corner of positive density; elsewhere every
/// sample interpolates to at most zero and adds nothing. A fifth of the Cloud1-class
/// scene's samples fall in brick cells outside these boxes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CellBox {
    pub lo: [u8; 3],
    pub hi: [u8; 3],
}

impl CellBox {
    pub const ALL: CellBox = CellBox { lo: [0; 3], hi: [BRICK_DIM as u8; 3] };
    const NONE: CellBox = CellBox { lo: [BRICK_DIM as u8; 3], hi: [0; 3] };

    /// The cells with a corner among the brick's kept points.
    fn of(rows: &Rows) -> CellBox {
        // Per axis, a bit per plane of points holding a kept value.
        let mut planes = [0u16; 3];
        for (x, plane) in rows.0.iter().enumerate() {
            for (y, &zs) in plane.iter().enumerate() {
                planes[2] |= zs;
                planes[1] |= ((zs != 0) as u16) << y;
                planes[0] |= ((zs != 0) as u16) << x;
            }
        }
        let mut b = CellBox::NONE;
        for a in 0..3 {
            if planes[a] != 0 {
                // Point p is a corner of cells p - 1 and p (those inside the brick).
                let (first, last) = (planes[a].trailing_zeros() as u8, 15 - planes[a].leading_zeros() as u8);
                b.lo[a] = first.saturating_sub(1);
                b.hi[a] = (last + 1).min(BRICK_DIM as u8);
            }
        }
        b
    }
}

impl<T: Point> Lattice<T> {
    /// A lattice of the bricks at brick coordinates `bricks` (repeats allowed), each filled
    /// by `fill(voxel origin, its 9^3 points)`, in parallel; `background` everywhere else.
    pub(crate) fn build(world_to_index: DAffine3, bricks: &[IVec3], background: T, fill: impl Fn(IVec3, &mut [T]) -> Visit + Sync) -> Self {
        Self::with_table(world_to_index, bricks, background, |origins| {
            // Zeroed by the allocator (fresh pages come zeroed; the fill then touches them in
            // parallel): writing T::ZERO first cost a single-threaded pass over all of it.
            let mut values: Vec<T> = bytemuck::zeroed_vec(origins.len() * BRICK_VALUES);
            let visits = values.par_chunks_mut(BRICK_VALUES).zip(origins.par_iter()).map(|(v, &o)| fill(o, v)).collect();
            Store::Filled { values, visits }
        })
    }

    /// [`Lattice::build`] with each brick filled when a march first reads it: what only
    /// the bricks rays reach cost (a thick medium stops them within a few voxels).
    /// [`Lattice::values`] does not apply.
    pub(crate) fn build_lazy(world_to_index: DAffine3, bricks: &[IVec3], background: T, fill: Box<Fill<T>>) -> Self {
        Self::with_table(world_to_index, bricks, background, |origins| Store::Lazy { bricks: origins.iter().map(|_| OnceLock::new()).collect(), origins, fill })
    }

    /// The table of the bricks at brick coordinates `bricks` (repeats allowed), their
    /// slots in table order, and `store` of their voxel origins in slot order.
    fn with_table(world_to_index: DAffine3, bricks: &[IVec3], background: T, store: impl FnOnce(Vec<IVec3>) -> Store<T>) -> Self {
        let (lo, hi) = bricks.iter().fold((IVec3::MAX, IVec3::MIN), |(l, h), &b| (l.min(b), h.max(b)));
        let dims = if bricks.is_empty() { IVec3::ZERO } else { hi - lo + 1 };
        let index = |b: IVec3| (((b.x - lo.x) * dims.y + (b.y - lo.y)) * dims.z + (b.z - lo.z)) as usize;
        let mut table = vec![EMPTY; (dims.x as usize) * (dims.y as usize) * (dims.z as usize)];
        for &b in bricks {
            table[index(b)] = 0;
        }
        // Slots in table order, so neighbouring bricks sit near each other in memory.
        let mut origins = Vec::new();
        for (i, slot) in table.iter_mut().enumerate() {
            if *slot != EMPTY {
                *slot = origins.len() as u32;
                let (yz, z) = (i / dims.z as usize, i % dims.z as usize);
                let b = lo + IVec3::new((yz / dims.y as usize) as i32, (yz % dims.y as usize) as i32, z as i32);
                origins.push(b << BRICK_LOG2);
            }
        }
        let cell_lo = (lo << BRICK_LOG2).as_dvec3();
        Lattice { world_to_index, lo, dims, cell_lo, cell_hi: cell_lo + (dims << BRICK_LOG2).as_dvec3(), table, store: store(origins), background }
    }

    /// What a march needs to know of the brick in `slot`, and its points (filled now if
    /// the lattice is lazy and nothing read them before).
    #[inline(always)]
    fn slot(&self, slot: u32) -> (Visit, &[T]) {
        let slot = slot as usize;
        match &self.store {
            Store::Filled { values, visits } => (visits[slot], &values[slot * BRICK_VALUES..(slot + 1) * BRICK_VALUES]),
            Store::Lazy { bricks, origins, fill } => {
                let (visit, points) = bricks[slot].get_or_init(|| {
                    let mut points: Box<[T]> = bytemuck::zeroed_slice_box(BRICK_VALUES);
                    (fill(origins[slot], &mut points), points)
                });
                (*visit, points)
            }
        }
    }

    pub fn world_to_index(&self) -> &DAffine3 {
        &self.world_to_index
    }

    /// Every stored brick's points, brick after brick in slot order ([`Lattice::brick`]).
    pub fn values(&self) -> &[T] {
        match &self.store {
            Store::Filled { values, .. } => values,
            Store::Lazy { .. } => panic!("a lazy lattice's values are filled as the march reads them"),
        }
    }

    /// The value everywhere outside the stored bricks.
    pub fn background(&self) -> T {
        self.background
    }

    /// Every stored brick's voxel origin and what a march needs to know of it.
    pub fn bricks(&self) -> impl Iterator<Item = (IVec3, Visit)> + '_ {
        self.table.iter().enumerate().filter(|(_, &slot)| slot != EMPTY).map(|(i, &slot)| {
            let (yz, z) = (i / self.dims.z as usize, i % self.dims.z as usize);
            let b = self.lo + IVec3::new((yz / self.dims.y as usize) as i32, (yz % self.dims.y as usize) as i32, z as i32);
            (b << BRICK_LOG2, self.slot(slot).0)
        })
    }

    /// The brick table (slots, [`EMPTY`] where no brick is stored; x-major, z fastest) and
    /// its first brick coordinate and extent: what the GPU reads the lattice by.
    pub fn table(&self) -> (&[u32], IVec3, IVec3) {
        (&self.table, self.lo, self.dims)
    }

    /// Trilinear interpolation at index-space point `p`, in the order of
    /// [`Volume::sample_index`] (z, then y, then x), in f32.
    #[inline(always)]
    pub fn sample<A: Arith>(&self, arith: A, p: DVec3) -> T {
        let f = p.floor();
        // A non-finite point fails both tests.
        if !(f.cmpge(self.cell_lo).all() && f.cmplt(self.cell_hi).all()) {
            return self.background;
        }
        // SAFETY: finite and inside the table's cells, so within i32.
        let i = unsafe { IVec3::new(f.x.to_int_unchecked(), f.y.to_int_unchecked(), f.z.to_int_unchecked()) };
        let b = (i >> BRICK_LOG2 as i32) - self.lo;
        let slot = self.table[((b.x * self.dims.y + b.y) * self.dims.z + b.z) as usize];
        if slot == EMPTY {
            return self.background;
        }
        self.interpolate(arith, self.brick(slot), i & IVec3::splat(BRICK_DIM - 1), (p - f).as_vec3())
    }

    /// The points of the brick in `slot`.
    #[inline(always)]
    pub fn brick(&self, slot: u32) -> &[T] {
        self.slot(slot).1
    }

    /// Trilinear interpolation in cell `l` (0..8 per axis) of `brick` at fraction `w`.
    #[inline(always)]
    fn interpolate<A: Arith>(&self, arith: A, brick: &[T], l: IVec3, w: Vec3) -> T {
        Self::interpolate_at(arith, brick, (l.x as usize * EDGE + l.y as usize) * EDGE + l.z as usize, w.x, w.y, w.z)
    }

    /// Trilinear interpolation in the cell whose first corner is point `base` of `brick`
    /// (as [`crate::simd::Cells::index`] gives it), at fractions `wx, wy, wz`.
    #[inline(always)]
    pub fn interpolate_at<A: Arith>(arith: A, brick: &[T], base: usize, wx: f32, wy: f32, wz: f32) -> T {
        let v = &brick[base..base + X + Y + 2];
        let lerp = |a, b, w| T::lerp(arith, a, b, w);
        lerp(
            lerp(lerp(v[0], v[1], wz), lerp(v[Y], v[Y + 1], wz), wy),
            lerp(lerp(v[X], v[X + 1], wz), lerp(v[X + Y], v[X + Y + 1], wz), wy),
            wx,
        )
    }

    /// The bricks a ray `o + t d` (index space) crosses for `t >= t_min`, in order, as
    /// `(t_start, t_end, slot, brick origin)`, skipping empty table entries: a 3D DDA over
    /// the brick table, whose occupied bricks are exactly the cells where the density can
    /// interpolate above zero.
    #[inline(always)]
    pub fn bricks_along(&self, o: DVec3, d: DVec3, t_min: f64) -> BrickWalk<'_, T> {
        let scale = 1.0 / BRICK_DIM as f64;
        let q0 = (o - self.cell_lo) * scale;
        let dq = d * scale;
        let dims = self.dims.as_dvec3();
        let (mut ta, mut tb) = (t_min, f64::INFINITY);
        let mut inv = DVec3::ZERO;
        for a in 0..3 {
            if dq[a] == 0.0 {
                if !(q0[a] >= 0.0 && q0[a] < dims[a]) {
                    tb = f64::NEG_INFINITY;
                }
            } else {
                inv[a] = 1.0 / dq[a];
                let (t0, t1) = ((0.0 - q0[a]) * inv[a], (dims[a] - q0[a]) * inv[a]);
                ta = ta.max(t0.min(t1));
                tb = tb.min(t0.max(t1));
            }
        }
        let mut walk = BrickWalk {
            lattice: self,
            t: ta,
            t_end: tb,
            cell: [0; 3],
            index: 0,
            step: [0; 3],
            stride: [(self.dims.y * self.dims.z) as isize, self.dims.z as isize, 1],
            plane: [0.0; 3],
            q0: q0.to_array(),
            inv: inv.to_array(),
            next: [f64::INFINITY; 3],
        };
        if !(ta < tb) {
            walk.t_end = f64::NEG_INFINITY;
            return walk;
        }
        // At the entry point the ray sits on the table's boundary: clamping puts it in the
        // first brick inside whichever face it came through.
        let cell = (q0 + dq * ta).floor().clamp(DVec3::ZERO, dims - 1.0).as_ivec3();
        walk.cell = cell.to_array();
        walk.index = ((cell.x * self.dims.y + cell.y) * self.dims.z + cell.z) as isize;
        for a in 0..3 {
            if dq[a] != 0.0 {
                walk.step[a] = if dq[a] > 0.0 { 1 } else { -1 };
                walk.plane[a] = (cell[a] + (dq[a] > 0.0) as i32) as f64;
                walk.next[a] = (walk.plane[a] - q0[a]) * inv[a];
            }
        }
        walk
    }
}

/// A brick a ray crosses ([`Lattice::bricks_along`]).
pub(crate) struct BrickSpan<'a, T> {
    /// The ray's parameter over the brick, and over the box of its cells to visit (empty
    /// where `visit_start >= visit_end`): outside the box the density is at most zero.
    pub start: f64,
    pub end: f64,
    pub visit_start: f64,
    pub visit_end: f64,
    pub points: &'a [T],
    /// The brick's lowest corner, index space.
    pub origin: DVec3,
    /// Its density bound ([`Visit::majorant`]).
    pub majorant: f32,
    /// Its cells to sample ([`Visit::occupied`]).
    pub occupied: [u64; 8],
}

/// [`Lattice::bricks_along`]'s iterator (state in arrays: glam's vectors index their
/// lanes through a match).
pub(crate) struct BrickWalk<'a, T: Point> {
    lattice: &'a Lattice<T>,
    t: f64,
    t_end: f64,
    /// Table coordinates of the current brick, and its index in the table.
    cell: [i32; 3],
    index: isize,
    step: [i32; 3],
    stride: [isize; 3],
    /// Per axis, the brick plane (table coordinates) the ray crosses next, and when.
    plane: [f64; 3],
    q0: [f64; 3],
    inv: [f64; 3],
    next: [f64; 3],
}

impl<'a, T: Point> Iterator for BrickWalk<'a, T> {
    type Item = BrickSpan<'a, T>;

    #[inline(always)]
    fn next(&mut self) -> Option<Self::Item> {
        let l = self.lattice;
        while self.t < self.t_end {
            let n = &self.next;
            let axis = if n[0] <= n[1] && n[0] <= n[2] { 0 } else if n[1] <= n[2] { 1 } else { 2 };
            let exit = n[axis].min(self.t_end);
            let (c, slot) = (self.cell, l.table[self.index as usize]);
            let start = self.t;
            self.t = exit;
            self.cell[axis] += self.step[axis];
            self.index += self.stride[axis] * self.step[axis] as isize;
            if self.cell[axis] < 0 || self.cell[axis] >= l.dims[axis] {
                self.t_end = exit;
            }
            // Planes computed from the ray each time rather than accumulated, so the
            // brick boundaries carry one rounding, not one per brick crossed.
            self.plane[axis] += self.step[axis] as f64;
            self.next[axis] = (self.plane[axis] - self.q0[axis]) * self.inv[axis];
            if slot == EMPTY {
                continue;
            }
            if !(exit > start) {
                continue;
            }
            // The part of the ray in the brick's box of cells to visit.
            let (mut visit_start, mut visit_end) = (start, exit);
            let (visit, points) = l.slot(slot);
            let b = visit.cells;
            if b != CellBox::ALL {
                for a in 0..3 {
                    if self.inv[a] == 0.0 {
                        continue;
                    }
                    let plane = |cell: u8| (c[a] as f64 + cell as f64 / BRICK_DIM as f64 - self.q0[a]) * self.inv[a];
                    let (t0, t1) = (plane(b.lo[a]), plane(b.hi[a]));
                    visit_start = visit_start.max(t0.min(t1));
                    visit_end = visit_end.min(t0.max(t1));
                }
            }
            let origin = ((IVec3::from(c) + l.lo) << BRICK_LOG2 as i32).as_dvec3();
            return Some(BrickSpan { start, end: exit, visit_start, visit_end, points, origin, majorant: visit.majorant, occupied: visit.occupied });
        }
        None
    }
}

/// The values of `volume` over the index box `[lo, lo + n)` into `out` (x-major, z fastest),
/// the background where no brick is stored: one brick lookup per brick the box touches.
fn gather<T: Voxel>(volume: &Volume<T>, lo: IVec3, n: IVec3, out: &mut [T]) {
    let hi = lo + n - 1;
    let (b0, b1) = (lo >> BRICK_LOG2 as i32, hi >> BRICK_LOG2 as i32);
    let at = |p: IVec3| (((p.x - lo.x) * n.y + (p.y - lo.y)) * n.z + (p.z - lo.z)) as usize;
    for bx in b0.x..=b1.x {
        for by in b0.y..=b1.y {
            for bz in b0.z..=b1.z {
                let origin = IVec3::new(bx, by, bz) << BRICK_LOG2 as i32;
                let (a, b) = (origin.max(lo), (origin + BRICK_DIM - 1).min(hi));
                let brick = volume.brick_index(origin).map(|i| volume.brick(i));
                for x in a.x..=b.x {
                    for y in a.y..=b.y {
                        let row = &mut out[at(IVec3::new(x, y, a.z))..=at(IVec3::new(x, y, b.z))];
                        match &brick {
                            Some(brick) => {
                                let l = IVec3::new(x, y, a.z) - origin;
                                let from = ((l.x << (2 * BRICK_LOG2)) | (l.y << BRICK_LOG2) | l.z) as usize;
                                row.copy_from_slice(&brick.values[from..from + row.len()]);
                            }
                            None => row.fill(volume.background()),
                        }
                    }
                }
            }
        }
    }
}

/// How a cache lattice maps onto the density lattice when it is the density's coarsened by
/// a whole factor per axis on the same points: cache index `q = scale * p + offset` per
/// axis for density index `p`, with `1 / scale` an integer and the cache points on density
/// points. `None` for any other lattice.
fn coarsening(density: &DAffine3, cache_world_to_index: &DAffine3) -> Option<(DVec3, DVec3)> {
    let m = *cache_world_to_index * *density;
    let (mut scale, mut offset) = (DVec3::ZERO, DVec3::ZERO);
    for a in 0..3 {
        let col = m.matrix3.col(a);
        let s = col[a];
        let off = col.abs().element_sum() - s.abs();
        let n = (1.0 / s).round();
        let aligned = n >= 1.0 && (1.0 / s - n).abs() <= 1e-9 * n && off <= 1e-12 * s.abs();
        // Cache point k sits at density index n (k - offset): a density point when n * offset is whole.
        let shift = n * m.translation[a];
        if !aligned || (shift - shift.round()).abs() > 1e-9 * shift.abs().max(1.0) {
            return None;
        }
        // Snapped to the lattice they are within rounding of: a rotated or sheared transform
        // composes to a factor a few ulps off 1 and an offset a few ulps off a whole number,
        // and resampling those counted one cache point too many per axis far from the origin
        // (a panic on a generated scene, issue #47).
        scale[a] = 1.0 / n;
        offset[a] = shift.round() / n;
    }
    Some((scale, offset))
}

/// The sum of `grids` (all on one lattice, scaled by `albedo`) trilinearly interpolated at
/// the 9^3 density points from `origin` (density index), added to `out`, where density index
/// `p` is cache index `scale * p + offset` per axis ([`coarsening`]): separably, z then y
/// then x, which are the nested lerps of [`Volume::sample_index`] at each point, shared
/// between points. Interpolating the sum is the sum of the interpolations: trilinear
/// interpolation is linear in the values.
fn resample(grids: &[&Volume<Vec3>], albedo: Vec3, scale: DVec3, offset: DVec3, origin: IVec3, out: &mut [Vec3A; BRICK_VALUES]) {
    let mut cells = [[0usize; EDGE]; 3];
    let mut weights = [[0f32; EDGE]; 3];
    let mut k0 = IVec3::ZERO;
    let mut n = IVec3::ZERO;
    for a in 0..3 {
        // In whole numbers over the factor ([`coarsening`] snapped them), so that the floors
        // are exact however far the brick lies from the origin.
        let factor = (1.0 / scale[a]).round();
        let shift = (offset[a] * factor).round();
        let q = |j: usize| ((origin[a] + j as i32) as f64 + shift) / factor;
        k0[a] = q(0).floor() as i32;
        n[a] = q(EDGE - 1).floor() as i32 + 2 - k0[a];
        for j in 0..EDGE {
            let k = q(j).floor();
            cells[a][j] = (k as i32 - k0[a]) as usize;
            weights[a][j] = (q(j) - k) as f32;
        }
    }
    let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
    // At most EDGE + 1 cache points per axis (a cache cell is at least a density cell).
    const MOST: usize = EDGE + 1;
    let mut block = [Vec3::ZERO; MOST * MOST * MOST];
    let mut corners = [Vec3A::ZERO; MOST * MOST * MOST];
    for (i, grid) in grids.iter().enumerate() {
        gather(grid, k0, n, &mut block[..nx * ny * nz]);
        for (c, &v) in corners.iter_mut().zip(&block[..nx * ny * nz]) {
            *c = if i == 0 { Vec3A::from(albedo * v) } else { *c + Vec3A::from(albedo * v) };
        }
    }
    let lerp = |a: Vec3A, b: Vec3A, w: f32| a + (b - a) * w;
    // Along z: (cache x, cache y, density z).
    let mut zs = [Vec3A::ZERO; MOST * MOST * EDGE];
    for xy in 0..nx * ny {
        for j in 0..EDGE {
            let c = xy * nz + cells[2][j];
            zs[xy * EDGE + j] = lerp(corners[c], corners[c + 1], weights[2][j]);
        }
    }
    // Along y: (cache x, density y, density z).
    let mut ys = [Vec3A::ZERO; MOST * EDGE * EDGE];
    for x in 0..nx {
        for j in 0..EDGE {
            let c = (x * ny + cells[1][j]) * EDGE;
            for z in 0..EDGE {
                ys[(x * EDGE + j) * EDGE + z] = lerp(zs[c + z], zs[c + EDGE + z], weights[1][j]);
            }
        }
    }
    for j in 0..EDGE {
        let c = cells[0][j] * EDGE * EDGE;
        for yz in 0..EDGE * EDGE {
            out[j * EDGE * EDGE + yz] += lerp(ys[c + yz], ys[c + EDGE * EDGE + yz], weights[0][j]);
        }
    }
}

/// Which sum of a ray's result a cache lattice adds to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Layer {
    Single,
    Multiple,
}

/// What the density lattice holds at a point: the density and the cache resampled onto
/// it, premultiplied by the albedo, in one of two layouts.
pub(crate) trait DensityPoint: Point {
    /// Whether single and multiple are kept apart (else `single` holds their sum).
    const SPLIT: bool;
    fn new(density: f32, single: Vec3, multiple: Vec3) -> Self;
    fn density(&self) -> f32;
    /// albedo * Li_single (or the sum) in xyz; w is not part of it.
    fn single(&self) -> Vec4;
    /// albedo * Li_multiple in xyz when [`DensityPoint::SPLIT`]; w is not part of it.
    fn multiple(&self) -> Vec4;
    /// Adds albedo * Li of one cache grid, a multiple-scattering one or not.
    fn add_li(&mut self, li: Vec3, multiple: bool);
}

/// albedo * (Li_single + Li_multiple) and the density, one register.
impl DensityPoint for Vec4 {
    const SPLIT: bool = false;
    #[inline(always)]
    fn new(density: f32, single: Vec3, multiple: Vec3) -> Self {
        (single + multiple).extend(density)
    }
    #[inline(always)]
    fn density(&self) -> f32 {
        self.w
    }
    #[inline(always)]
    fn single(&self) -> Vec4 {
        *self
    }
    #[inline(always)]
    fn multiple(&self) -> Vec4 {
        Vec4::ZERO
    }
    #[inline(always)]
    fn add_li(&mut self, li: Vec3, _: bool) {
        *self += li.extend(0.0);
    }
}

/// albedo * Li_single and the density; albedo * Li_multiple.
impl DensityPoint for [Vec4; 2] {
    const SPLIT: bool = true;
    #[inline(always)]
    fn new(density: f32, single: Vec3, multiple: Vec3) -> Self {
        [single.extend(density), multiple.extend(0.0)]
    }
    #[inline(always)]
    fn density(&self) -> f32 {
        self[0].w
    }
    #[inline(always)]
    fn single(&self) -> Vec4 {
        self[0]
    }
    #[inline(always)]
    fn multiple(&self) -> Vec4 {
        self[1]
    }
    #[inline(always)]
    fn add_li(&mut self, li: Vec3, multiple: bool) {
        self[multiple as usize] += li.extend(0.0);
    }
}

/// The density lattice with the cache grids that resample onto it, and the cache grids
/// that do not, on lattices of their own (albedo * Li in xyz).
pub(crate) struct MarchVolume<T: DensityPoint> {
    pub density: Lattice<T>,
    pub others: Vec<(Lattice<Vec4>, Layer)>,
}

/// Brick coordinates of the bricks whose 9^3 points (origin to origin + 8 per axis) hold a
/// value `keep` accepts: a brick's own, and the bricks below it whose aprons reach its
/// lower faces.
fn bricks_reading<T: Voxel>(volume: &Volume<T>, keep: impl Fn(T) -> bool + Sync) -> Vec<IVec3> {
    let per_brick: Vec<Vec<IVec3>> = volume
        .par_bricks()
        .map(|brick| {
            // Bit e of `reach` (e's bits x, y, z): some kept value lies on the lower face of
            // each axis set in e, so the brick at origin - 8 e reads it.
            let mut reach = 0u8;
            for (offset, &v) in brick.values.iter().enumerate() {
                if keep(v) {
                    let l = nimbus_volume::brick_local(offset);
                    let faces = (l.x == 0) as usize * 4 + (l.y == 0) as usize * 2 + (l.z == 0) as usize;
                    // Every subset of the faces the point lies on.
                    reach |= SUBSETS[faces];
                }
            }
            let b = brick.origin >> BRICK_LOG2 as i32;
            (0..8).filter(|e| reach & (1 << e) != 0).map(|e| b - IVec3::new(e >> 2 & 1, e >> 1 & 1, e & 1)).collect()
        })
        .collect();
    per_brick.concat()
}

/// `SUBSETS[m]`: bit e set for every e whose bits are a subset of m's (3 bits).
const SUBSETS: [u8; 8] = {
    let mut t = [0u8; 8];
    let mut m = 0;
    while m < 8 {
        let mut e = 0;
        while e < 8 {
            if e & m == e {
                t[m] |= 1 << e;
            }
            e += 1;
        }
        m += 1;
    }
    t
};

impl<T: DensityPoint> MarchVolume<T> {
    /// The layout of `density` and `cache` for a march with this albedo; `None` where it
    /// does not apply: a density background above zero fills all space.
    pub fn new(density: &Volume<f32>, cache: &IlluminationCache, albedo: Vec3) -> Option<Self> {
        if !(density.background() <= 0.0) {
            return None;
        }
        let to_world = density.transform().index_to_world();
        let mut fused = Vec::new();
        let mut others = Vec::new();
        for (grid, layer) in [(&cache.li_single, Layer::Single), (&cache.li_multiple, Layer::Multiple)] {
            let Some(grid) = grid else { continue };
            match coarsening(&to_world, &grid.transform().world_to_index()) {
                Some((scale, offset)) => fused.push((grid, layer, scale, offset)),
                None => others.push((own_lattice(grid, albedo), layer)),
            }
        }
        // albedo * Li of the fused grids as (single, multiple).
        let split = |li: Vec3, layer: Layer| if layer == Layer::Multiple { (Vec3::ZERO, li) } else { (li, Vec3::ZERO) };
        let background = fused.iter().fold(T::new(density.background(), Vec3::ZERO, Vec3::ZERO), |acc, &(grid, layer, _, _)| {
            let (s, m) = split(albedo * grid.background(), layer);
            T::new(acc.density(), acc.single().truncate() + s, acc.multiple().truncate() + m)
        });
        // The fused grids grouped by lattice and by the sum they add to: a group is
        // resampled once, as the sum of its grids.
        let mut groups: Vec<(Vec<&Volume<Vec3>>, Layer, DVec3, DVec3)> = Vec::new();
        for &(grid, layer, scale, offset) in &fused {
            let layer = if T::SPLIT { layer } else { Layer::Single };
            match groups.iter_mut().find(|g| (g.1, g.2, g.3) == (layer, scale, offset)) {
                Some(g) => g.0.push(grid),
                None => groups.push((vec![grid], layer, scale, offset)),
            }
        }
        let bricks = bricks_reading(density, |v| v > 0.0);
        let lattice = Lattice::build(density.transform().world_to_index(), &bricks, background, |origin, out| {
            let mut d = [0.0f32; BRICK_VALUES];
            gather(density, origin, IVec3::splat(EDGE as i32), &mut d);
            for (o, &d) in out.iter_mut().zip(&d) {
                *o = T::new(d, Vec3::ZERO, Vec3::ZERO);
            }
            for (grids, layer, scale, offset) in &groups {
                let multiple = *layer == Layer::Multiple;
                if *scale == DVec3::ONE && *offset == offset.round() {
                    // The density's own lattice (shifted by whole points): copies.
                    let mut block = [Vec3::ZERO; BRICK_VALUES];
                    for grid in grids {
                        gather(grid, origin + offset.as_ivec3(), IVec3::splat(EDGE as i32), &mut block);
                        for (o, &v) in out.iter_mut().zip(&block) {
                            o.add_li(albedo * v, multiple);
                        }
                    }
                } else {
                    let mut li = [Vec3A::ZERO; BRICK_VALUES];
                    resample(grids, albedo, *scale, *offset, origin, &mut li);
                    for (o, &v) in out.iter_mut().zip(&li) {
                        o.add_li(v.into(), multiple);
                    }
                }
            }
            Visit::of(&d)
        });
        Some(MarchVolume { density: lattice, others })
    }
}

/// A cache grid on its own lattice, premultiplied by the albedo: every stored brick and the
/// bricks below whose aprons reach it.
fn own_lattice(grid: &Volume<Vec3>, albedo: Vec3) -> Lattice<Vec4> {
    let bg = grid.background();
    let bricks = bricks_reading(grid, |_| true);
    Lattice::build(grid.transform().world_to_index(), &bricks, (albedo * bg).extend(0.0), |origin, out| {
        let mut li = [Vec3::ZERO; BRICK_VALUES];
        gather(grid, origin, IVec3::splat(EDGE as i32), &mut li);
        for (o, v) in out.iter_mut().zip(li) {
            *o = (albedo * v).extend(0.0);
        }
        // Never walked: a march walks the density lattice.
        Visit::ALL
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simd::Unfused;
    use nimbus_volume::Transform;

    /// A brick's cells to sample, against their definition (a corner of positive density)
    /// cell by cell, and its box around them, on sparse points: single points (one on a
    /// corner and one on a face of the brick), a line, and scattered points at several
    /// densities.
    #[test]
    fn the_cells_to_sample_are_those_with_a_corner_of_positive_density() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 33) as usize
        };
        let mut cases: Vec<Vec<f32>> = Vec::new();
        for single in [0, BRICK_VALUES - 1, (8 * EDGE + 4) * EDGE + 3] {
            let mut p = vec![0.0f32; BRICK_VALUES];
            p[single] = 1.0;
            cases.push(p);
        }
        let mut line = vec![-1.0f32; BRICK_VALUES];
        for z in 0..EDGE {
            line[(3 * EDGE + 5) * EDGE + z] = 0.5;
        }
        cases.push(line);
        for one_in in [2, 7, 40, 300] {
            cases.push((0..BRICK_VALUES).map(|_| if next() % one_in == 0 { 1.0 } else { 0.0 }).collect());
        }
        for points in cases {
            let visit = Visit::of(&points);
            let (mut lo, mut hi) = ([8u8; 3], [0u8; 3]);
            for (cx, word) in visit.occupied.iter().enumerate() {
                for cy in 0..8 {
                    for cz in 0..8 {
                        let corner = |dx: usize, dy: usize, dz: usize| points[((cx + dx) * EDGE + cy + dy) * EDGE + cz + dz] > 0.0;
                        let want = (0..8).any(|k| corner(k >> 2 & 1, k >> 1 & 1, k & 1));
                        assert_eq!(word >> (cy * 8 + cz) & 1 == 1, want, "cell {cx} {cy} {cz}");
                        if want {
                            for (a, c) in [cx, cy, cz].into_iter().enumerate() {
                                (lo[a], hi[a]) = (lo[a].min(c as u8), hi[a].max(c as u8 + 1));
                            }
                        }
                    }
                }
            }
            // An empty brick keeps the empty box's own convention.
            if lo[0] < 8 {
                assert_eq!(visit.cells, CellBox { lo, hi });
            } else {
                assert_eq!(visit.cells, CellBox::NONE);
            }
            // The table maps each cell's first corner to that cell's bit.
            for i in 0..BRICK_VALUES {
                let (x, y, z) = (i / (EDGE * EDGE), i / EDGE % EDGE, i % EDGE);
                if x < 8 && y < 8 && z < 8 {
                    assert_eq!(CELL_OF_POINT[i] as usize, x * 64 + y * 8 + z);
                }
            }
        }
    }

    fn ramp(transform: Transform) -> Volume<Vec3> {
        let mut v = Volume::new(transform, Vec3::ZERO);
        for x in -9..20 {
            for y in -3..12 {
                for z in -17..5 {
                    let p = IVec3::new(x, y, z).as_vec3();
                    v.set(IVec3::new(x, y, z), Vec3::new(p.x * p.y - p.z, (p.x * 0.3).sin() + p.z * p.z, 1.0 + p.y));
                }
            }
        }
        v
    }

    #[test]
    fn brick_bounds_are_the_majorant_grids() {
        // A ball of density with a bump, on bricks both whole and cut by its edge.
        let mut density = Volume::new(Transform::uniform(0.5, DVec3::new(0.2, 0.0, -0.3)), 0.0f32);
        for x in -12..12 {
            for y in -12..12 {
                for z in -12..12 {
                    let r = IVec3::new(x, y, z).as_vec3().length();
                    if r < 11.0 {
                        density.set(IVec3::new(x, y, z), (11.0 - r) * (1.0 + 0.3 * (x as f32 * 0.7).sin()));
                    }
                }
            }
        }
        let volume = MarchVolume::<Vec4>::new(&density, &IlluminationCache::default(), Vec3::ONE).unwrap();
        let grid = nimbus_volume::MajorantGrid::build(&density);
        assert_eq!(grid.cell_size(), BRICK_DIM);
        let l = &volume.density;
        let mut seen = 0;
        for (i, &slot) in l.table.iter().enumerate() {
            if slot != EMPTY {
                let (yz, z) = (i / l.dims.z as usize, i % l.dims.z as usize);
                let b = l.lo + IVec3::new((yz / l.dims.y as usize) as i32, (yz % l.dims.y as usize) as i32, z as i32);
                let centre = (b * BRICK_DIM).as_dvec3() + 0.5 * BRICK_DIM as f64;
                assert_eq!(l.slot(slot).0.majorant, grid.at(centre), "brick {b}");
                seen += 1;
            }
        }
        assert!(seen > 20);
        // And every positive cell of the grid is a brick of the lattice.
        assert_eq!(grid.values().iter().filter(|&&m| m > 0.0).count(), seen);
    }

    #[test]
    fn subsets_of_face_sets() {
        assert_eq!(SUBSETS[0], 0b1);
        assert_eq!(SUBSETS[0b100], 0b1_0001);
        assert_eq!(SUBSETS[7], 0xff);
    }

    #[test]
    fn lattices_sample_as_the_volume_does() {
        let t = Transform::uniform(0.7, DVec3::new(0.3, -1.1, 2.0));
        let v = ramp(t);
        let lattice = own_lattice(&v, Vec3::ONE);
        let w2i = t.world_to_index();
        for i in 0..4000 {
            let f = i as f64;
            let p = DVec3::new((f * 0.137) % 34.0 - 12.0, (f * 0.0731) % 20.0 - 6.0, (f * 0.311) % 28.0 - 20.0);
            let want = v.sample_index(p);
            let got = lattice.sample(Unfused, w2i.transform_point3(t.to_world(p))).truncate();
            assert!((got - want).abs().max_element() <= 1e-5 * want.abs().max_element().max(1.0), "{p}: {got} vs {want}");
        }
    }

    #[test]
    fn whole_factor_coarsenings_resample_exactly() {
        let density = Transform::uniform(0.5, DVec3::new(1.0, 2.0, 3.0));
        let coarse = |s: f64, shift: DVec3| {
            Transform::new(density.index_to_world() * DAffine3::from_scale(DVec3::splat(s)) * DAffine3::from_translation(shift)).unwrap()
        };
        let d2w = density.index_to_world();
        assert!(coarsening(&d2w, &coarse(1.0, DVec3::ZERO).world_to_index()).is_some());
        assert!(coarsening(&d2w, &coarse(4.0, DVec3::new(-0.25, 0.5, 0.0)).world_to_index()).is_some());
        assert!(coarsening(&d2w, &coarse(2.0, DVec3::splat(0.3)).world_to_index()).is_none(), "cache points between density points");
        assert!(coarsening(&d2w, &coarse(1.5, DVec3::ZERO).world_to_index()).is_none(), "not a whole factor");
        assert!(coarsening(&d2w, &coarse(0.5, DVec3::ZERO).world_to_index()).is_none(), "finer");
        // A rotated, sheared lattice far from the origin and the cache on its own points: the
        // composed map is a few ulps off the identity, and is snapped to it (a generated
        // scene's march panicked on the unsnapped one, counting 11 cache points an axis).
        let sheared = Transform::new(DAffine3::from_mat3_translation(
            glam::DMat3::from_cols(DVec3::new(0.201, 0.03, -0.02), DVec3::new(-0.04, 0.148, 0.01), DVec3::new(0.015, -0.02, 0.092)),
            DVec3::new(3.0e4, -4.6, 163.7),
        ))
        .unwrap();
        let (scale, offset) = coarsening(&sheared.index_to_world(), &sheared.world_to_index()).unwrap();
        assert_eq!((scale, offset), (DVec3::ONE, DVec3::ZERO));
        for (s, shift) in [(1.0, DVec3::ZERO), (2.0, DVec3::ZERO), (4.0, DVec3::new(-0.25, 0.5, 0.75)), (3.0, DVec3::ZERO)] {
            let ct = coarse(s, shift);
            let cache = ramp(ct);
            let (scale, offset) = coarsening(&d2w, &ct.world_to_index()).unwrap();
            for origin in [IVec3::new(-16, 0, -8), IVec3::new(8, -8, 0), IVec3::new(0, 16, -24)] {
                let mut out = [Vec3A::ONE; BRICK_VALUES];
                resample(&[&cache, &cache], Vec3::splat(0.5), scale, offset, origin, &mut out);
                for (i, got) in out.iter().map(|&v| Vec3::from(v) - 1.0).enumerate() {
                    let j = IVec3::new((i / X) as i32, (i / Y % EDGE) as i32, (i % EDGE) as i32);
                    let want = cache.sample_world(density.to_world((origin + j).as_dvec3()));
                    assert!((got - want).abs().max_element() <= 1e-5 * want.abs().max_element().max(1.0), "scale {s}, {j}: {got} vs {want}");
                }
            }
        }
    }
}
