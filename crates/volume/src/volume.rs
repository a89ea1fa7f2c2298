//! The sparse volume: 8^3 bricks aligned to OpenVDB leaves, found through a two-level table
//! shaped like OpenVDB's upper tree (128^3-voxel nodes, each a dense table of 16^3 brick
//! slots, the nodes found through a dense index over their bounding box, or a hash map where
//! that box is huge), so a lookup costs two indexed loads and memory follows the active
//! bricks.

use glam::{DVec3, IVec3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::{Transform, Voxel};

pub const BRICK_LOG2: u32 = 3;
pub const BRICK_DIM: i32 = 1 << BRICK_LOG2;
pub const BRICK_VOXELS: usize = 1 << (3 * BRICK_LOG2);

/// log2 of a node's edge in bricks (16 bricks = 128 voxels, OpenVDB's lower internal node).
const NODE_LOG2: u32 = 4;
const NODE_SLOTS: usize = 1 << (3 * NODE_LOG2);
const NO_BRICK: u32 = u32::MAX;

/// Offset of local voxel (x,y,z) in a brick, x-major and z fastest: the same order as
/// `openvdb::tree::LeafNode<T,3>::coordToOffset`, so leaf buffers copy across unchanged.
#[inline]
pub fn brick_offset(local: IVec3) -> usize {
    ((local.x << (2 * BRICK_LOG2)) | (local.y << BRICK_LOG2) | local.z) as usize
}

/// Inverse of [`brick_offset`].
#[inline]
pub fn brick_local(offset: usize) -> IVec3 {
    let o = offset as i32;
    IVec3::new(o >> (2 * BRICK_LOG2), (o >> BRICK_LOG2) & (BRICK_DIM - 1), o & (BRICK_DIM - 1))
}

/// Origin (lowest corner) of the brick holding voxel `ijk`.
#[inline]
pub fn brick_origin(ijk: IVec3) -> IVec3 {
    ijk & IVec3::splat(!(BRICK_DIM - 1))
}

/// The lattice cell holding index-space point `p`, as trilinear interpolation uses it: its
/// lowest corner and `p`'s fraction across it; `None` for a non-finite point or one beyond
/// the i32 lattice.
#[inline]
pub fn lattice_cell(p: DVec3) -> Option<(IVec3, DVec3)> {
    // Truncation and a correction rather than f64::floor, which on baseline x86-64 (no
    // SSE4.1) is a libm call: 4% of a path's time in vdbcache, three per density lookup.
    let limit = (i32::MAX - 1) as f64;
    if !(p.x.abs() < limit && p.y.abs() < limit && p.z.abs() < limit) {
        return None; // NaN fails the comparisons too
    }
    let floor = |x: f64| {
        let i = x as i32;
        if (i as f64) > x {
            i - 1
        } else {
            i
        }
    };
    let base = IVec3::new(floor(p.x), floor(p.y), floor(p.z));
    Some((base, p - base.as_dvec3()))
}

/// The trilinear interpolation of a cell's corners (in [`Volume::corners`]' order) at the
/// fractions `uvw` across it, in nested lerps as OpenVDB's BoxSampler takes them.
#[inline]
pub fn trilinear<T: Voxel>(c: &[T; 8], uvw: DVec3) -> T {
    let lerp = T::lerp;
    lerp(
        lerp(lerp(c[0], c[1], uvw.z), lerp(c[2], c[3], uvw.z), uvw.y),
        lerp(lerp(c[4], c[5], uvw.z), lerp(c[6], c[7], uvw.z), uvw.y),
        uvw.x,
    )
}

/// A 512-bit activity mask, bit n of word n/64 for offset n (openvdb::util::NodeMask<3>).
pub type BrickMask = [u64; 8];

#[inline]
fn mask_bit(mask: &BrickMask, offset: usize) -> bool {
    mask[offset >> 6] & (1u64 << (offset & 63)) != 0
}

/// A borrowed brick: its origin, 512 values in [`brick_offset`] order and activity mask.
#[derive(Clone, Copy, Debug)]
pub struct BrickRef<'a, T> {
    pub origin: IVec3,
    pub values: &'a [T],
    pub active: &'a BrickMask,
}

impl<T> BrickRef<'_, T> {
    pub fn is_active(&self, offset: usize) -> bool {
        mask_bit(self.active, offset)
    }

    pub fn active_count(&self) -> u32 {
        self.active.iter().map(|w| w.count_ones()).sum()
    }
}

/// A sparse volume of values of type `T`. Inactive voxels inside a brick keep a value (as in
/// an OpenVDB leaf); everywhere outside the bricks the value is the background.
#[derive(Clone, Debug)]
pub struct Volume<T: Voxel> {
    transform: Transform,
    background: T,
    origins: Vec<IVec3>,
    values: Vec<T>,
    masks: Vec<BrickMask>,
    nodes: NodeTable,
}

/// Most entries of a [`NodeTable`]'s dense index: 64k nodes of 128^3 voxels, an 8192^3-voxel
/// box at 1 MiB of index, far beyond any one scene's extent in voxels.
const MAX_DENSE_NODES: i64 = 1 << 16;

/// The upper tree: 128^3-voxel nodes by key, found through a dense index over the nodes'
/// bounding box while that box is small (every scene we have met), else through the hash
/// map. The hash probe had been a fifth of the paths' time in vdbcache: every trilinear
/// sample makes one.
#[derive(Clone, Debug, Default)]
struct NodeTable {
    tables: Vec<Box<[u32; NODE_SLOTS]>>,
    keys: FxHashMap<IVec3, u32>,
    /// Index into `tables` by node key within `origin + [0, dims)`, `NO_BRICK` where absent;
    /// empty (dims zero) once the box outgrew [`MAX_DENSE_NODES`].
    dense: Vec<u32>,
    origin: IVec3,
    dims: IVec3,
}

impl NodeTable {
    #[inline]
    fn get(&self, key: IVec3) -> Option<&[u32; NODE_SLOTS]> {
        let c = key - self.origin;
        let index = if self.dims.x > 0 {
            if c.cmplt(IVec3::ZERO).any() || c.cmpge(self.dims).any() {
                return None;
            }
            self.dense[((c.x * self.dims.y + c.y) * self.dims.z + c.z) as usize]
        } else {
            *self.keys.get(&key)?
        };
        (index != NO_BRICK).then(|| &*self.tables[index as usize])
    }

    fn get_or_insert(&mut self, key: IVec3) -> &mut [u32; NODE_SLOTS] {
        let index = match self.keys.get(&key) {
            Some(&i) => i,
            None => {
                let i = self.tables.len() as u32;
                self.tables.push(Box::new([NO_BRICK; NODE_SLOTS]));
                self.keys.insert(key, i);
                self.reindex();
                i
            }
        };
        &mut self.tables[index as usize]
    }

    /// Rebuilds the dense index over the nodes' bounding box, or drops it if too large.
    fn reindex(&mut self) {
        let lo = self.keys.keys().fold(IVec3::MAX, |a, &k| a.min(k));
        let hi = self.keys.keys().fold(IVec3::MIN, |a, &k| a.max(k));
        let dims = hi - lo + 1;
        let entries = dims.x as i64 * dims.y as i64 * dims.z as i64;
        if entries > MAX_DENSE_NODES {
            self.dense = Vec::new();
            self.dims = IVec3::ZERO;
            return;
        }
        self.origin = lo;
        self.dims = dims;
        self.dense = vec![NO_BRICK; entries as usize];
        for (&k, &i) in &self.keys {
            let c = k - lo;
            self.dense[((c.x * dims.y + c.y) * dims.z + c.z) as usize] = i;
        }
    }
}

fn assert_brick_origin(origin: IVec3) {
    assert_eq!(origin, brick_origin(origin), "brick origin {origin} is not a multiple of {BRICK_DIM}");
}

#[inline]
fn node_key(ijk: IVec3) -> IVec3 {
    ijk >> (BRICK_LOG2 + NODE_LOG2) as i32
}

#[inline]
fn node_slot(ijk: IVec3) -> usize {
    let b = (ijk >> BRICK_LOG2 as i32) & IVec3::splat((1 << NODE_LOG2) - 1);
    ((b.x << (2 * NODE_LOG2)) | (b.y << NODE_LOG2) | b.z) as usize
}

impl Volume<f32> {
    /// The largest value the volume holds: its bricks' values and its background.
    pub fn peak(&self) -> f32 {
        self.bricks().flat_map(|b| b.values.iter().copied()).fold(self.background(), f32::max)
    }
}

impl<T: Voxel> Volume<T> {
    pub fn new(transform: Transform, background: T) -> Self {
        Volume {
            transform,
            background,
            origins: Vec::new(),
            values: Vec::new(),
            masks: Vec::new(),
            nodes: NodeTable::default(),
        }
    }

    pub fn transform(&self) -> &Transform {
        &self.transform
    }

    pub fn set_transform(&mut self, transform: Transform) {
        self.transform = transform;
    }

    pub fn background(&self) -> T {
        self.background
    }

    pub fn brick_count(&self) -> usize {
        self.origins.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    pub fn active_voxel_count(&self) -> u64 {
        self.masks.iter().flatten().map(|w| w.count_ones() as u64).sum()
    }

    /// Index of the brick holding `ijk`, if there is one.
    #[inline]
    pub fn brick_index(&self, ijk: IVec3) -> Option<usize> {
        let slot = self.nodes.get(node_key(ijk))?[node_slot(ijk)];
        (slot != NO_BRICK).then_some(slot as usize)
    }

    pub fn brick(&self, index: usize) -> BrickRef<'_, T> {
        BrickRef {
            origin: self.origins[index],
            values: &self.values[index * BRICK_VOXELS..(index + 1) * BRICK_VOXELS],
            active: &self.masks[index],
        }
    }

    /// Inserts (or replaces) the brick at `origin`, a multiple of 8 on every axis.
    pub fn insert_brick(&mut self, origin: IVec3, values: &[T], active: &BrickMask) {
        assert_brick_origin(origin);
        assert_eq!(values.len(), BRICK_VOXELS, "a brick holds {BRICK_VOXELS} values");
        let index = self.brick_index_or_insert(origin);
        self.values[index * BRICK_VOXELS..(index + 1) * BRICK_VOXELS].copy_from_slice(values);
        self.masks[index] = *active;
    }

    fn brick_index_or_insert(&mut self, ijk: IVec3) -> usize {
        let n = self.origins.len();
        let index = self.index_or_register(ijk);
        if index == n {
            self.values.extend(std::iter::repeat_n(self.background, BRICK_VOXELS));
        }
        index
    }

    /// The index of the brick holding `ijk`; a new brick gets the next index, an origin and an
    /// empty mask, but no values (the caller provides them).
    fn index_or_register(&mut self, ijk: IVec3) -> usize {
        let n = self.origins.len();
        let slot = &mut self.nodes.get_or_insert(node_key(ijk))[node_slot(ijk)];
        if *slot != NO_BRICK {
            return *slot as usize;
        }
        *slot = n as u32;
        self.origins.push(brick_origin(ijk));
        self.masks.push([0; 8]);
        n
    }

    pub fn bricks(&self) -> impl ExactSizeIterator<Item = BrickRef<'_, T>> + '_ {
        (0..self.origins.len()).map(move |i| self.brick(i))
    }

    pub fn par_bricks(&self) -> impl IndexedParallelIterator<Item = BrickRef<'_, T>> + '_ {
        (0..self.origins.len()).into_par_iter().map(move |i| self.brick(i))
    }

    /// The value at `ijk`: the brick's value if a brick holds it, else the background.
    #[inline]
    pub fn get(&self, ijk: IVec3) -> T {
        match self.brick_index(ijk) {
            Some(b) => self.values[b * BRICK_VOXELS + brick_offset(ijk & IVec3::splat(BRICK_DIM - 1))],
            None => self.background,
        }
    }

    pub fn is_active(&self, ijk: IVec3) -> bool {
        self.brick_index(ijk)
            .is_some_and(|b| mask_bit(&self.masks[b], brick_offset(ijk & IVec3::splat(BRICK_DIM - 1))))
    }

    /// Sets the value at `ijk` and marks it active, creating its brick if needed.
    pub fn set(&mut self, ijk: IVec3, value: T) {
        let b = self.brick_index_or_insert(ijk);
        let offset = brick_offset(ijk & IVec3::splat(BRICK_DIM - 1));
        self.values[b * BRICK_VOXELS + offset] = value;
        self.masks[b][offset >> 6] |= 1u64 << (offset & 63);
    }

    /// Trilinear interpolation in index space, equal to `openvdb::tools::BoxSampler::sample`:
    /// the same corner order, the same nested lerps, weights in f64 as OpenVDB computes them.
    #[inline]
    pub fn sample_index(&self, p: DVec3) -> T {
        let Some((ijk, uvw)) = lattice_cell(p) else { return self.background };
        trilinear(&self.corners(ijk), uvw)
    }

    /// The eight lattice values around the cell whose lowest corner is `ijk`, in the order
    /// (x,y,z) = 000, 001, 010, 011, 100, 101, 110, 111: what a walk that integrates the
    /// trilinear function cell by cell reads once per cell.
    #[inline]
    pub fn corners(&self, ijk: IVec3) -> [T; 8] {
        let local = ijk & IVec3::splat(BRICK_DIM - 1);
        if local.max_element() < BRICK_DIM - 1 {
            // The whole cell lies inside one brick: one lookup, eight loads.
            if let Some(b) = self.brick_index(ijk) {
                let v = &self.values[b * BRICK_VOXELS..(b + 1) * BRICK_VOXELS];
                let o = brick_offset(local);
                const X: usize = 1 << (2 * BRICK_LOG2);
                const Y: usize = 1 << BRICK_LOG2;
                return [v[o], v[o + 1], v[o + Y], v[o + Y + 1], v[o + X], v[o + X + 1], v[o + X + Y], v[o + X + Y + 1]];
            }
            return [self.background; 8];
        }
        // The cell reaches into the next brick along each axis where it starts at a brick's
        // last voxel (a third of all cells): each of the 2, 4 or 8 bricks it touches is
        // looked up once, not once per corner. Corner n's brick is that of corner n & m.
        let m = (usize::from(local.x == BRICK_DIM - 1) << 2) | (usize::from(local.y == BRICK_DIM - 1) << 1) | usize::from(local.z == BRICK_DIM - 1);
        let corner = |n: usize| IVec3::new((n >> 2) as i32 & 1, (n >> 1) as i32 & 1, n as i32 & 1);
        let mut bricks = [None; 8];
        for (k, b) in bricks.iter_mut().enumerate() {
            if k & !m == 0 {
                *b = self.brick_index(ijk + corner(k));
            }
        }
        let at = |n: usize| {
            let c = ijk + corner(n);
            bricks[n & m].map_or(self.background, |b| self.values[b * BRICK_VOXELS + brick_offset(c & IVec3::splat(BRICK_DIM - 1))])
        };
        [at(0), at(1), at(2), at(3), at(4), at(5), at(6), at(7)]
    }

    pub fn sample_world(&self, p: DVec3) -> T {
        self.sample_index(self.transform.to_index(p))
    }

    /// Inclusive index bounding box of the active voxels, or None when nothing is active.
    pub fn active_index_bbox(&self) -> Option<(IVec3, IVec3)> {
        self.par_bricks()
            .filter_map(|brick| {
                let mut lo = IVec3::MAX;
                let mut hi = IVec3::MIN;
                for (w, &word) in brick.active.iter().enumerate() {
                    let mut bits = word;
                    while bits != 0 {
                        let offset = w * 64 + bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        let ijk = brick.origin + brick_local(offset);
                        lo = lo.min(ijk);
                        hi = hi.max(ijk);
                    }
                }
                (lo.x <= hi.x).then_some((lo, hi))
            })
            .reduce_with(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }

    /// World-space axis-aligned box around the active voxels' cells, padded by half a voxel
    /// so a voxel's whole footprint is inside: what a camera frames and a sun's disc covers.
    pub fn world_bounds(&self) -> Option<(DVec3, DVec3)> {
        let (lo, hi) = self.active_index_bbox()?;
        let (lo, hi) = (lo.as_dvec3() - 0.5, hi.as_dvec3() + 0.5);
        let corners = (0..8).map(|n| {
            DVec3::new(
                if n & 4 != 0 { hi.x } else { lo.x },
                if n & 2 != 0 { hi.y } else { lo.y },
                if n & 1 != 0 { hi.z } else { lo.z },
            )
        });
        corners
            .map(|c| self.transform.to_world(c))
            .fold(None, |acc: Option<(DVec3, DVec3)>, w| match acc {
                None => Some((w, w)),
                Some((a, b)) => Some((a.min(w), b.max(w))),
            })
    }

    /// Builds a volume from bricks computed in parallel: `fill` writes a brick's 512 values
    /// and returns its activity mask; bricks that come back with no active voxel are dropped,
    /// so a stage can propose a generous set of bricks and keep only what holds something.
    pub fn from_brick_fn<F>(transform: Transform, background: T, origins: &[IVec3], fill: F) -> Self
    where
        F: Fn(IVec3, &mut [T]) -> BrickMask + Sync,
    {
        // Filled in place, in parallel, then compacted: a copy of every brick through a
        // per-brick buffer, and the fresh pages of both, cost more than the fill itself on
        // millions of voxels.
        let mut values = vec![background; origins.len() * BRICK_VOXELS];
        let masks: Vec<BrickMask> = values
            .par_chunks_mut(BRICK_VOXELS)
            .zip(origins.par_iter())
            .map(|(values, &origin)| fill(origin, values))
            .collect();
        let mut volume = Volume::new(transform, background);
        volume.values = values;
        for (from, (&origin, mask)) in origins.iter().zip(&masks).enumerate() {
            if mask.iter().all(|&w| w == 0) {
                continue;
            }
            // As insert_brick: a repeated origin replaces the earlier brick.
            assert_brick_origin(origin);
            let to = volume.index_or_register(origin);
            if to != from {
                volume.values.copy_within(from * BRICK_VOXELS..(from + 1) * BRICK_VOXELS, to * BRICK_VOXELS);
            }
            volume.masks[to] = *mask;
        }
        volume.values.truncate(volume.origins.len() * BRICK_VOXELS);
        volume
    }

    /// A new volume on the same bricks with each value mapped.
    pub fn map<U: Voxel>(&self, background: U, f: impl Fn(T) -> U + Sync) -> Volume<U> {
        Volume {
            transform: self.transform,
            background,
            origins: self.origins.clone(),
            values: self.values.par_iter().map(|&v| f(v)).collect(),
            masks: self.masks.clone(),
            nodes: self.nodes.clone(),
        }
    }
}
