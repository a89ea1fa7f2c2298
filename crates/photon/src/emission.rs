//! Where photons leave the lights (design.md section 5: photons are emitted only where they
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
//! A point light likewise emits only into the directions in which some box lies: a table of
//! equal solid-angle cells over `sample_uniform_sphere`'s parameter square (rows in z,
//! columns in azimuth, in a frame whose equator runs through the medium, where the cells are
//! nearly square; near the poles they are thin wedges), marking each cell that the cone of
//! directions toward some box reaches, the power I x (marked solid angle).
//!
//! A photon picks a marked cell uniformly by index (from two random words, so every cell's
//! probability is 1/n to within n/2^64), then a point uniformly within it; the GPU twins are
//! `emission_point` and `emission_direction` in `shaders/photon.wgsl`, draw for draw.

use std::f64::consts::PI;

use glam::{DVec2, DVec3, IVec3, Vec2, Vec3};
use nimbus_optics::{sample_uniform_sphere, Rng};
use nimbus_volume::{brick_local, Volume};

/// Most lattice cells over the projection's bounding rectangle (2048^2: a 4 MiB mark table,
/// one-voxel cells for any grid up to about 1200 voxels across); past it the cells double.
const MAX_LATTICE_CELLS: f64 = (1u64 << 22) as f64;

/// Rows (in z) and columns (in azimuth) of a point light's direction table: cells of equal
/// solid angle, 4 pi / 2^17 sr, about 0.5 degrees across (mirrored in photon.wgsl).
pub const DIRECTION_ROWS: u32 = 256;
pub const DIRECTION_COLUMNS: u32 = 512;

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

/// The marked entries of a row-major mark table `columns` wide, as (column, row), row by row.
fn marked_cells(marked: &[bool], columns: usize) -> Vec<[u32; 2]> {
    marked.iter().enumerate().filter(|&(_, &m)| m).map(|(i, _)| [(i % columns) as u32, (i / columns) as u32]).collect()
}

/// The index of cell (column, row) in a [`marked_cells`] list, if it is there.
fn find_cell(cells: &[[u32; 2]], column: u32, row: u32) -> Option<usize> {
    cells.binary_search_by_key(&(row, column), |c| (c[1], c[0])).ok()
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
        let cells = marked_cells(&marked, columns);
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
        find_cell(&self.cells, column, row)
    }
}

/// The directions a point light's photons leave in.
#[derive(Clone, Debug)]
pub struct PointEmission {
    pub position: DVec3,
    /// The table's x, y and z axes in world space (orthonormal, right-handed).
    pub frame: [DVec3; 3],
    /// The marked direction cells as (column, row), row by row: cell (c, r) is the square
    /// [r, r + 1) / DIRECTION_ROWS x [c, c + 1) / DIRECTION_COLUMNS of
    /// `sample_uniform_sphere`'s parameter (z = 1 - 2 u.x, azimuth 2 pi u.y) in `frame`.
    pub cells: Vec<[u32; 2]>,
}

/// Boxes seen wider than this (radians, from their centre's direction) are split in eight
/// before their directions are marked: a near box's cone bounds its directions loosely.
const SPLIT_ANGLE: f64 = 0.5;
/// How many times a box is split at most; a box still seen wider than a half-space (the
/// light just beside it) marks every direction.
const MAX_SPLITS: u32 = 3;
/// Angular slack of the marking tests, radians: far below a cell, far above rounding.
const ANGLE_SLACK: f64 = 1e-6;

fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos()
}

/// Direction table geometry: per row its centre's z and sin(polar angle) and the largest
/// angle from its cells' centres to their corners; per column its centre's azimuth.
struct DirectionTable {
    row_z: Vec<f64>,
    row_sin: Vec<f64>,
    row_radius: Vec<f64>,
    column_cos: Vec<f64>,
    column_sin: Vec<f64>,
}

impl DirectionTable {
    fn new() -> DirectionTable {
        let (rows, columns) = (DIRECTION_ROWS as usize, DIRECTION_COLUMNS as usize);
        let z_of = |u: f64| 1.0 - 2.0 * u;
        let at = |z: f64, phi: f64| {
            let s = (1.0 - z * z).max(0.0).sqrt();
            DVec3::new(s * phi.cos(), s * phi.sin(), z)
        };
        let half_phi = PI / columns as f64;
        let (mut row_z, mut row_sin, mut row_radius) = (Vec::new(), Vec::new(), Vec::new());
        for r in 0..rows {
            let (z0, z1) = (z_of(r as f64 / rows as f64), z_of((r + 1) as f64 / rows as f64));
            let z = 0.5 * (z0 + z1);
            let centre = at(z, 0.0);
            // The farthest point of a cell from its centre is a corner: along a parallel the
            // angle grows with the azimuth difference, and along a meridian cos(angle) is a
            // sinusoid of the polar angle, so its minimum over a segment is at an end.
            let radius = [at(z0, half_phi), at(z1, half_phi)].iter().map(|&c| angle_between(centre, c)).fold(0.0, f64::max);
            row_z.push(z);
            row_sin.push((1.0 - z * z).max(0.0).sqrt());
            row_radius.push(radius);
        }
        let phi = |c: usize| 2.0 * PI * (c as f64 + 0.5) / columns as f64;
        DirectionTable {
            row_z,
            row_sin,
            row_radius,
            column_cos: (0..columns).map(|c| phi(c).cos()).collect(),
            column_sin: (0..columns).map(|c| phi(c).sin()).collect(),
        }
    }

    /// Marks every cell that the cone of directions within `alpha` of unit `axis` reaches
    /// (cell and cone overlap only if their centres are within alpha + the cell's radius).
    fn mark_cone(&self, marked: &mut [bool], axis: DVec3, alpha: f64) {
        let (rows, columns) = (DIRECTION_ROWS as usize, DIRECTION_COLUMNS as usize);
        let reach = alpha + self.row_radius.iter().copied().fold(0.0, f64::max) + ANGLE_SLACK;
        let polar = axis.z.clamp(-1.0, 1.0).acos();
        // Rows: the cone's polar range; u.x = (1 - z) / 2 grows as z falls.
        let row_of = |z: f64| (((1.0 - z) * 0.5 * rows as f64).floor().max(0.0) as usize).min(rows - 1);
        let (first_row, last_row) = (row_of((polar - reach).max(0.0).cos()), row_of((polar + reach).min(PI).cos()));
        // Columns: the cone's azimuth range, unless it holds a pole.
        let columns_range: Vec<usize> = if polar - reach <= 0.0 || polar + reach >= PI || reach >= 0.5 * PI {
            (0..columns).collect()
        } else {
            let width = (reach.sin() / polar.sin()).min(1.0).asin() + ANGLE_SLACK;
            let centre = axis.y.atan2(axis.x);
            let to_column = |phi: f64| (phi / (2.0 * PI) * columns as f64).floor() as i64;
            (to_column(centre - width)..=to_column(centre + width)).map(|c| c.rem_euclid(columns as i64) as usize).collect()
        };
        for row in first_row..=last_row {
            let limit = (alpha + self.row_radius[row] + ANGLE_SLACK).min(PI).cos();
            for &column in &columns_range {
                let cell = &mut marked[row * columns + column];
                if *cell {
                    continue;
                }
                let centre = DVec3::new(self.row_sin[row] * self.column_cos[column], self.row_sin[row] * self.column_sin[column], self.row_z[row]);
                if centre.dot(axis) >= limit {
                    *cell = true;
                }
            }
        }
    }
}

impl PointEmission {
    /// The directions from `position` in which some brick's medium of `density` lies.
    pub fn new(position: DVec3, density: &Volume<f32>) -> PointEmission {
        let (rows, columns) = (DIRECTION_ROWS as usize, DIRECTION_COLUMNS as usize);
        let transform = density.transform();
        let light = transform.to_index(position);
        let table = DirectionTable::new();
        let mut marked = vec![false; rows * columns];
        let mut boxes: Vec<(DVec3, DVec3, u32)> = medium_boxes(density).into_iter().map(|(lo, hi)| (lo, hi, 0)).collect();
        // The table's poles perpendicular to the direction of the medium's middle.
        let (lo, hi) = boxes.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), &(l, h, _)| (a.min(l), b.max(h)));
        let toward = (transform.to_world(0.5 * (lo + hi)) - position).try_normalize().unwrap_or(DVec3::Z);
        let (z_axis, x_axis) = toward.any_orthonormal_pair();
        let frame = [x_axis, z_axis.cross(x_axis), z_axis];
        let to_table = |d: DVec3| DVec3::new(d.dot(frame[0]), d.dot(frame[1]), d.dot(frame[2]));
        while let Some((lo, hi, splits)) = boxes.pop() {
            if light.cmpge(lo).all() && light.cmple(hi).all() {
                // Inside (or on) a box: every direction starts in medium.
                marked.fill(true);
                break;
            }
            let axis = (transform.to_world(0.5 * (lo + hi)) - position).normalize();
            let alpha = box_corners(lo, hi).iter().map(|&c| angle_between(axis, (transform.to_world(c) - position).normalize())).fold(0.0, f64::max);
            if alpha > SPLIT_ANGLE && splits < MAX_SPLITS {
                let mid = 0.5 * (lo + hi);
                for n in 0..8 {
                    let pick = |bit: usize, a: f64, b: f64| if n & bit != 0 { b } else { a };
                    let sub_lo = DVec3::new(pick(1, lo.x, mid.x), pick(2, lo.y, mid.y), pick(4, lo.z, mid.z));
                    let sub_hi = DVec3::new(pick(1, mid.x, hi.x), pick(2, mid.y, hi.y), pick(4, mid.z, hi.z));
                    boxes.push((sub_lo, sub_hi, splits + 1));
                }
                continue;
            }
            // The box's directions lie within alpha of the axis (the cone of half-angle alpha
            // is convex for alpha < pi/2 and holds the box's corners, so the whole box);
            // wider, they may not.
            if alpha >= 0.5 * PI - ANGLE_SLACK {
                marked.fill(true);
                break;
            }
            table.mark_cone(&mut marked, to_table(axis), alpha);
        }
        let cells = marked_cells(&marked, columns);
        PointEmission { position, frame, cells }
    }

    /// The marked solid angle, steradians: the light's power is I times it.
    pub fn solid_angle(&self) -> f64 {
        4.0 * PI * self.cells.len() as f64 / (DIRECTION_ROWS as f64 * DIRECTION_COLUMNS as f64)
    }

    /// A photon's direction, uniform over the marked cells (pdf 1 / solid angle).
    pub fn sample_direction(&self, rng: &mut Rng) -> DVec3 {
        let [column, row] = self.cells[uniform_index(rng, self.cells.len() as u32) as usize];
        let u = rng.next_vec2();
        let square = Vec2::new((row as f32 + u.x) / DIRECTION_ROWS as f32, (column as f32 + u.y) / DIRECTION_COLUMNS as f32);
        let d = sample_uniform_sphere(square).as_dvec3();
        (d.x * self.frame[0] + d.y * self.frame[1] + d.z * self.frame[2]).normalize()
    }

    /// Which marked cell (its index in `cells`) direction `dir` lies in, if any.
    pub fn cell_of(&self, dir: DVec3) -> Option<usize> {
        let dir = DVec3::new(dir.dot(self.frame[0]), dir.dot(self.frame[1]), dir.dot(self.frame[2])).normalize();
        let u = ((1.0 - dir.z) * 0.5).clamp(0.0, 1.0);
        let v = (dir.y.atan2(dir.x) / (2.0 * PI)).rem_euclid(1.0);
        let row = ((u * DIRECTION_ROWS as f64) as u32).min(DIRECTION_ROWS - 1);
        let column = ((v * DIRECTION_COLUMNS as f64) as u32).min(DIRECTION_COLUMNS - 1);
        find_cell(&self.cells, column, row)
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
