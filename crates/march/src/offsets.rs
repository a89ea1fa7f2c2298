//! The offset noise baked once per render on a lattice anchored in world space, read by
//! trilinear interpolation at each sample (both backends; see the crate doc).
//!
//! Node `n` (three i64) sits at world position `n * noise_scale / nodes_per_scale` and holds
//! `fbm3_vec(n / nodes_per_scale) * offset_noise`, the exact displacement there: the same
//! world point always gets the same nodes and values, whatever the camera, the bounds or
//! the frame. Only the noise-lattice bricks (8^3 cells, 9^3 nodes with the apron, the
//! layout's [`Lattice`]) within the noise's reach ([`NOISE_REACH`] amplitudes per world
//! axis) of a non-empty cell of the medium's majorant grid are baked. A sample further from
//! every such cell reads no offset, and needs none: displaced by at most the reach, it would
//! land outside them too, where the density is zero.

use std::collections::HashMap;
use std::sync::OnceLock;

use glam::{DAffine3, DMat3, DVec3, IVec3, Vec3, Vec4};
use nimbus_optics::noise::{fbm3_vec, fbm3_vec_block, fbm3_vec_grid};
use nimbus_volume::{MajorantGrid, Volume, BRICK_LOG2};

use crate::cpu::{index_reach, NOISE_REACH};
use crate::layout::{CellBox, DensityPoint, Lattice, Layer, MarchVolume, Visit, BRICK_VALUES};
use crate::simd::{Arith, Unfused, EDGE};
use crate::MarchParams;

/// A brick's own points per axis (its 9^3 less the apron, which its neighbours own).
const CORE: i32 = 1 << BRICK_LOG2;
const CORE_VALUES: usize = (CORE * CORE * CORE) as usize;

/// The baked displacement field.
pub(crate) struct Offsets {
    pub lattice: Lattice<Vec4>,
    /// World node index of the lattice's index 0 (a multiple of the brick size), so lattice
    /// indices stay small however far from the origin the volume lies.
    pub anchor: DVec3,
    /// Nodes per world unit.
    pub per_world: f64,
}

impl Offsets {
    /// The field within the noise's reach of the non-empty cells of `medium` (a majorant
    /// grid over `density`'s index space, not dilated for the noise), `nodes_per_scale`
    /// nodes per `noise_scale`.
    pub fn bake(density: &Volume<f32>, medium: &MajorantGrid, params: &MarchParams, nodes_per_scale: u32) -> Offsets {
        let per_world = nodes_per_scale as f64 / params.noise_scale;
        let reach = NOISE_REACH * params.offset_noise * per_world;
        let to_world = density.transform().index_to_world();
        let cell = medium.cell_size() as f64;
        // Each non-empty cell's world box grown by the reach, in world node coordinates.
        let mut boxes = Vec::new();
        for (lo, m) in medium.cells() {
            if !(m > 0.0) {
                continue;
            }
            let lo = lo.as_dvec3();
            let (mut a, mut b) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for k in 0..8 {
                let corner = lo + DVec3::new((k >> 2 & 1) as f64, (k >> 1 & 1) as f64, (k & 1) as f64) * cell;
                let w = to_world.transform_point3(corner) * per_world;
                (a, b) = (a.min(w), b.max(w));
            }
            boxes.push(((a - reach).floor(), (b + reach).floor()));
        }
        let brick = (1u32 << BRICK_LOG2) as f64;
        let anchor = boxes.iter().fold(DVec3::INFINITY, |m, b| m.min(b.0));
        let anchor = if anchor.is_finite() { (anchor / brick).floor() * brick } else { DVec3::ZERO };
        // Neighbouring cells' boxes share most of their bricks: Lattice::build marks each
        // brick once, so the repeats need no sort here.
        let mut bricks = Vec::new();
        for (a, b) in boxes {
            let (lo, hi) = (((a - anchor) / brick).floor().as_ivec3(), ((b - anchor) / brick).floor().as_ivec3());
            for x in lo.x..=hi.x {
                for y in lo.y..=hi.y {
                    for z in lo.z..=hi.z {
                        bricks.push(IVec3::new(x, y, z));
                    }
                }
            }
        }
        let (octaves, seed, amplitude) = (params.noise_octaves, params.seed as u32, params.offset_noise);
        let world_to_index = DAffine3 { matrix3: DMat3::from_diagonal(DVec3::splat(per_world)), translation: -anchor };
        let inv_nodes = 1.0 / nodes_per_scale as f64;
        let lattice = Lattice::build(world_to_index, &bricks, Vec4::ZERO, |origin, out| {
            let n = origin.as_dvec3() + anchor;
            let mut fbm = [Vec3::ZERO; EDGE * EDGE * EDGE];
            fbm3_vec_block([n.x as i64, n.y as i64, n.z as i64], EDGE, inv_nodes, octaves, seed, &mut fbm);
            for (o, v) in out.iter_mut().zip(fbm) {
                *o = (v.as_dvec3() * amplitude).as_vec3().extend(0.0);
            }
            Visit::ALL
        });
        Offsets { lattice, anchor, per_world }
    }

    /// The displacement at world position `x`, interpolated.
    #[inline(always)]
    pub fn at<A: Arith>(&self, arith: A, x: DVec3) -> DVec3 {
        self.at_lattice(arith, self.to_lattice(x))
    }

    /// World position `x` in the lattice's index space.
    #[inline(always)]
    pub fn to_lattice(&self, x: DVec3) -> DVec3 {
        x * self.per_world - self.anchor
    }

    /// The displacement at lattice index-space position `q`, interpolated.
    #[inline(always)]
    pub fn at_lattice<A: Arith>(&self, arith: A, q: DVec3) -> DVec3 {
        self.lattice.sample(arith, q).truncate().as_dvec3()
    }
}

impl<T: DensityPoint> MarchVolume<T> {
    /// The medium displaced by the offset noise ([`crate::NoiseEval::Displaced`]): at each
    /// point `p` of the density lattice (world `x`), this layout's point at `x + o(x)`, `o`
    /// the exact fBm at `x` ([`offset`]), with the cache lattices of their own read there
    /// too and added in (so the result holds the whole cache in its one lattice). A march
    /// over it is the march without noise. What it changes against reading the offsets at
    /// each sample is that the displaced medium is interpolated between the points of the
    /// density lattice, not the medium between displaced positions: a resampling, which
    /// blurs the density by up to a cell (the error against the exact noise in
    /// docs/benchmarks.md, "Offset noise").
    ///
    /// Its bricks are those whose points lie within the noise's reach ([`NOISE_REACH`]) of
    /// the cells this layout visits (anywhere else a point reads zero density), each baked
    /// when a march first reads it ([`Lattice::build_lazy`]): rays stop within a few voxels
    /// of a thick medium's surface and never read most of its inside.
    ///
    /// [`offset`]: crate::cpu::offset
    pub fn displaced(self, params: &MarchParams) -> MarchVolume<T> {
        let to_index = *self.density.world_to_index();
        let to_world = to_index.inverse();
        let amplitude = params.offset_noise;
        let reach = index_reach(&to_index, NOISE_REACH * amplitude).ceil().as_ivec3();
        let edge = IVec3::splat(1 << BRICK_LOG2);
        // Per brick, the box of its points (index, inclusive) that can read positive density,
        // and one point more: a cell with a corner that can interpolates the cache from all
        // eight. Its other points hold the background, with no fBm taken for them.
        let mut boxes: HashMap<IVec3, (IVec3, IVec3)> = HashMap::new();
        for (origin, visit) in self.density.bricks() {
            let CellBox { lo, hi } = visit.cells;
            if (0..3).any(|a| lo[a] >= hi[a]) {
                continue;
            }
            // Bricks b hold the points b * 8 to b * 8 + 8 per axis.
            let (a, b) = (origin + IVec3::from(lo.map(i32::from)) - reach - 1, origin + IVec3::from(hi.map(i32::from)) + reach + 1);
            let (first, last) = ((a - 1).div_euclid(edge), b.div_euclid(edge));
            for x in first.x..=last.x {
                for y in first.y..=last.y {
                    for z in first.z..=last.z {
                        let c = IVec3::new(x, y, z);
                        let (l, h) = (a.max(c * edge), b.min(c * edge + edge));
                        boxes.entry(c).and_modify(|(bl, bh)| (*bl, *bh) = (bl.min(l), bh.max(h))).or_insert((l, h));
                    }
                }
            }
        }
        let bricks: Vec<IVec3> = boxes.keys().copied().collect();
        let (scale, octaves, seed) = (params.noise_scale, params.noise_octaves, params.seed as u32);
        // On an axis-aligned lattice the fBm is taken a box at a time, its hashes shared.
        let m = to_world.matrix3;
        let diagonal = DVec3::new(m.x_axis.x, m.y_axis.y, m.z_axis.z);
        let aligned = m == DMat3::from_diagonal(diagonal) && diagonal.cmpgt(DVec3::ZERO).all();
        let background = self.density.background();
        // A brick's 9^3 points are its own 8^3 and the first ones of its seven neighbours
        // above (the apron), so each point is baked once, in the brick that owns it (its
        // core), when the first brick that holds it is read: baking each brick's apron again
        // cost 9^3 / 8^3 = 1.42x the points. A point a core's box leaves out holds the
        // background, as it would in any brick's box (every box holds all the points within
        // reach of positive density and one more).
        let core = move |c: IVec3| -> Box<[T]> {
            let origin = c << BRICK_LOG2;
            let mut out = vec![background; CORE_VALUES].into_boxed_slice();
            let (lo, hi) = boxes[&c];
            // The box, relative to the core, and the fBm at its points (x-major, z fastest).
            let (lo, hi) = (lo - origin, (hi - origin).min(IVec3::splat(CORE - 1)));
            if (0..3).any(|a| lo[a] > hi[a]) {
                return out;
            }
            let n = (hi - lo + 1).to_array().map(|k| k as usize);
            let mut fbm = [Vec3::ZERO; CORE_VALUES];
            let fbm = &mut fbm[..n[0] * n[1] * n[2]];
            if aligned {
                // Point p lies at world diagonal p + t = (p + t / diagonal) diagonal.
                let start = (origin + lo).as_dvec3() + to_world.translation / diagonal;
                fbm3_vec_grid(start.to_array(), (diagonal / scale).to_array(), n, octaves, seed, fbm);
            } else {
                for (k, f) in fbm.iter_mut().enumerate() {
                    let j = IVec3::new((k / (n[1] * n[2])) as i32, (k / n[2] % n[1]) as i32, (k % n[2]) as i32);
                    *f = fbm3_vec(to_world.transform_point3((origin + lo + j).as_dvec3()) / scale, octaves, seed);
                }
            }
            let mut k = 0;
            for x in lo.x..=hi.x {
                for y in lo.y..=hi.y {
                    for z in lo.z..=hi.z {
                        let p = (origin + IVec3::new(x, y, z)).as_dvec3();
                        let shift = fbm[k].as_dvec3() * amplitude;
                        k += 1;
                        let mut v = self.density.sample(Unfused, p + to_index.transform_vector3(shift));
                        // Every point, lit or not: a sample between points interpolates the cache too.
                        for (lattice, layer) in &self.others {
                            let li = lattice.sample(Unfused, lattice.world_to_index().transform_point3(to_world.transform_point3(p) + shift));
                            v.add_li(li.truncate(), *layer == Layer::Multiple);
                        }
                        out[((x * CORE + y) * CORE + z) as usize] = v;
                    }
                }
            }
            out
        };
        let cores: HashMap<IVec3, OnceLock<Box<[T]>>> = bricks.iter().map(|&c| (c, OnceLock::new())).collect();
        let fill = move |origin: IVec3, out: &mut [T]| {
            let c = origin >> BRICK_LOG2;
            let mut d = [0.0f32; BRICK_VALUES];
            for corner in 0..8 {
                let step = IVec3::new(corner >> 2 & 1, corner >> 1 & 1, corner & 1);
                // The points of this brick the neighbour at `step` owns: its first along each
                // axis stepped to, all eight along the others.
                let (first, last) = (step * CORE, IVec3::splat(CORE - 1) + step);
                let neighbour = cores.get(&(c + step)).map(|cell| cell.get_or_init(|| core(c + step)));
                for x in first.x..=last.x {
                    for y in first.y..=last.y {
                        for z in first.z..=last.z {
                            let l = IVec3::new(x, y, z);
                            let i = ((x as usize * EDGE) + y as usize) * EDGE + z as usize;
                            let v = neighbour.map_or(background, |points| {
                                let j = l - step * CORE;
                                points[((j.x * CORE + j.y) * CORE + j.z) as usize]
                            });
                            (out[i], d[i]) = (v, v.density());
                        }
                    }
                }
            }
            Visit::of(&d)
        };
        MarchVolume { density: Lattice::build_lazy(to_index, &bricks, background, Box::new(fill)), others: Vec::new() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::scenes::{camera, cloud, params};
    use crate::cpu::offset;
    use crate::NoiseEval;

    /// The baked field against the exact fBm at `count` points spread over the cells that
    /// hold medium (those of the majorant grid with a positive bound): the largest
    /// and the RMS difference of a component, relative to the amplitude, and the node count.
    fn baked_against_exact(density: &Volume<f32>, params: &MarchParams, nodes: u32, count: usize) -> (f64, f64, usize) {
        let majorant = MajorantGrid::build(density);
        let offsets = Offsets::bake(density, &majorant, params, nodes);
        let (lo, hi) = density.world_bounds().unwrap();
        let to_index = density.transform().world_to_index();
        let (mut worst, mut sq, mut n) = (0.0f64, 0.0f64, 0usize);
        let mut rng = nimbus_optics::Rng::with_domain(1, 2, 3);
        while n < count {
            let x = lo + (hi - lo) * DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 1.2 - (hi - lo) * 0.1;
            if !(majorant.at(to_index.transform_point3(x)) > 0.0) {
                continue;
            }
            let d = (offsets.at(Unfused, x) - offset(params, x)) / params.offset_noise;
            worst = worst.max(d.abs().max_element());
            sq += d.length_squared() / 3.0;
            n += 1;
        }
        (worst, (sq / n as f64).sqrt(), offsets.lattice.values().len())
    }

    #[test]
    fn the_baked_field_holds_the_fbm_at_its_nodes() {
        for centre in [DVec3::ZERO, DVec3::new(1.0e6, -3.0e5, 2.0e6)] {
            let density = cloud(16, 3.0, centre);
            let p = MarchParams { offset_noise: 0.05, noise_scale: 0.4, ..params(camera(centre, 8, 8)) };
            let offsets = Offsets::bake(&density, &MajorantGrid::build(&density), &p, 8);
            let h = p.noise_scale / 8.0;
            // Nodes of the world lattice near the cloud, read back through the lattice.
            let base = (centre / h).round();
            for k in 0..64 {
                let n = base + DVec3::new((k % 4) as f64, (k / 4 % 4) as f64, (k / 16) as f64) - 2.0;
                let (got, want) = (offsets.at(Unfused, n * h), offset(&p, n * h));
                assert!((got - want).abs().max_element() <= 1e-6 * p.offset_noise, "{centre}: node {n}: {got} vs {want}");
            }
            // Within the reach the coverage and the majorant's dilation assume.
            let largest = offsets.lattice.values().iter().fold(0.0f32, |m, v| m.max(v.truncate().abs().max_element())) as f64;
            assert!(largest > 0.2 * p.offset_noise && largest <= NOISE_REACH * p.offset_noise, "largest {largest}");
        }
    }

    #[test]
    fn the_baked_field_stays_near_the_exact_fbm() {
        // Figures for docs/benchmarks.md (the default lattice, 8 nodes per scale, asserted).
        for centre in [DVec3::ZERO, DVec3::new(1.0e6, -3.0e5, 2.0e6)] {
            let density = cloud(24, 3.0, centre);
            let p = MarchParams { offset_noise: 0.1, noise_scale: 0.4, ..params(camera(centre, 8, 8)) };
            for nodes in [4, 8, 16] {
                let (worst, rms, count) = baked_against_exact(&density, &p, nodes, 20_000);
                eprintln!("centre {centre}, {nodes} nodes per scale ({count} nodes): baked - exact, of the amplitude: max {worst:.4}, RMS {rms:.4}");
                if nodes == NoiseEval::BAKED_NODES {
                    assert!(worst < 0.25 && rms < 0.06, "max {worst}, RMS {rms}");
                }
            }
        }
    }

    #[test]
    fn baked_noise_renders_as_exact_noise_does_near_the_origin_and_far_from_it() {
        use crate::cpu::scenes::{cache_for, cache_on_density_lattice};
        use crate::render_cpu;
        for centre in [DVec3::ZERO, DVec3::new(1.0e6, -3.0e5, 2.0e6)] {
            let density = cloud(24, 3.0, centre);
            // A cache on lattices of its own (read at the displaced points and folded into
            // the displaced layout) and one fused into the density lattice.
            for (name, cache) in [("own lattices", cache_for(&density)), ("fused", cache_on_density_lattice(&density, 1.0, 4.0))] {
                let p = MarchParams { offset_noise: 0.1, noise_scale: 0.4, spp: 2, ..params(camera(centre, 48, 36)) };
                let exact = render_cpu(&density, &cache, &MarchParams { noise_eval: NoiseEval::Exact, ..p.clone() }).unwrap();
                let plain = render_cpu(&density, &cache, &MarchParams { offset_noise: 0.0, ..p.clone() }).unwrap();
                // Relative RMSE of the colour over covered pixels, and the largest alpha difference.
                let rmse = |a: &crate::Image, b: &crate::Image| {
                    let (mut sq, mut sum, mut n, mut alpha) = (0.0f64, 0.0f64, 0, 0.0f32);
                    for (x, y) in a.rgba.iter().zip(&b.rgba) {
                        assert!(x.is_finite());
                        alpha = alpha.max((x.w - y.w).abs());
                        if y.w > 0.01 {
                            sq += (*x - *y).truncate().length_squared() as f64 / 3.0;
                            sum += y.truncate().element_sum() as f64 / 3.0;
                            n += 1;
                        }
                    }
                    assert!(n > 200, "{n} covered pixels");
                    ((sq / n as f64).sqrt() / (sum / n as f64), alpha)
                };
                let (moved, _) = rmse(&plain, &exact);
                assert!(moved > 0.02, "the noise shows");
                for eval in [NoiseEval::Baked { nodes: 4 }, NoiseEval::Displaced] {
                    let image = render_cpu(&density, &cache, &MarchParams { noise_eval: eval, ..p.clone() }).unwrap();
                    let (error, alpha) = rmse(&image, &exact);
                    eprintln!("centre {centre}, {name}, {eval:?}: against exact noise {error:.5} (alpha {alpha:.4}), no noise against exact {moved:.5}");
                    // Measured near the origin, own lattices: offsets per sample 0.0050,
                    // displaced medium 0.0127 (its resampling blurs the density by up to a
                    // cell), against the noise's own 0.0289.
                    let bound = if eval == NoiseEval::Displaced { 0.5 } else { 0.25 };
                    assert!(error < bound * moved, "{eval:?}: {error}, noise {moved}");
                    assert!(alpha < 0.05, "{eval:?}: alpha {alpha}");
                }
            }
        }
    }

    #[test]
    fn the_displaced_medium_holds_the_medium_at_the_displaced_points() {
        use crate::cpu::scenes::cache_for;
        use crate::layout::DensityPoint;
        use nimbus_volume::Transform;
        let straight = cloud(24, 3.0, DVec3::new(1.0e6, -3.0e5, 2.0e6));
        // The same voxels on a rotated lattice: the fBm taken point by point, not by boxes.
        let rotation = DAffine3::from_rotation_z(0.3) * DAffine3::from_rotation_x(-0.2);
        let mut turned = Volume::new(Transform::new(straight.transform().index_to_world() * rotation).unwrap(), 0.0f32);
        for brick in straight.bricks() {
            for (i, &v) in brick.values.iter().enumerate() {
                turned.set(brick.origin + nimbus_volume::brick_local(i), v);
            }
        }
        for density in [&straight, &turned] {
            // Six voxels of amplitude: the displacement reaches well past the point the
            // cache adds around the medium.
            let p = MarchParams { offset_noise: 0.6, noise_scale: 2.4, ..params(camera(DVec3::ZERO, 8, 8)) };
            // Li on lattices of its own, folded into the displaced points.
            let cache = cache_for(density);
            let source = MarchVolume::<[Vec4; 2]>::new(density, &cache, p.medium.albedo).unwrap();
            let displaced = MarchVolume::<[Vec4; 2]>::new(density, &cache, p.medium.albedo).unwrap().displaced(&p);
            assert!(displaced.others.is_empty() && !source.others.is_empty());
            let (to_index, to_world) = (*source.density.world_to_index(), source.density.world_to_index().inverse());
            let (mut positive, mut points) = (0, 0);
            let mut check = |q: DVec3, got: [Vec4; 2]| {
                let shift = offset(&p, to_world.transform_point3(q));
                let mut want = source.density.sample(Unfused, q + to_index.transform_vector3(shift));
                for (lattice, layer) in &source.others {
                    let li = lattice.sample(Unfused, lattice.world_to_index().transform_point3(to_world.transform_point3(q) + shift));
                    want.add_li(li.truncate(), *layer == Layer::Multiple);
                }
                assert!((got.density().max(0.0) - want.density().max(0.0)).abs() <= 1e-4 * want.density().abs().max(1.0), "{q}: {} vs {}", got.density(), want.density());
                if want.density() > 0.0 {
                    let near = |a: Vec4, b: Vec4| (a - b).abs().max_element() <= 1e-4 * b.abs().max_element().max(1e-3);
                    assert!(near(got.single(), want.single()) && near(got.multiple(), want.multiple()), "{q}: {got:?} vs {want:?}");
                    positive += 1;
                }
                points += 1;
            };
            // Every point of the bricks baked and of a brick around them, where the layout
            // reads the background.
            let (lo, hi) = displaced.density.bricks().fold((IVec3::MAX, IVec3::MIN), |(l, h), (o, _)| (l.min(o - 8), h.max(o + 16)));
            for x in lo.x..=hi.x {
                for y in lo.y..=hi.y {
                    for z in lo.z..=hi.z {
                        let q = IVec3::new(x, y, z).as_dvec3();
                        check(q, displaced.density.sample(Unfused, q));
                    }
                }
            }
            // And every point each brick stores, its apron (which its neighbours above own)
            // included: a sample between bricks interpolates toward those.
            let (table, first, dims) = displaced.density.table();
            for (i, &slot) in table.iter().enumerate().filter(|(_, &slot)| slot != u32::MAX) {
                let (yz, z) = (i / dims.z as usize, i % dims.z as usize);
                let origin = (first + IVec3::new((yz / dims.y as usize) as i32, (yz % dims.y as usize) as i32, z as i32)) << BRICK_LOG2;
                for (k, &got) in displaced.density.brick(slot).iter().enumerate() {
                    let l = IVec3::new((k / (EDGE * EDGE)) as i32, (k / EDGE % EDGE) as i32, (k % EDGE) as i32);
                    check((origin + l).as_dvec3(), got);
                }
            }
            eprintln!("{points} displaced points, {positive} with density");
            assert!(positive > 1000, "{positive} points with density");
        }
    }

    #[test]
    fn the_same_world_point_gets_the_same_offset_whatever_the_bounds() {
        // Two volumes of different extent (so different bricks and anchors) over one region.
        let small = cloud(12, 3.0, DVec3::ZERO);
        let large = cloud(32, 3.0, DVec3::new(0.2, -0.1, 0.3));
        let p = MarchParams { offset_noise: 0.05, noise_scale: 0.4, ..params(camera(DVec3::ZERO, 8, 8)) };
        let a = Offsets::bake(&small, &MajorantGrid::build(&small), &p, 8);
        let b = Offsets::bake(&large, &MajorantGrid::build(&large), &p, 8);
        assert_ne!(a.anchor, b.anchor);
        for k in 0..1000 {
            let x = DVec3::new((k as f64 * 0.0137) % 0.5, (k as f64 * 0.0291) % 0.5, (k as f64 * 0.0071) % 0.5) - 0.25;
            let (u, v) = (a.at(Unfused, x), b.at(Unfused, x));
            assert!((u - v).abs().max_element() <= 1e-6 * p.offset_noise, "{x}: {u} vs {v}");
        }
    }
}
