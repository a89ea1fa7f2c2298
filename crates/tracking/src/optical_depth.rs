//! The optical depth toward a sun, tabled once on a light-aligned lattice: single scattering
//! and next-event estimation read it instead of integrating a shadow ray per point, so
//! their cost is O(voxels) per light rather than O(voxels x ray length).
//!
//! # The lattice
//!
//! Rays run parallel to the sun through the density's index space. They pass through the
//! nodes of a 2D lattice spaced `across` density voxels on the two index axes other than the
//! one the sun's direction leans on most (its dominant axis), and along each ray nodes sit
//! every `along` voxels of that dominant axis. So the lattice is the density lattice sheared
//! along the light: the map from lattice index to world is affine, and the table is an
//! ordinary sparse [`Volume`] whose [`Transform`] carries the shear, looked up trilinearly
//! (bilinear across rays, linear along them). Where the sun falls along an index axis the
//! shear vanishes and, the lattice's origin being the density's, every density node is a
//! lattice node: the table then holds exactly what a shadow ray from that node integrates.
//!
//! # What a node holds
//!
//! The transmittance toward the light, exp(-optical depth), the optical depth
//! `extinction * integral density` integrated cell by cell through the trilinear density:
//! within one cell the density along a ray is a cubic in t, integrated in closed form (what
//! composite Simpson panels split at voxel boundaries also integrate exactly, as
//! `MediumRay::optical_depth` does, up to rounding), so a node's value is exact whatever the
//! lattice spacing; only reading between nodes interpolates.
//!
//! Across the rays, what is interpolated depends on the lattice. Where the sun falls along an
//! index axis the lattice is unsheared: every 2 x 2 block of rays lies in one column of
//! density cells, the trilinear density is bilinear across the rays at every height, and so
//! is the optical depth, its integral along them. Optical depth is then interpolated, and
//! the lookup is exact. Interpolating transmittance there is the chord of a convex exp
//! across a depth gradient, bright wherever the depth changes across a cell: a ball of
//! particles optically thick within a voxel (up to 69 a voxel, the default sun straight down)
//! came out 1.7% bright in single scattering in the mean, 2.7% relative RMSE, against 0.45%
//! and 1.1% (as shadow rays give) with the depth interpolated (docs/benchmarks.md, "Dense
//! media"). Where the lattice is sheared, rays cross the cells' faces at different places and
//! the depth across them is not bilinear: at a lit surface it bends convexly (the depth grows
//! as the square of the distance into a density ramp), interpolated depth reads dark (the
//! same ball under an oblique sun: 0.991 of the reference's mean, shadow rays 0.998) and
//! interpolated transmittance, whose errors of both signs cancel, is kept (1.001); on the
//! bundled cloud interpolated depth had made the path-traced multiple scattering 0.4% darker
//! than shadow rays did (image mean 0.990 against 0.994, two seeds). Interpolated
//! transmittance is also unbiased for a shadow edge that falls anywhere between the rays.
//!
//! Negative density (ringing in third-party grids) counts as empty, as in every tracker
//! here, by clamping the cell's corners.
//!
//! # What is stored
//!
//! Only lattice bricks where a lookup can land: those covering, conservatively, the region
//! where the trilinear density is non-zero (each non-empty density brick's interpolation
//! footprint). Upstream of a ray's first stored node the ray meets no medium, so each ray is
//! integrated from there. A ray stops integrating once its optical depth passes
//! `opaque_depth`: every node beyond keeps that depth, which callers read as black (a
//! transmittance below their cut-off).

use glam::{DAffine3, DMat3, DVec3, IVec3, Vec3};
use nimbus_optics::{Light, Rng};
use nimbus_volume::{lattice_cell, brick_offset, brick_origin, Transform, Volume, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

use crate::DensityMedium;

/// How far the eight nodes around a point stray from the value interpolated between them
/// (their mean absolute deviation from it, weighted as the interpolation weighs them) beyond
/// which a lookup no longer trusts the interpolation alone, and past which it trusts the
/// caller's shadow ray alone ([`OpticalDepthVolume::lookup`]); in between the two are
/// blended. The measure is zero at a node, where the table is exact, and continuous across
/// cell faces, so the GPU's f32 lattice coordinates (a point on a face lands in either cell)
/// and its table, a few 1e-7 off the CPU's, give the CPU's answer to that order, not another
/// branch. Where a medium is optically thick within a voxel its lit surface and its
/// terminator lie inside one lattice cell, and interpolating across them lit the far side: a
/// ball of optical depth 250 a voxel came out 26% bright in multiple scattering with [0.1,
/// 0.15] (0.95 with shadow rays).
///
/// This is the paths' next-event estimates' spread (issue #47, 2026-12-07). They had kept
/// [0.1, 0.15], which on the bundled scenes changed nothing beyond their noise, but on scenes
/// drawn by `nimbus-scene --random` (dense shells and clumps of 2 to 16 optical depths a
/// voxel) made multiple scattering 1-2% bright in the mean: seed 20261207042 2.1% bright and
/// 2.6% off the reference, 0.65% and 1.2% with this spread, 0.39% and 0.7% with shadow rays
/// at every lookup. It costs the bundled scenes' bakes 17-21% more CPU time and the
/// Cloud1-class bake 38% (docs/benchmarks.md). Between the two the paths trace the ray with
/// the blend's weight as its probability ([`TabledTransmittance::sample`]): 3-13% of that
/// back. Single scattering takes a lower one ([`SINGLE_SPREAD`]).
pub const TABLED_SPREAD: [f32; 2] = [0.02, 0.04];

/// [`TABLED_SPREAD`] for single scattering: one lookup per cache node, the image's direct
/// light, where what the interpolation misses shows undiluted, and a shadow ray costs little
/// beside the paths. At [0.02, 0.04] (issue #30), under an oblique sun (a sheared lattice,
/// transmittance interpolated across the rays), a ball optically thick within a voxel came out
/// 0.63% (21 optical depths a voxel) and 1.58% (210) off the reference, as shadow rays give
/// (0.60%, 1.57%), against 0.94% and 2.15% at [0.1, 0.15]. Lower still (2026-12-07):
/// `nimbus-scene --random 20261207039` (lumps on sheared voxels 1:1.87, a sun overhead),
/// Li_single on a lattice of a quarter voxel against a brute-force march: 0.62% off (mean
/// 1.0034) at [0.02, 0.04], 0.34% (1.0019) at this, 0.28% with shadow rays at every node;
/// its single stage 3.3 -> 5.2 s.
pub const SINGLE_SPREAD: [f32; 2] = [0.005, 0.01];

/// Values a stored lattice brick holds: each node's transmittance, then each node's depth
/// rate (extinction x density x node step), both in [`brick_offset`] order. The GPU's node
/// buffer has the same layout.
pub const TABLE_BRICK_VALUES: usize = 2 * BRICK_VOXELS;

/// Below this optical depth over one node step (both nodes' depth rates together), the
/// density at the nodes says nothing of the shape between them (a ray grazing a feature
/// between two empty nodes): the profile blends into the plain exponential, so that it is
/// continuous in the nodes' values and f32 rounding of near-zero densities changes nothing.
pub const ALONG_RAY_FLOOR: f32 = 1e-3;

/// Transmittance at fraction `u` of the way from a ray's node k (transmittance `t0`, depth
/// rate `d0`: extinction x density x node step) to node k + 1 (`t1`, `d1`): the nodes' exact
/// optical depth between them, `ln(t0 / t1)`, spread along the ray as the integral of the
/// density interpolated linearly between the nodes. Interpolating the transmittance linearly
/// instead is right only where the depth between the nodes is small: where a ray enters a
/// medium optically thick within one node step (a thin dense sheet, or flat voxels, whose
/// dominant axis sets the step), the transmittance falls as exp(-c s^2), concave, and the
/// chord lies below it (a sheet of 6 x 0.01 voxels under a grazing sun came out 0.9% dark in
/// single scattering; 0.18% now, 0.09% with shadow rays).
#[inline]
pub fn along_ray(t0: f32, t1: f32, d0: f32, d1: f32, u: f32) -> f32 {
    let depth = (t0.max(f32::MIN_POSITIVE) / t1.max(f32::MIN_POSITIVE)).ln().max(0.0);
    let shape = (d0 * u + 0.5 * (d1 - d0) * u * u + ALONG_RAY_FLOOR * u) / (0.5 * (d0 + d1) + ALONG_RAY_FLOOR);
    t0 * (-depth * shape).exp()
}

/// A light table's answer at a point: the interpolated transmittance and the weight the
/// caller's own shadow ray takes beside it (0 where the nodes agree, 1 across a shadow edge
/// sharper than the lattice).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TabledTransmittance {
    pub table: f64,
    pub ray_weight: f64,
}

impl TabledTransmittance {
    /// The transmittance, tracing `ray` only where the table asks for it.
    #[inline]
    pub fn resolve(self, ray: impl FnOnce() -> f64) -> f64 {
        if self.ray_weight <= 0.0 {
            self.table
        } else if self.ray_weight >= 1.0 {
            ray()
        } else {
            self.table + self.ray_weight * (ray() - self.table)
        }
    }

    /// The transmittance with the same expectation as [`TabledTransmittance::resolve`], the
    /// shadow ray traced with probability `ray_weight` in place of the blend (one draw from
    /// `rng` where the weight is strictly between 0 and 1): a path's next-event estimates are
    /// averaged over many paths, and a ray traced at a fraction of the lookups that would
    /// blend it costs that fraction.
    #[inline]
    pub fn sample(self, rng: &mut Rng, ray: impl FnOnce(&mut Rng) -> f64) -> f64 {
        if self.ray_weight <= 0.0 {
            self.table
        } else if self.ray_weight >= 1.0 || rng.next_f64() < self.ray_weight {
            ray(rng)
        } else {
            self.table
        }
    }
}

/// Spacing of a light lattice, in density voxels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightLattice {
    /// Between neighbouring rays, on the two non-dominant index axes: shadow edges are as
    /// sharp as the density across the light, so this is finer than a voxel.
    pub across: f64,
    /// Between nodes along a ray, on the dominant index axis: the optical depth is an
    /// integral along the ray, smooth there.
    pub along: f64,
}

impl Default for LightLattice {
    /// Rays half a voxel apart, nodes one voxel apart along them.
    fn default() -> Self {
        LightLattice { across: 0.5, along: 1.0 }
    }
}

/// The optical depth toward one sun on its light lattice, held as transmittance.
#[derive(Clone, Debug)]
pub struct OpticalDepthVolume {
    /// Transmittance toward the light at each lattice node (1 where nothing is stored: no
    /// medium lies toward the light from there).
    pub transmittance: Volume<f32>,
    /// At each lattice node, the optical depth its density would give over one node step,
    /// extinction x density x step (0 where nothing is stored): the shape of the optical depth
    /// between two nodes of a ray ([`along_ray`]).
    pub node_depth: Volume<f32>,
    /// Rays stopped integrating past this optical depth.
    pub opaque_depth: f64,
    /// The lattice it was built on.
    pub lattice: LightLattice,
    /// Whether the lattice is unsheared (the sun along an index axis), so that optical depth
    /// is bilinear across its rays and is what the lookup interpolates across them.
    pub depth_across: bool,
}

impl OpticalDepthVolume {
    /// Tables the optical depth toward a sun whose light travels along `sun_dir` (unit).
    pub fn build(medium: DensityMedium, sun_dir: Vec3, lattice: LightLattice, opaque_depth: f64) -> OpticalDepthVolume {
        let plan = LightTablePlan::new(medium.density, sun_dir, lattice);
        let bricks: Vec<(IVec3, Vec<f32>)> = plan
            .columns
            .par_iter()
            .flat_map_iter(|(column, ks)| plan.geometry.integrate_brick_column(medium, *column, ks, opaque_depth))
            .collect();
        plan.table(bricks.iter().map(|(origin, values)| (*origin, values.as_slice())), opaque_depth)
    }

    /// The table of `plan` from its nodes integrated elsewhere (the GPU backend): brick after
    /// brick in [`LightTablePlan::bricks`]' order, each in [`brick_offset`] order.
    pub fn from_nodes(plan: &LightTablePlan, nodes: &[f32], opaque_depth: f64) -> OpticalDepthVolume {
        assert_eq!(nodes.len(), plan.brick_count() * TABLE_BRICK_VALUES, "two values per node of the plan's bricks");
        plan.table(plan.bricks().zip(nodes.chunks_exact(TABLE_BRICK_VALUES)), opaque_depth)
    }

    /// Transmittance toward the light from world point `x`, interpolated.
    #[inline]
    pub fn transmittance(&self, x: DVec3) -> f64 {
        self.lookup(x).table
    }

    /// Transmittance toward the light from world point `x` as the lattice resolves it: the
    /// interpolation ([`along_ray`] along the rays, bilinear across them: in optical depth on
    /// an unsheared lattice, else in transmittance), and how much of a
    /// shadow ray to take in its place where the eight nodes around `x` stray from it across
    /// [`TABLED_SPREAD`].
    #[inline]
    pub fn lookup(&self, x: DVec3) -> TabledTransmittance {
        self.lookup_within(x, TABLED_SPREAD)
    }

    /// [`OpticalDepthVolume::lookup`], the shadow ray blended in across `spread` instead of
    /// [`TABLED_SPREAD`].
    #[inline]
    pub fn lookup_within(&self, x: DVec3, spread: [f32; 2]) -> TabledTransmittance {
        let p = self.transmittance.transform().to_index(x);
        let Some((cell, uvw)) = lattice_cell(p) else { return TabledTransmittance { table: 1.0, ray_weight: 1.0 } };
        let c = self.transmittance.corners(cell);
        let rate = self.node_depth.corners(cell);
        let uvw = uvw.as_vec3();
        // Corner n's bit 0 is the lattice z, the light's axis: pairs (n, n + 1) are one ray.
        let ray = |n: usize| along_ray(c[n], c[n + 1], rate[n], rate[n + 1], uvw.z);
        let lerp = |a: f32, b: f32, w: f32| a + (b - a) * w;
        let table = if self.depth_across {
            let depth = |n: usize| -ray(n).max(f32::MIN_POSITIVE).ln();
            (-lerp(lerp(depth(0), depth(2), uvw.y), lerp(depth(4), depth(6), uvw.y), uvw.x)).exp()
        } else {
            lerp(lerp(ray(0), ray(2), uvw.y), lerp(ray(4), ray(6), uvw.y), uvw.x)
        };
        let weight = |n: usize| {
            let f = |bit: usize, u: f32| if n >> bit & 1 == 1 { u } else { 1.0 - u };
            f(2, uvw.x) * f(1, uvw.y) * f(0, uvw.z)
        };
        let deviation: f32 = (0..8).map(|n| weight(n) * (c[n] - table).abs()).sum();
        let [from, to] = spread;
        let ray_weight = ((deviation - from) / (to - from)).clamp(0.0, 1.0) as f64;
        TabledTransmittance { table: table as f64, ray_weight }
    }

    /// Optical depth toward the light from world point `x`: -ln of the interpolated
    /// transmittance.
    pub fn optical_depth(&self, x: DVec3) -> f64 {
        -self.transmittance(x).max(f64::MIN_POSITIVE).ln()
    }

    /// Lattice nodes stored.
    pub fn nodes(&self) -> u64 {
        (self.transmittance.brick_count() * BRICK_VOXELS) as u64
    }
}

/// The tabled optical depth of every light that has one: suns. Point lights get none
/// (their rays diverge; they keep per-point shadow rays).
#[derive(Clone, Debug, Default)]
pub struct LightDepths {
    pub per_light: Vec<Option<OpticalDepthVolume>>,
}

impl LightDepths {
    /// Tables each sun of `lights`; `opaque_depth` as in [`OpticalDepthVolume::build`].
    pub fn build(medium: DensityMedium, lights: &[Light], lattice: LightLattice, opaque_depth: f64) -> LightDepths {
        let per_light = lights.iter().map(|light| Self::tabled_direction(light).map(|dir| OpticalDepthVolume::build(medium, dir, lattice, opaque_depth))).collect();
        LightDepths { per_light }
    }

    /// The direction a light's table is built along, for the lights that get one: suns that
    /// shine. Both backends ask this.
    pub fn tabled_direction(light: &Light) -> Option<Vec3> {
        match *light {
            // A sun with a disc is shadowed by rays drawn over the disc: one table holds one
            // direction's shadow.
            Light::Sun { dir, irradiance, angle } if irradiance != Vec3::ZERO && angle == 0.0 => Some(dir),
            _ => None,
        }
    }

    /// Light `index`'s table, if it has one.
    pub fn get(&self, index: usize) -> Option<&OpticalDepthVolume> {
        self.per_light.get(index).and_then(Option::as_ref)
    }

    /// Transmittance toward light `index` from world point `x` for a path's next-event
    /// estimate: its table where it has one and resolves `x`, the shadow ray `ray` otherwise,
    /// and in between (across [`TABLED_SPREAD`]) the ray drawn with the blend's weight
    /// ([`TabledTransmittance::sample`]).
    #[inline]
    pub fn transmittance(&self, index: usize, x: DVec3, rng: &mut Rng, ray: impl FnOnce(&mut Rng) -> f64) -> f64 {
        match self.get(index) {
            Some(table) => table.lookup(x).sample(rng, ray),
            None => ray(rng),
        }
    }

    /// Transmittance toward light `index` from world point `x`, the shadow ray blended in
    /// across `spread` ([`SINGLE_SPREAD`] for single scattering, whose one lookup per node
    /// shows undiluted in the image).
    #[inline]
    pub fn transmittance_within(&self, index: usize, x: DVec3, spread: [f32; 2], ray: impl FnOnce() -> f64) -> f64 {
        match self.get(index) {
            Some(table) => table.lookup_within(x, spread).resolve(ray),
            None => ray(),
        }
    }

    /// Nodes stored over all lights.
    pub fn nodes(&self) -> u64 {
        self.per_light.iter().flatten().map(OpticalDepthVolume::nodes).sum()
    }
}

/// How next-event estimation finds the transmittance toward a light.
#[derive(Clone, Copy, Debug)]
pub enum Shadowing<'a> {
    /// Ratio tracking along a shadow ray: unbiased (the reference path tracer's).
    RatioTracked,
    /// The light's tabled optical depth where it has one, ratio tracking otherwise: no
    /// tracked ray per collision, and no noise from it.
    Tabled(&'a LightDepths),
}

/// How one sun's table is laid out, decided on the host once for both backends: the
/// lattice's geometry, which of its bricks are stored and in what order (brick columns in
/// order, each column's bricks along the light). Only the integration of the rays differs:
/// [`OpticalDepthVolume::build`] here in f64, the GPU backend in f32
/// (`shaders/optical_depth.wgsl`), each then handing its nodes to the same assembly.
#[derive(Clone, Debug)]
pub struct LightTablePlan {
    geometry: LatticeGeometry,
    /// Lattice index -> world: the table's transform.
    transform: Transform,
    /// The stored bricks by brick column (the lattice x, y of the bricks' origin), each
    /// column's bricks' lattice z sorted.
    columns: Vec<((i32, i32), Vec<i32>)>,
}

impl LightTablePlan {
    /// The lattice of a sun whose light travels along `sun_dir` (unit) through `density`.
    pub fn new(density: &Volume<f32>, sun_dir: Vec3, lattice: LightLattice) -> LightTablePlan {
        let geometry = LatticeGeometry::new(density.transform(), sun_dir.as_dvec3(), lattice);
        let transform = Transform::new(density.transform().index_to_world() * geometry.to_density)
            .expect("a shear of an invertible map along a non-degenerate direction is invertible");
        let columns = geometry.brick_columns(density);
        LightTablePlan { geometry, transform, columns }
    }

    /// Lattice index -> world.
    pub fn transform(&self) -> &Transform {
        &self.transform
    }

    /// Lattice index -> density index: linear, the two lattices' origins coincide.
    pub fn to_density(&self) -> DMat3 {
        self.geometry.to_density.matrix3
    }

    /// The light's direction in density index space, per unit of world distance.
    pub fn dir_index(&self) -> DVec3 {
        self.geometry.dir_index
    }

    /// World distance between consecutive nodes along a ray.
    pub fn step(&self) -> f64 {
        self.geometry.step
    }

    /// Whether the lattice is unsheared, the sun along an index axis: optical depth is then
    /// bilinear across the rays and is what lookups interpolate across them.
    pub fn depth_across(&self) -> bool {
        let d = self.geometry.dir_index;
        let a = d.abs().max_position();
        (0..3).filter(|&n| n != a).all(|n| d[n].abs() <= 1e-9 * d[a].abs())
    }

    /// The stored bricks by brick column: the column's lattice (x, y) and its bricks' z,
    /// sorted. Each column's 8 x 8 rays are integrated over [`LightTablePlan::column_nodes`].
    pub fn columns(&self) -> &[((i32, i32), Vec<i32>)] {
        &self.columns
    }

    /// The nodes a column's rays are integrated over: the lattice z of the first and how
    /// many, from its first stored brick's first node (upstream of which the ray meets no
    /// medium) to its last's last, through any unstored bricks between.
    pub fn column_nodes(ks: &[i32]) -> (i32, usize) {
        let (k0, k1) = (ks[0], ks[ks.len() - 1] + BRICK_DIM - 1);
        (k0, (k1 - k0 + 1) as usize)
    }

    /// The stored bricks' origins (lattice index) in storage order.
    pub fn bricks(&self) -> impl Iterator<Item = IVec3> + '_ {
        self.columns.iter().flat_map(|((x, y), ks)| ks.iter().map(move |&z| IVec3::new(*x, *y, z)))
    }

    pub fn brick_count(&self) -> usize {
        self.columns.iter().map(|(_, ks)| ks.len()).sum()
    }

    /// The table holding `bricks` (origin, [`TABLE_BRICK_VALUES`] values: the transmittances
    /// in [`brick_offset`] order, then the depth rates), in storage order.
    fn table<'a>(&self, bricks: impl Iterator<Item = (IVec3, &'a [f32])>, opaque_depth: f64) -> OpticalDepthVolume {
        let mut transmittance = Volume::new(self.transform, 1.0f32);
        let mut node_depth = Volume::new(self.transform, 0.0f32);
        const ALL: [u64; 8] = [u64::MAX; 8];
        for (origin, values) in bricks {
            let (t, rate) = values.split_at(BRICK_VOXELS);
            transmittance.insert_brick(origin, t, &ALL);
            node_depth.insert_brick(origin, rate, &ALL);
        }
        OpticalDepthVolume { transmittance, node_depth, opaque_depth, lattice: self.geometry.lattice, depth_across: self.depth_across() }
    }
}

/// How the light lattice sits in the density's index space.
#[derive(Clone, Debug)]
struct LatticeGeometry {
    lattice: LightLattice,
    /// Lattice index -> density index (linear: the origins coincide).
    to_density: DAffine3,
    to_lattice: DAffine3,
    /// The light's direction in density index space, per unit of world distance.
    dir_index: DVec3,
    /// World distance between consecutive nodes along a ray.
    step: f64,
}

impl LatticeGeometry {
    fn new(transform: &Transform, sun_dir: DVec3, lattice: LightLattice) -> LatticeGeometry {
        let d = transform.dir_to_index(sun_dir);
        let a = d.abs().max_position();
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let (b, c) = (b.min(c), b.max(c));
        let axis = |n: usize| {
            let mut e = DVec3::ZERO;
            e[n] = 1.0;
            e
        };
        // Each node step along a ray advances `along` voxels on the dominant axis, downstream.
        let along = d * (lattice.along / d[a].abs());
        let m = DMat3::from_cols(axis(b) * lattice.across, axis(c) * lattice.across, along);
        let to_density = DAffine3::from_mat3(m);
        LatticeGeometry { lattice, to_density, to_lattice: to_density.inverse(), dir_index: d, step: lattice.along / d[a].abs() }
    }

    /// The lattice bricks a lookup can land in, grouped by brick column (the brick's first
    /// two coordinates), each with its bricks' third coordinates sorted.
    fn brick_columns(&self, density: &Volume<f32>) -> Vec<((i32, i32), Vec<i32>)> {
        let marked: Vec<Vec<IVec3>> = density
            .par_bricks()
            .filter(|b| b.values.iter().any(|&v| v > 0.0))
            .map(|b| {
                // Trilinear density is non-zero only within (o - 1, o + 8) of a brick's voxels.
                let (lo, hi) = (b.origin.as_dvec3() - 1.0, b.origin.as_dvec3() + BRICK_DIM as f64);
                let (mut qlo, mut qhi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for n in 0..8 {
                    let p = DVec3::new(if n & 4 != 0 { hi.x } else { lo.x }, if n & 2 != 0 { hi.y } else { lo.y }, if n & 1 != 0 { hi.z } else { lo.z });
                    let q = self.to_lattice.transform_point3(p);
                    qlo = qlo.min(q);
                    qhi = qhi.max(q);
                }
                // A lookup at q reads nodes floor(q) and floor(q) + 1.
                let (nlo, nhi) = (brick_origin(qlo.floor().as_ivec3()), brick_origin(qhi.floor().as_ivec3() + 1));
                let mut out = Vec::new();
                for x in (nlo.x..=nhi.x).step_by(BRICK_DIM as usize) {
                    for y in (nlo.y..=nhi.y).step_by(BRICK_DIM as usize) {
                        for z in (nlo.z..=nhi.z).step_by(BRICK_DIM as usize) {
                            out.push(IVec3::new(x, y, z));
                        }
                    }
                }
                out
            })
            .collect();
        let mut all: Vec<IVec3> = marked.into_iter().flatten().collect();
        all.sort_unstable_by_key(|o| (o.x, o.y, o.z));
        all.dedup();
        let mut columns: Vec<((i32, i32), Vec<i32>)> = Vec::new();
        for o in all {
            match columns.last_mut() {
                Some((c, ks)) if *c == (o.x, o.y) => ks.push(o.z),
                _ => columns.push(((o.x, o.y), vec![o.z])),
            }
        }
        columns
    }

    /// Integrates the 8 x 8 rays of one brick column from its first stored node to its last,
    /// and returns its bricks: transmittances, then depth rates ([`TABLE_BRICK_VALUES`]).
    fn integrate_brick_column(&self, medium: DensityMedium, (bx, by): (i32, i32), ks: &[i32], opaque_depth: f64) -> Vec<(IVec3, Vec<f32>)> {
        let (k0, count) = LightTablePlan::column_nodes(ks);
        let mut bricks: Vec<(IVec3, Vec<f32>)> = ks.iter().map(|&z| (IVec3::new(bx, by, z), vec![0.0f32; TABLE_BRICK_VALUES])).collect();
        let mut tau = vec![0.0f64; count];
        for li in 0..BRICK_DIM {
            for lj in 0..BRICK_DIM {
                let start = self.to_density.transform_point3(IVec3::new(bx + li, by + lj, k0).as_dvec3());
                ray_optical_depths(medium, start, self.dir_index, self.step, opaque_depth, &mut tau);
                for (origin, values) in bricks.iter_mut() {
                    for lk in 0..BRICK_DIM {
                        let node = IVec3::new(bx + li, by + lj, origin.z + lk);
                        let offset = brick_offset(IVec3::new(li, lj, lk));
                        values[offset] = (-tau[(origin.z + lk - k0) as usize]).exp() as f32;
                        let rho = medium.density.sample_index(self.to_density.transform_point3(node.as_dvec3())).max(0.0) as f64;
                        values[BRICK_VOXELS + offset] = (medium.extinction as f64 * self.step * rho) as f32;
                    }
                }
            }
        }
        bricks
    }
}

/// The optical depth at the points `origin + k * step * dir` (density index space, `dir` per
/// unit of world distance), k = 0, 1, ..., `out.len()` - 1, integrated from `origin` (where
/// the ray must not yet have met medium) cell by cell in closed form. Past `opaque_depth`
/// the remaining points keep the depth reached.
pub fn ray_optical_depths(medium: DensityMedium, origin: DVec3, dir: DVec3, step: f64, opaque_depth: f64, out: &mut [f64]) {
    let ext = medium.extinction as f64;
    let t_end = step * (out.len() as f64 - 1.0);
    let mut tau = 0.0;
    let mut k = 0usize;
    // Emits every node up to distance `t` with the depth tau + f(t_node).
    let mut emit_until = |k: &mut usize, t: f64, tau: f64, f: &dyn Fn(f64) -> f64| {
        while *k < out.len() && (*k as f64) * step <= t {
            out[*k] = tau + f(*k as f64 * step);
            *k += 1;
        }
    };
    'walk: for seg in medium.majorant.walk(origin, dir, 0.0, t_end) {
        if !(seg.majorant > 0.0 && ext > 0.0 && seg.t_end.is_finite()) {
            continue;
        }
        // Nodes before this segment (in empty space) hold the depth so far.
        emit_until(&mut k, seg.t_start, tau, &|_| 0.0);
        let mut next = DVec3::INFINITY;
        let mut inc = DVec3::INFINITY;
        for axis in 0..3 {
            if dir[axis] != 0.0 {
                let c = origin[axis] + seg.t_start * dir[axis];
                let plane = if dir[axis] > 0.0 { c.floor() + 1.0 } else { c.ceil() - 1.0 };
                next[axis] = (plane - origin[axis]) / dir[axis];
                inc[axis] = 1.0 / dir[axis].abs();
            }
        }
        let mut t = seg.t_start;
        while t < seg.t_end {
            let cross = next.min_element().min(seg.t_end);
            if cross > t {
                let cell = (origin + dir * (0.5 * (t + cross))).floor();
                let corners = medium.density.corners(cell.as_ivec3()).map(|v| v.max(0.0) as f64);
                let cubic = cubic_along(&corners, origin + dir * t - cell, dir);
                let (t0, depth0) = (t, tau);
                emit_until(&mut k, cross, depth0, &|tn| ext * integral(&cubic, tn - t0));
                tau += ext * integral(&cubic, cross - t);
                t = cross;
                if tau > opaque_depth {
                    break 'walk;
                }
            }
            for axis in 0..3 {
                while next[axis] <= t {
                    next[axis] += inc[axis];
                }
            }
        }
    }
    for v in &mut out[k..] {
        *v = tau;
    }
}

/// The trilinear interpolant of a cell's corners (order 000, 001, ..., 111 in x, y, z) along
/// `u0 + s * du` (cell-local coordinates) as a cubic in s: coefficients of s^0..s^3.
fn cubic_along(c: &[f64; 8], u0: DVec3, du: DVec3) -> [f64; 4] {
    // f = k0 + kx x + ky y + kz z + kxy xy + kxz xz + kyz yz + kxyz xyz.
    let k0 = c[0];
    let kx = c[4] - c[0];
    let ky = c[2] - c[0];
    let kz = c[1] - c[0];
    let kxy = c[6] - c[4] - c[2] + c[0];
    let kxz = c[5] - c[4] - c[1] + c[0];
    let kyz = c[3] - c[2] - c[1] + c[0];
    let kxyz = c[7] - c[6] - c[5] - c[3] + c[4] + c[2] + c[1] - c[0];
    let (x0, y0, z0) = (u0.x, u0.y, u0.z);
    let (dx, dy, dz) = (du.x, du.y, du.z);
    // Products of two linear factors: p0 + p1 s + p2 s^2.
    let prod = |a0: f64, a1: f64, b0: f64, b1: f64| [a0 * b0, a0 * b1 + a1 * b0, a1 * b1];
    let xy = prod(x0, dx, y0, dy);
    let xz = prod(x0, dx, z0, dz);
    let yz = prod(y0, dy, z0, dz);
    let xyz = [xy[0] * z0, xy[0] * dz + xy[1] * z0, xy[1] * dz + xy[2] * z0, xy[2] * dz];
    [
        k0 + kx * x0 + ky * y0 + kz * z0 + kxy * xy[0] + kxz * xz[0] + kyz * yz[0] + kxyz * xyz[0],
        kx * dx + ky * dy + kz * dz + kxy * xy[1] + kxz * xz[1] + kyz * yz[1] + kxyz * xyz[1],
        kxy * xy[2] + kxz * xz[2] + kyz * yz[2] + kxyz * xyz[2],
        kxyz * xyz[3],
    ]
}

/// integral_0^s of the cubic.
#[inline]
fn integral(a: &[f64; 4], s: f64) -> f64 {
    s * (a[0] + s * (a[1] / 2.0 + s * (a[2] / 3.0 + s * a[3] / 4.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sampled_lookup_has_the_blends_expectation_and_traces_the_ray_at_its_weight() {
        let ray_value = 0.2;
        for (table, ray_weight) in [(0.6, 0.0), (0.6, 0.3), (0.6, 0.75), (0.6, 1.0)] {
            let lookup = TabledTransmittance { table, ray_weight };
            let blend = lookup.resolve(|| ray_value);
            let (mut rng, mut sum, mut rays, n) = (Rng::new(7, 0), 0.0, 0u32, 200_000);
            for _ in 0..n {
                sum += lookup.sample(&mut rng, |_| {
                    rays += 1;
                    ray_value
                });
            }
            let (mean, share) = (sum / n as f64, rays as f64 / n as f64);
            // The binomial's standard error at n = 200k: at most 0.0011 in the share.
            assert!((share - ray_weight).abs() < 0.005, "weight {ray_weight}: rays at {share}");
            assert!((mean - blend).abs() < 0.4 * 0.005, "weight {ray_weight}: {mean} against the blend's {blend}");
        }
    }

    #[test]
    fn the_cubic_is_the_trilinear_interpolant_along_the_line() {
        let c = [0.3, 1.7, 0.2, 0.9, 2.5, 0.1, 1.1, 0.6];
        let tri = |p: DVec3| {
            let l = |a: f64, b: f64, w: f64| a + (b - a) * w;
            l(l(l(c[0], c[1], p.z), l(c[2], c[3], p.z), p.y), l(l(c[4], c[5], p.z), l(c[6], c[7], p.z), p.y), p.x)
        };
        let (u0, du) = (DVec3::new(0.1, 0.8, 0.35), DVec3::new(0.6, -0.5, 0.45));
        let a = cubic_along(&c, u0, du);
        for n in 0..=10 {
            let s = n as f64 * 0.1;
            let poly = a[0] + s * (a[1] + s * (a[2] + s * a[3]));
            assert!((poly - tri(u0 + du * s)).abs() < 1e-12, "s = {s}");
        }
        // The closed-form integral against a fine midpoint rule.
        let n = 20000;
        let mid: f64 = (0..n).map(|i| tri(u0 + du * ((i as f64 + 0.5) / n as f64))).sum::<f64>() / n as f64;
        assert!((integral(&a, 1.0) - mid).abs() < 1e-8);
    }
}
