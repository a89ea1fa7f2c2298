//! Photons binned into a uniform grid by counting sort: built in O(photons), queried by the
//! cells a ball overlaps.

use std::collections::BinaryHeap;

use glam::{DVec3, IVec3, Vec3};

/// Photon indices grouped by grid cell. Positions are kept relative to the grid's origin in
/// f32, which is exact enough at any world offset since cells are small.
pub struct PhotonBins {
    origin: DVec3,
    cell: f64,
    dims: IVec3,
    /// Start of each cell's run in `order`; one more entry than cells.
    starts: Vec<u32>,
    /// Photon indices sorted by cell.
    order: Vec<u32>,
    /// Positions relative to `origin`, in `order`'s order: a cell's run is contiguous in
    /// memory, so a search streams through it (indexing by photon number instead, as the
    /// photons lie in path order, made every candidate a cache miss).
    local: Vec<Vec3>,
}

/// Largest number of cells the grid may have (grows the cell size past it).
const MAX_CELLS: f64 = (1u64 << 24) as f64;

impl PhotonBins {
    /// Bins `positions` with cells of about `cell` world units.
    pub fn new(positions: &[DVec3], cell: f64) -> PhotonBins {
        let (lo, hi) = positions
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), &p| (a.min(p), b.max(p)));
        if positions.is_empty() {
            return PhotonBins { origin: DVec3::ZERO, cell: 1.0, dims: IVec3::ONE, starts: vec![0, 0], order: vec![], local: vec![] };
        }
        let extent = (hi - lo).max(DVec3::splat(1e-9));
        let mut cell = cell.max(1e-12);
        let count = |c: f64| ((extent / c).floor() + 1.0).element_product();
        while count(cell) > MAX_CELLS {
            cell *= 1.5;
        }
        let dims = ((extent / cell).floor() + 1.0).as_ivec3();
        let mut bins = PhotonBins { origin: lo, cell, dims, starts: vec![], order: vec![], local: vec![] };
        let ids: Vec<u32> = positions.iter().map(|&p| bins.cell_id(bins.cell_of(p)) as u32).collect();
        let cells = (dims.x * dims.y * dims.z) as usize;
        let mut starts = vec![0u32; cells + 1];
        for &id in &ids {
            starts[id as usize + 1] += 1;
        }
        for i in 0..cells {
            starts[i + 1] += starts[i];
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; positions.len()];
        for (i, &id) in ids.iter().enumerate() {
            order[fill[id as usize] as usize] = i as u32;
            fill[id as usize] += 1;
        }
        bins.local = order.iter().map(|&i| (positions[i as usize] - lo).as_vec3()).collect();
        bins.starts = starts;
        bins.order = order;
        bins
    }

    /// World position of the grid's lowest corner; positions are kept relative to it.
    pub fn origin(&self) -> DVec3 {
        self.origin
    }

    /// Cell edge (world units).
    pub fn cell(&self) -> f64 {
        self.cell
    }

    /// Cells per axis; cell (x, y, z) is number (x * dims.y + y) * dims.z + z.
    pub fn dims(&self) -> IVec3 {
        self.dims
    }

    /// Where each cell's run starts in [`PhotonBins::order`]; one more entry than cells.
    pub fn starts(&self) -> &[u32] {
        &self.starts
    }

    /// Photon indices sorted by cell.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Photon positions relative to [`PhotonBins::origin`], in [`PhotonBins::order`]'s order
    /// (entry j is photon `order()[j]`).
    pub fn local_positions(&self) -> &[Vec3] {
        &self.local
    }

    fn cell_of(&self, p: DVec3) -> IVec3 {
        ((p - self.origin) / self.cell).floor().as_ivec3().clamp(IVec3::ZERO, self.dims - 1)
    }

    fn cell_id(&self, c: IVec3) -> usize {
        ((c.x * self.dims.y + c.y) * self.dims.z + c.z) as usize
    }

    /// Calls `f(photon index, squared distance)` for every photon within `radius` of `p`.
    pub fn for_each_within(&self, p: DVec3, radius: f64, mut f: impl FnMut(u32, f32)) {
        if self.local.is_empty() {
            return;
        }
        let q = (p - self.origin).as_vec3();
        let r2 = (radius * radius) as f32;
        let lo = (((p - radius) - self.origin) / self.cell).floor().as_ivec3().max(IVec3::ZERO);
        let hi = (((p + radius) - self.origin) / self.cell).floor().as_ivec3().min(self.dims - 1);
        if lo.z > hi.z {
            return;
        }
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                // A row of cells along z is one contiguous run.
                let a = self.starts[self.cell_id(IVec3::new(x, y, lo.z))] as usize;
                let b = self.starts[self.cell_id(IVec3::new(x, y, hi.z)) + 1] as usize;
                for (&i, &l) in self.order[a..b].iter().zip(&self.local[a..b]) {
                    let d2 = (l - q).length_squared();
                    if d2 <= r2 {
                        f(i, d2);
                    }
                }
            }
        }
    }

    /// The `k` photons nearest `p` within `max_radius`: their indices (unordered) and the
    /// squared distance to the farthest of them. Searches shells of cells outward and stops
    /// once the next shell cannot hold anything nearer than the current k-th.
    pub fn nearest(&self, p: DVec3, k: usize, max_radius: f64, out: &mut Vec<u32>) -> f32 {
        out.clear();
        if self.local.is_empty() || k == 0 {
            return 0.0;
        }
        let q = (p - self.origin).as_vec3();
        let max_r2 = (max_radius * max_radius) as f32;
        let centre = ((p - self.origin) / self.cell).floor().as_ivec3();
        // Max-heap on squared distance (f32 bits order like the floats, being non-negative).
        let mut heap: BinaryHeap<(u32, u32)> = BinaryHeap::with_capacity(k + 1);
        let max_shell = (max_radius / self.cell).ceil() as i32 + 1;
        let visit = |heap: &mut BinaryHeap<(u32, u32)>, c: IVec3| {
            let id = self.cell_id(c);
            let run = self.starts[id] as usize..self.starts[id + 1] as usize;
            for (&i, &l) in self.order[run.clone()].iter().zip(&self.local[run]) {
                let d2 = (l - q).length_squared();
                if d2 > max_r2 {
                    continue;
                }
                if heap.len() < k {
                    heap.push((d2.to_bits(), i));
                } else if let Some(mut top) = heap.peek_mut().filter(|top| d2 < f32::from_bits(top.0)) {
                    // Replacing the top in place sifts once (pop then push sifted twice).
                    *top = (d2.to_bits(), i);
                }
            }
        };
        for shell in 0..=max_shell {
            // Nothing in this shell is nearer than (shell - 1) cells.
            let reach = ((shell - 1).max(0) as f64 * self.cell) as f32;
            if reach * reach > max_r2 || (heap.len() == k && reach * reach > f32::from_bits(heap.peek().unwrap().0)) {
                break;
            }
            // Only the shell's surface cells inside the grid are visited: with photons on a
            // plane the cells are tiny against max_radius, and walking every cell of every
            // shell's cube (shells^4 in all) did not finish.
            let (lo, hi) = (centre - shell, centre + shell);
            let (a, b) = (lo.max(IVec3::ZERO), hi.min(self.dims - 1));
            if a.cmpgt(b).any() {
                continue;
            }
            // The shell's two faces across an axis that lie inside the grid (one at shell 0).
            let faces = |axis: usize| {
                let (l, h) = (lo[axis], hi[axis]);
                [Some(l), (h != l).then_some(h)].into_iter().flatten().filter(move |v| (a[axis]..=b[axis]).contains(v))
            };
            for x in a.x..=b.x {
                if x == lo.x || x == hi.x {
                    for y in a.y..=b.y {
                        for z in a.z..=b.z {
                            visit(&mut heap, IVec3::new(x, y, z));
                        }
                    }
                    continue;
                }
                for y in faces(1) {
                    for z in a.z..=b.z {
                        visit(&mut heap, IVec3::new(x, y, z));
                    }
                }
                for z in faces(2) {
                    for y in (a.y..=b.y).filter(|&y| y != lo.y && y != hi.y) {
                        visit(&mut heap, IVec3::new(x, y, z));
                    }
                }
            }
            // Once the shell's cube holds the whole grid there is nothing farther out.
            if lo.cmple(IVec3::ZERO).all() && hi.cmpge(self.dims - 1).all() {
                break;
            }
        }
        let far = heap.peek().map_or(0.0, |e| f32::from_bits(e.0));
        out.extend(heap.into_iter().map(|e| e.1));
        far
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points(n: usize) -> Vec<DVec3> {
        let mut s = 12345u64;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n).map(|_| DVec3::new(next() * 4.0 + 1e5, next() * 2.0, next() * 3.0)).collect()
    }

    #[test]
    fn radius_query_equals_brute_force() {
        let pts = points(5000);
        let bins = PhotonBins::new(&pts, 0.25);
        for q in pts.iter().step_by(97) {
            let mut got = vec![];
            bins.for_each_within(*q, 0.4, |i, _| got.push(i));
            got.sort();
            let want: Vec<u32> = (0..pts.len() as u32).filter(|&i| (pts[i as usize] - *q).length() <= 0.4).collect();
            assert_eq!(got, want);
        }
    }

    /// Photons on a plane (what an opaque medium stores: every interaction at its surface) make
    /// cells tiny against the search reach. The search used to walk every cell of every
    /// shell's cube, about (reach / cell)^4 of them, and did not finish here.
    #[test]
    fn nearest_over_a_flat_photon_map_ends_and_equals_brute_force() {
        let pts: Vec<DVec3> = points(300).iter().map(|p| DVec3::new(p.x * 0.15, p.y * 0.3, 0.6)).collect();
        let bins = PhotonBins::new(&pts, 1e-3);
        let mut out = vec![];
        for q in [DVec3::new(1e5 * 0.15 + 0.3, 0.3, 0.1), DVec3::new(1e5 * 0.15, 0.0, 0.6), DVec3::new(0.0, 0.0, 0.0)] {
            for (k, reach) in [(8, 1.2), (400, 1.2), (8, 0.05)] {
                let far = bins.nearest(q, k, reach, &mut out);
                let mut d: Vec<f64> = pts.iter().map(|p| (*p - q).length_squared()).filter(|d| *d <= reach * reach).collect();
                d.sort_by(|a, b| a.partial_cmp(b).unwrap());
                assert_eq!(out.len(), k.min(d.len()), "query {q}, k {k}, reach {reach}");
                if let Some(want) = d.get(out.len().max(1) - 1) {
                    assert!((far as f64 - want).abs() < 1e-4 * want.max(1e-6), "{far} vs {want}");
                }
            }
        }
    }

    #[test]
    fn nearest_equals_brute_force() {
        let pts = points(5000);
        let bins = PhotonBins::new(&pts, 0.1);
        let mut out = vec![];
        for (n, q) in pts.iter().step_by(131).enumerate() {
            let q = *q + DVec3::splat(0.01 * n as f64);
            let far = bins.nearest(q, 32, 10.0, &mut out);
            let mut d: Vec<f64> = pts.iter().map(|p| (*p - q).length_squared()).collect();
            d.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(out.len(), 32);
            assert!((far as f64 - d[31]).abs() < 1e-4 * d[31].max(1e-6), "{far} vs {}", d[31]);
        }
    }
}
