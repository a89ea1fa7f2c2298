//! Where a sun's photons leave from (design.md section 5: photons are emitted only where they
//! can meet medium).
//!
//! A disc over the volume's bounding box wastes most photons on a thin or scattered medium
//! (a Blender smoke plume: 99% of them crossed empty space). Instead the emitter is a square
//! lattice in a plane perpendicular to the sun, upstream of the medium, of which only the
//! cells that the projection of some brick's medium covers emit: per brick, the box around
//! its positive voxels grown by the voxel that trilinear sampling reaches beyond them. The
//! density is zero outside those boxes, so a ray that crosses none of them meets no medium
//! in any distance mode: leaving out the lattice cells that no box projects onto removes
//! only photons that would have escaped untouched, and the estimate stays unbiased with the
//! power E x (marked area).
//!
//! A photon picks a marked cell uniformly by index (from two random words, so every cell's
//! probability is 1/n to within n/2^64), then a point uniformly within it; the GPU twin is
//! `emission_point` in `shaders/photon.wgsl`, draw for draw.

use glam::{DVec2, DVec3, IVec3, Vec3};
use nimbus_optics::Rng;
use nimbus_volume::{brick_local, Volume};

/// Most lattice cells over the projection's bounding rectangle (2048^2: a 4 MiB mark table,
/// one-voxel cells for any grid up to about 1200 voxels across); past it the cells double.
const MAX_LATTICE_CELLS: f64 = (1u64 << 22) as f64;

/// The emitting cells of one sun's lattice.
#[derive(Clone, Debug)]
pub struct SunEmission {
    /// World position of lattice cell (0, 0)'s lowest corner, upstream of all medium.
    pub corner: DVec3,
    /// The direction photons travel (unit).
    pub normal: DVec3,
    /// Unit vectors along the lattice's columns and rows, perpendicular to `normal`.
    pub tangent: DVec3,
    pub bitangent: DVec3,
    /// Cell edge, world units.
    pub cell: f64,
    /// The marked cells as (column, row), row by row.
    pub cells: Vec<[u32; 2]>,
}

/// A cell index uniform over `0..n` from the 64-bit word `hi:lo`: floor(word x n / 2^64).
/// The GPU twin is `emission_index_from_words` in photon.wgsl.
pub(crate) fn index_from_words(hi: u32, lo: u32, n: u32) -> u32 {
    ((((hi as u64) << 32 | lo as u64) as u128 * n as u128) >> 64) as u32
}

/// A cell index uniform over `0..n` from the next two words of `rng`, high word first.
fn uniform_index(rng: &mut Rng, n: u32) -> u32 {
    let hi = rng.next_u32();
    let lo = rng.next_u32();
    index_from_words(hi, lo, n)
}

/// Per brick holding a positive voxel, the index-space box `[lo - 1, hi + 1]` around its
/// positive voxels `lo..=hi`: trilinear sampling reads voxel v at positions within one voxel
/// of it, so outside these boxes the density is zero (the background's medium beyond the
/// grid aside, which no finite emitter covers).
fn medium_boxes(density: &Volume<f32>) -> Vec<(DVec3, DVec3)> {
    density
        .bricks()
        .filter_map(|brick| {
            let mut range: Option<(IVec3, IVec3)> = None;
            for (offset, &value) in brick.values.iter().enumerate() {
                if value > 0.0 {
                    let p = brick.origin + brick_local(offset);
                    range = Some(range.map_or((p, p), |(l, h)| (l.min(p), h.max(p))));
                }
            }
            range.map(|(l, h)| (l.as_dvec3() - 1.0, h.as_dvec3() + 1.0))
        })
        .collect()
}

/// The corners of index box `[lo, hi]`, corner n taking hi on axis a where bit a of n is set.
fn box_corners(lo: DVec3, hi: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|n| {
        DVec3::new(
            if n & 1 != 0 { hi.x } else { lo.x },
            if n & 2 != 0 { hi.y } else { lo.y },
            if n & 4 != 0 { hi.z } else { lo.z },
        )
    })
}

/// The twelve edges of a box as pairs of [`box_corners`] indices.
const BOX_EDGES: [(usize, usize); 12] =
    [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)];

/// The x range, within the strip `y0 <= y <= y1`, of the convex polygon that is the
/// projection of a parallelepiped with projected corners `p`, or None if the polygon misses
/// the strip. The polygon's edges are projections of the box's edges, so clipping all twelve
/// edges to the strip and taking their extreme x is exact (the inner ones lie inside it).
fn strip_extent(p: &[DVec2; 8], y0: f64, y1: f64) -> Option<(f64, f64)> {
    let mut range: Option<(f64, f64)> = None;
    let mut include = |x: f64| range = Some(range.map_or((x, x), |(a, b)| (a.min(x), b.max(x))));
    for &(i, j) in &BOX_EDGES {
        let (a, b) = (p[i], p[j]);
        let (ya, yb) = (a.y.min(b.y), a.y.max(b.y));
        if yb < y0 || ya > y1 {
            continue;
        }
        if yb - ya <= 0.0 {
            include(a.x);
            include(b.x);
            continue;
        }
        for y in [ya.max(y0), yb.min(y1)] {
            let t = ((y - a.y) / (b.y - a.y)).clamp(0.0, 1.0);
            include(a.x + (b.x - a.x) * t);
        }
    }
    range
}

impl SunEmission {
    /// The emitting lattice of a sun travelling along `dir` onto `density`; None when no
    /// voxel is positive.
    pub fn new(dir: Vec3, density: &Volume<f32>) -> Option<SunEmission> {
        let boxes = medium_boxes(density);
        if boxes.is_empty() {
            return None;
        }
        let transform = density.transform();
        let normal = dir.as_dvec3().normalize();
        let (tangent, bitangent) = normal.any_orthonormal_pair();
        // Each box as its corners' (tangent, bitangent) coordinates, and the extent of all.
        let mut depth = f64::INFINITY;
        let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
        let projected: Vec<[DVec2; 8]> = boxes
            .iter()
            .map(|&(a, b)| {
                box_corners(a, b).map(|c| {
                    let w = transform.to_world(c);
                    depth = depth.min(w.dot(normal));
                    let q = DVec2::new(w.dot(tangent), w.dot(bitangent));
                    lo = lo.min(q);
                    hi = hi.max(q);
                    q
                })
            })
            .collect();
        // One voxel per cell where the budget allows: about a voxel of slack around the
        // projection's outline, against the disc's whole bounding circle.
        let extent = (hi - lo).max(DVec2::splat(f64::MIN_POSITIVE));
        let mut cell = transform.voxel_size().min_element();
        while extent.x / cell * (extent.y / cell) > MAX_LATTICE_CELLS {
            cell *= 2.0;
        }
        // Rounding margin: a box whose outline lies within it of a cell's edge marks that cell.
        let eps = 1e-6 * cell;
        let origin = lo - DVec2::splat(eps);
        let columns = ((extent.x + 2.0 * eps) / cell).ceil().max(1.0) as usize;
        let rows = ((extent.y + 2.0 * eps) / cell).ceil().max(1.0) as usize;
        let mut marked = vec![false; columns * rows];
        for p in &projected {
            let p = p.map(|q| (q - origin) / cell);
            let (y_lo, y_hi) = p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), q| (a.min(q.y), b.max(q.y)));
            let first_row = ((y_lo - 1e-6).floor().max(0.0) as usize).min(rows - 1);
            let last_row = ((y_hi + 1e-6).floor().max(0.0) as usize).min(rows - 1);
            for row in first_row..=last_row {
                let Some((x0, x1)) = strip_extent(&p, row as f64 - 1e-6, (row + 1) as f64 + 1e-6) else { continue };
                let first = ((x0 - 1e-6).floor().max(0.0) as usize).min(columns - 1);
                let last = ((x1 + 1e-6).floor().max(0.0) as usize).min(columns - 1);
                marked[row * columns + first..=row * columns + last].fill(true);
            }
        }
        let cells = (0..rows)
            .flat_map(|row| (0..columns).map(move |column| (row, column)))
            .filter(|&(row, column)| marked[row * columns + column])
            .map(|(row, column)| [column as u32, row as u32])
            .collect();
        // Upstream of every box by one lattice cell, so a photon starts outside the medium.
        let corner = origin.x * tangent + origin.y * bitangent + (depth - cell) * normal;
        Some(SunEmission { corner, normal, tangent, bitangent, cell, cells })
    }

    /// The marked area, world units squared: the sun's power is E times it.
    pub fn area(&self) -> f64 {
        self.cells.len() as f64 * self.cell * self.cell
    }

    /// A photon's starting point, uniform over the marked cells (pdf 1 / area): a cell by
    /// index from two words, then (u, v) within it.
    pub fn sample_point(&self, rng: &mut Rng) -> DVec3 {
        let [column, row] = self.cells[uniform_index(rng, self.cells.len() as u32) as usize];
        let u = rng.next_vec2().as_dvec2();
        self.corner + ((column as f64 + u.x) * self.tangent + (row as f64 + u.y) * self.bitangent) * self.cell
    }

    /// Which marked cell (its index in `cells`) the sun's ray through world point `p` starts
    /// in, if any.
    pub fn cell_of(&self, p: DVec3) -> Option<usize> {
        let q = DVec2::new((p - self.corner).dot(self.tangent), (p - self.corner).dot(self.bitangent)) / self.cell;
        if q.x < 0.0 || q.y < 0.0 || q.max_element() >= u32::MAX as f64 {
            return None;
        }
        let (column, row) = (q.x as u32, q.y as u32);
        self.cells.binary_search_by_key(&(row, column), |c| (c[1], c[0])).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_indices_are_exactly_the_scaled_word() {
        for n in [1u32, 2, 3, 1000, 4_194_305, u32::MAX] {
            assert_eq!(index_from_words(0, 0, n), 0);
            assert_eq!(index_from_words(u32::MAX, u32::MAX, n), n - 1);
            // Index k begins at the word ceil(k 2^64 / n): the word before it still gives k - 1.
            for k in [1u64, n as u64 / 2, n as u64 - 1].into_iter().filter(|&k| k > 0 && k < n as u64) {
                let first = ((k as u128) << 64).div_ceil(n as u128) as u64;
                assert_eq!(index_from_words((first >> 32) as u32, first as u32, n) as u64, k, "n {n} k {k}");
                let before = first - 1;
                assert_eq!(index_from_words((before >> 32) as u32, before as u32, n) as u64, k - 1, "n {n} k {k}");
            }
        }
    }
}
