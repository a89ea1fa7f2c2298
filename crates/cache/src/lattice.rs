//! Li_single's lattice, chosen per axis from the scene.
//!
//! Li_single is baked at lattice nodes and read back by trilinear interpolation, which
//! misses wherever the sun's transmittance bends between two nodes: across the thin axis
//! of flat voxels, through a dense layer under a grazing sun, along the long axis of
//! stretched voxels. How much it misses depends on the medium, the voxel shape and the
//! lights together, so no fixed lattice serves every scene: the density's own lattice is
//! 0.06% off a brute-force single-scattering march on one scene and 1.5% on another.
//!
//! So the bake measures it. At a sample of the density's voxels, seen from the camera,
//! it evaluates Li_single at a node, at the next node along each cache axis and halfway
//! between, and sums how far the midpoint is from the two nodes' mean, weighted by what
//! the camera receives from there (density times transmittance to the eye), relative to
//! Li_single itself. Halving an axis's spacing divides its term by four (the
//! interpolation error of a smooth function goes with the spacing squared), so each axis
//! is halved until its term is within a third of the tolerance, at most
//! [`MAX_REFINEMENT`] times finer than the requested scale. Where even that would leave the
//! sum above the tolerance, the lattice stays as requested and is marked
//! [`SingleLattice::direct`]: vdbmarch then traces single scattering's shadow rays at each
//! of its samples (issue #47; a generated thin shell lit from behind, `nimbus-scene --random
//! 20261207009`, was 1.85% off the brute-force march at a quarter voxel and 64 times the
//! nodes).

use glam::DVec3;
use nimbus_optics::Camera;
use nimbus_tracking::{DensityMedium, LightDepths, MediumRay};
use nimbus_volume::{brick_local, Volume, BRICK_VOXELS};
use rayon::prelude::*;

use crate::{li_single, toward_eye, CacheParams};

/// Li_single's default interpolation tolerance: the estimate's relative sum. Measured, it
/// has come out at 0.4 to 0.9 times the image's relative RMSE against a brute-force march
/// (docs/benchmarks.md "Li_single's lattice"), so this keeps single scattering within about
/// half of its 0.5% goal.
pub const SINGLE_LATTICE_TOLERANCE: f64 = 0.006;

/// Most an axis is refined: four times finer than the requested scale.
pub const MAX_REFINEMENT: u32 = 4;

/// How many density voxels the estimate samples at most (evenly through the active ones).
pub const LATTICE_SAMPLES: usize = 16_384;

/// What [`choose_single_lattice`] decided and why.
#[derive(Clone, Debug, PartialEq)]
pub struct SingleLattice {
    /// Li_single's voxel edge per density index axis, in density voxels.
    pub scale: DVec3,
    /// The estimated relative interpolation error per axis at the requested scale.
    pub estimate: DVec3,
    /// The voxels the estimate sampled.
    pub samples: usize,
    /// Whether no lattice within [`MAX_REFINEMENT`] would bring the estimate within the
    /// tolerance: the lattice is then left unrefined and the march evaluates single
    /// scattering by shadow rays at each sample instead (issue #47; vdbmarch `--single`).
    pub direct: bool,
}

impl SingleLattice {
    /// The requested scale on every axis, nothing measured.
    pub fn uniform(scale: f64) -> SingleLattice {
        SingleLattice { scale: DVec3::splat(scale), estimate: DVec3::ZERO, samples: 0, direct: false }
    }

    /// The estimate's sum at the chosen scale (within the tolerance unless an axis reached
    /// [`MAX_REFINEMENT`]).
    pub fn remaining(&self, requested: f64) -> f64 {
        let r = DVec3::splat(requested) / self.scale;
        (self.estimate / (r * r)).element_sum()
    }

    /// The error Li_single's lattice leaves in the image, estimated: none where the march
    /// evaluates single scattering itself ([`SingleLattice::direct`]).
    pub fn image_error(&self, requested: f64) -> f64 {
        if self.direct {
            0.0
        } else {
            self.remaining(requested)
        }
    }
}

/// Li_single's lattice for `params`: `params.cache_scale` on every axis, each axis halved
/// as [the module](self) says while `params.single_tolerance` asks for it.
pub fn choose_single_lattice(medium: DensityMedium, params: &CacheParams, depths: &LightDepths) -> SingleLattice {
    let density = medium.density;
    let base = params.cache_scale;
    let Some(tolerance) = params.single_tolerance.filter(|_| params.bakes_single() && !params.lights.is_empty()) else {
        return SingleLattice::uniform(base);
    };
    let samples = sample_voxels(density, LATTICE_SAMPLES);
    let estimate = interpolation_error(medium, params, depths, &samples, base);
    // Each axis keeps its third of the tolerance on its own: an axis that cannot get there
    // within MAX_REFINEMENT does not make the others finer for it.
    let mut refinement = DVec3::ONE;
    for a in 0..3 {
        while estimate[a] / (refinement[a] * refinement[a]) > tolerance / 3.0 && refinement[a] < MAX_REFINEMENT as f64 {
            refinement[a] *= 2.0;
        }
    }
    // Where the axes' thirds leave the sum above the tolerance, halve the axis that misses
    // most while one can be.
    let remaining = |r: DVec3| (estimate / (r * r)).element_sum();
    while remaining(refinement) > tolerance {
        let terms = estimate / (refinement * refinement);
        let Some(a) = (0..3).filter(|&a| refinement[a] < MAX_REFINEMENT as f64).max_by(|&a, &b| terms[a].total_cmp(&terms[b])) else { break };
        refinement[a] *= 2.0;
    }
    if remaining(refinement) > tolerance {
        // The finest lattice would still miss (a thin shell lit from behind, a dense layer
        // under a grazing sun: the sun's transmittance bends within a quarter voxel), at up
        // to 64 times the nodes: the march traces the shadow rays itself, and the cache keeps
        // the requested lattice for what else reads it (the paths' levels, other tools).
        return SingleLattice { scale: DVec3::splat(base), estimate, samples: samples.len(), direct: true };
    }
    SingleLattice { scale: DVec3::splat(base) / refinement, estimate, samples: samples.len(), direct: false }
}


/// Index coordinates of at most `most` voxels holding density, evenly spread over them in
/// brick order (deterministic).
fn sample_voxels(density: &Volume<f32>, most: usize) -> Vec<DVec3> {
    let holding = |b: &nimbus_volume::BrickRef<f32>| b.values.iter().filter(|&&v| v > 0.0).count();
    let total: usize = density.bricks().map(|b| holding(&b)).sum();
    let stride = total.div_ceil(most.max(1)).max(1);
    let mut out = Vec::with_capacity(total / stride + 1);
    let mut k = 0usize;
    for brick in density.bricks() {
        for offset in 0..BRICK_VOXELS {
            if brick.values[offset] > 0.0 {
                if k % stride == 0 {
                    out.push((brick.origin + brick_local(offset)).as_dvec3());
                }
                k += 1;
            }
        }
    }
    out
}

/// Per cache axis (density index axis a, spacing `scale` voxels): the camera-weighted sum
/// of |Li(midpoint) - mean of Li at the two nodes| over the weighted sum of Li.
fn interpolation_error(medium: DensityMedium, params: &CacheParams, depths: &LightDepths, samples: &[DVec3], scale: f64) -> DVec3 {
    let density = medium.density;
    let transform = density.transform();
    let camera: &Camera = &params.camera;
    let step = params.single_step(density);
    let li = |x: DVec3| {
        li_single(medium, &params.medium, &params.lights, depths, x, toward_eye(camera, x), step, params.min_transmittance).element_sum() as f64
    };
    let (error, total) = samples
        .par_iter()
        .filter_map(|&c| {
            let x = transform.to_world(c);
            let to_eye = camera.eye() - x;
            let distance = to_eye.length();
            if distance <= 0.0 || !camera.sees_sphere(x, 0.0) {
                return None;
            }
            let seen = MediumRay::new(medium, x, to_eye / distance, 0.0, distance).transmittance(step, 1e-3);
            let weight = density.sample_index(c).max(0.0) as f64 * seen;
            if weight <= 0.0 {
                return None;
            }
            let at_node = li(x);
            let mut error = DVec3::ZERO;
            let mut mean = at_node;
            for a in 0..3 {
                let mut axis = DVec3::ZERO;
                axis[a] = scale;
                let next = li(transform.to_world(c + axis));
                let mid = li(transform.to_world(c + 0.5 * axis));
                error[a] = (mid - 0.5 * (at_node + next)).abs();
                mean += next;
            }
            Some((weight * error, weight * mean / 4.0))
        })
        .reduce(|| (DVec3::ZERO, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if total > 0.0 {
        error / total
    } else {
        DVec3::ZERO
    }
}
