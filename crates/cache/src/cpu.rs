//! The CPU backend: cache bricks baked in parallel with rayon.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use glam::{DVec3, Vec3};
use nimbus_optics::{r2_point, Camera, Light, Medium, Rng};
use nimbus_photon::PhotonMap;
use nimbus_tracking::{environment_nee, trace_path, DensityMedium, EmissionField, LightDepths, MediumRay, PathSources, PathStart, Shadowing, SINGLE_SPREAD};
use nimbus_volume::{MajorantGrid, Volume};

use crate::plan::Prologue;
use crate::multiple_lattice::bake_paths;
use crate::{BakeStats, CacheError, CacheParams, CachePlan, Gather, IlluminationCache, MultipleEstimator, PathMoments, PathPlan, PhotonBins};

/// Random-number domain of the path-traced multiple scattering ("CAPT").
pub(crate) const CACHE_PATHS_DOMAIN: u32 = 0x4341_5054;

/// Single scattering toward the camera at world point `x`:
/// sum over lights of p(w_light, w_out) E T_light(x), T_light looked up in the light's
/// tabled optical depth where `depths` has one, else integrated along a shadow ray by
/// composite Simpson with steps of `step`. Transmittance below `cutoff` counts as black.
#[allow(clippy::too_many_arguments)]
pub fn li_single(medium: DensityMedium, optics: &Medium, lights: &[Light], depths: &LightDepths, x: DVec3, w_out: Vec3, step: f64, cutoff: f64) -> Vec3 {
    let phase = optics.phase();
    lights
        .iter()
        .enumerate()
        .map(|(index, light)| {
            if light.has_disc() {
                return sun_disc_single(medium, phase, light, x, w_out, step, cutoff);
            }
            let incident = light.incident(x);
            if incident.irradiance == Vec3::ZERO {
                return Vec3::ZERO;
            }
            let ray = || MediumRay::new(medium, x, incident.to_light.as_dvec3(), 0.0, incident.distance).transmittance(step, cutoff);
            let tr = depths.transmittance_within(index, x, SINGLE_SPREAD, ray);
            let tr = if tr >= cutoff { tr } else { 0.0 } as f32;
            incident.irradiance * tr * phase.eval_dirs(-incident.to_light, w_out)
        })
        .sum()
}

/// Shadow rays per point toward a sun with a disc ([`sun_disc_single`]).
pub const SUN_DISC_RAYS: usize = 8;

/// Single scattering from a sun with a disc: the mean over [`SUN_DISC_RAYS`] Simpson shadow
/// rays spread over the disc by the R2 sequence (Roberts 2018), its offset hashed from `x`
/// so neighbouring points take different directions and the march's averaging smooths the
/// penumbra instead of repeating one pattern.
fn sun_disc_single(medium: DensityMedium, phase: nimbus_optics::HenyeyGreenstein, light: &Light, x: DVec3, w_out: Vec3, step: f64, cutoff: f64) -> Vec3 {
    const A1: f64 = 0.754_877_666_246_692_8;
    const A2: f64 = 0.569_840_290_998_053_3;
    let h = x.x.to_bits().wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ x.y.to_bits().rotate_left(21).wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ x.z.to_bits().rotate_left(42);
    let h = Rng::new(h, 0).next_vec2().as_dvec2();
    let mut sum = Vec3::ZERO;
    for k in 0..SUN_DISC_RAYS {
        let u = glam::DVec2::new((h.x + A1 * k as f64).fract(), (h.y + A2 * k as f64).fract()).as_vec2();
        let incident = light.incident_over_disc(x, u);
        if incident.irradiance == Vec3::ZERO {
            return Vec3::ZERO;
        }
        let tr = MediumRay::new(medium, x, incident.to_light.as_dvec3(), 0.0, incident.distance).transmittance(step, cutoff);
        let tr = if tr >= cutoff { tr } else { 0.0 } as f32;
        sum += incident.irradiance * tr * phase.eval_dirs(-incident.to_light, w_out);
    }
    sum / SUN_DISC_RAYS as f32
}

/// Directions of the ball quadrature: the 6 axes and the 8 diagonals.
pub(crate) const BALL_DIRECTIONS: [[f64; 3]; 14] = {
    const D: f64 = 0.577_350_269_189_625_8;
    [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [D, D, D],
        [D, D, -D],
        [D, -D, D],
        [D, -D, -D],
        [-D, D, D],
        [-D, D, -D],
        [-D, -D, D],
        [-D, -D, -D],
    ]
};

/// Radii (in units of the ball's radius) splitting the ball into three shells of equal
/// volume, each taken at its volume midpoint: (1/6)^(1/3), (1/2)^(1/3), (5/6)^(1/3).
pub(crate) const BALL_SHELLS: [f64; 3] = [0.550_321_208_149_104_4, 0.793_700_525_984_099_7, 0.941_036_415_534_214_6];

/// Mean density over the ball of `radius` around world point `x`: 14 directions on 3
/// equal-volume shells, equally weighted. The ratio estimator divides by this, so it must see
/// the whole ball: a stencil hugging the centre would miss the dense part of a ball that only
/// grazes a cloud, and the ratio would blow up at the cloud's edge.
pub fn mean_density_in_ball(density: &Volume<f32>, x: DVec3, radius: f64) -> f64 {
    let mut sum = 0.0;
    for shell in BALL_SHELLS {
        for d in BALL_DIRECTIONS {
            sum += density.sample_world(x + DVec3::from_array(d) * (shell * radius)).max(0.0) as f64;
        }
    }
    sum / (BALL_SHELLS.len() * BALL_DIRECTIONS.len()) as f64
}

/// A ball whose mean density is below this fraction of the volume's largest barely touches
/// the medium: the ratio estimator would divide its photons by a near-zero mean (a 42-point
/// quadrature under-resolves a sliver of medium) and send the cache voxel, and through
/// interpolation its denser neighbours, to huge values. Such a ball counts as empty.
///
/// The fraction must stay far below the medium's real contrasts: at 1e-3 it zeroed the
/// wisps of the smoke-like plume (density contrasts over 1000) and left its multiple
/// scattering 9% dark against the path-traced reference (the image 4.3% dark, 7.5% error at
/// preview); at 1e-6 multiple scattering reads +2.4% and the image error is 5.3% (4.1% at
/// final), while the Cloud1-class deck, where the rule was found, is unchanged (13.8%).
pub const EMPTY_BALL_FRACTION: f64 = 1e-6;

/// The photons' radiance estimate at `x` toward `w_out`, divided by the mean sigma_s over the
/// same ball (zero where that mean density is below `empty_below`); returns it and how many
/// photons it used.
#[allow(clippy::too_many_arguments)]
pub fn li_multiple(
    density: &Volume<f32>,
    empty_below: f64,
    optics: &Medium,
    photons: &PhotonMap,
    bins: &PhotonBins,
    gather: Gather,
    x: DVec3,
    w_out: Vec3,
    scratch: &mut Vec<u32>,
) -> (Vec3, u32) {
    let phase = optics.phase();
    let mut sum = Vec3::ZERO;
    let mut used = 0u32;
    let radius = match gather {
        Gather::Radius(r) => {
            bins.for_each_within(x, r, |i, _| {
                sum += photons.power[i as usize] * phase.eval_dirs(photons.dir[i as usize], w_out);
                used += 1;
            });
            r
        }
        Gather::Neighbours { k, max_radius } => {
            let far2 = bins.nearest(x, k as usize, max_radius, scratch);
            for &i in scratch.iter() {
                sum += photons.power[i as usize] * phase.eval_dirs(photons.dir[i as usize], w_out);
            }
            used = scratch.len() as u32;
            // Fewer than k photons within reach: the ball is the whole reach.
            if scratch.len() < k as usize {
                max_radius
            } else {
                // The k-th photon lies on the ball's surface: counting it whole overestimates
                // the photon density by k/(k-1), as in the k-nearest-neighbour density
                // estimate, whose unbiased form (for Poisson points) counts k-1.
                if k >= 2 {
                    sum *= (k - 1) as f32 / k as f32;
                }
                (far2 as f64).sqrt()
            }
        }
    };
    if used == 0 || radius <= 0.0 {
        return (Vec3::ZERO, used);
    }
    let mean_density = mean_density_in_ball(density, x, radius);
    if mean_density < empty_below {
        return (Vec3::ZERO, used);
    }
    let volume = 4.0 / 3.0 * PI * radius * radius * radius;
    let mean_sigma_s = optics.sigma_s(mean_density as f32);
    let ratio = |a: f32, s: f32| if s > 0.0 { a / s } else { 0.0 };
    let estimate = sum / volume as f32;
    (Vec3::new(ratio(estimate.x, mean_sigma_s.x), ratio(estimate.y, mean_sigma_s.y), ratio(estimate.z, mean_sigma_s.z)), used)
}

/// Li_multiple toward the eye by `paths` paths, path j from `origins[j % origins.len()]`:
/// each leaves its origin x in a direction drawn from the phase function about the camera
/// ray's direction there (-w_out, w_out toward `eye`), so the phase weight cancels, and
/// gathers all the light the path scatters toward x (its first collision is x's second
/// scattering); the mean over the paths, and the mean of their squares over the colour
/// channels, from which the bake predicts the noise they leave in the image (budget.rs).
/// `medium`'s majorant must suit delta tracking ([`MajorantGrid::for_tracking`]); next-event estimation looks transmittance up in
/// `depths` where a light has a table.
///
/// With an environment, each path also estimates the environment's light scattered at x
/// itself: a next-event estimate at x, and the path's first flight when it escapes, weighed
/// against each other by the power heuristic ([`environment_nee`], [`PathStart::Scattered`]).
///
/// With `sources.emission` the paths also gather the medium's emission at every collision
/// ([`trace_path`]'s `beta e / sigma_t`): at the first, emitted light reaching x unscattered,
/// which x scatters toward the eye (emission's single scattering: there is no separate
/// Li_single term for it); at later ones, emitted light scattered more often. None of it is
/// the emission vdbmarch adds along the camera ray itself (light emitted toward the eye that
/// no medium scattered), so nothing is counted twice.
///
/// `octants[k]`, where given, is origin k's octant about the voxel's node
/// ([`PathPlan::octants`]): the paths are also summed by it and by their index's parity
/// ([`PathMoments::halves`]).
#[allow(clippy::too_many_arguments)]
pub fn li_multiple_paths(
    medium: DensityMedium,
    optics: &Medium,
    lights: &[Light],
    depths: &LightDepths,
    sources: PathSources,
    origins: &[DVec3],
    octants: &[u8],
    paths: u32,
    max_depth: u32,
    eye: DVec3,
    rng: &mut Rng,
) -> PathMoments {
    let phase = optics.phase();
    let (mut sum, mut squares, mut halves) = (Vec3::ZERO, 0.0f32, [0.0f32; 16]);
    if origins.is_empty() {
        return PathMoments::default();
    }
    let environment = sources.environment.filter(|e| !e.is_black());
    // The first directions of a voxel's paths: per half (the parity of the path's index), the
    // R2 sequence rotated by two words of the stream (each direction is the phase function's,
    // each half's spread evenly). One sequence over both halves made them correlated, points
    // j and j + 1 lying a fixed step apart, where the lattice-bias estimate, a product of the
    // halves, assumes them independent (its estimates moved within their noise when they
    // became so: multiple_lattice.rs).
    let offsets = [[rng.next_u32(), rng.next_u32()], [rng.next_u32(), rng.next_u32()]];
    for j in 0..paths as usize {
        let x = origins[j % origins.len()];
        let w_out = (eye - x).normalize_or_zero().as_vec3();
        // At the eye itself there is no camera ray; any axis serves.
        let axis = if w_out == Vec3::ZERO { Vec3::Z } else { -w_out };
        let mut estimate = Vec3::ZERO;
        if let Some(env) = environment {
            estimate += environment_nee(medium, phase, env, x, -axis, false, rng);
        }
        let dir = phase.sample(axis, r2_point(offsets[j & 1], (j >> 1) as u32)).as_dvec3().normalize();
        let start = PathStart::Scattered { w_in: axis };
        estimate += trace_path(medium, optics, lights, Shadowing::Tabled(depths), x, dir, start, max_depth, rng, sources).total();
        sum += estimate;
        squares += estimate.length_squared() / 3.0;
        halves[8 * (j & 1) + octants.get(j % origins.len()).map_or(0, |&o| o as usize)] += estimate.element_sum() / 3.0;
    }
    let n = paths.max(1) as f32;
    PathMoments { mean: sum / n, mean_square: squares / n, halves }
}

/// Unit direction from world point `x` toward the eye: the w_out the cache is baked for.
pub fn toward_eye(camera: &Camera, x: DVec3) -> Vec3 {
    (camera.eye() - x).normalize_or_zero().as_vec3()
}

/// Bakes the cache on the CPU.
pub fn bake_cpu(density: &Volume<f32>, photons: &PhotonMap, params: &CacheParams) -> Result<(IlluminationCache, BakeStats), CacheError> {
    bake_cpu_emitting(density, photons, params, None)
}

/// [`bake_cpu`] with the medium's emission: the path-traced Li_multiple gathers it
/// ([`li_multiple_paths`]), so a fire lights its own smoke, with or without lights. The
/// photon estimator takes emission from the photons (vdbphoton's emission photons) and reads
/// `emission` not at all; Li_single stays the lights' alone.
pub fn bake_cpu_emitting(
    density: &Volume<f32>,
    photons: &PhotonMap,
    params: &CacheParams,
    emission: Option<&EmissionField>,
) -> Result<(IlluminationCache, BakeStats), CacheError> {
    let Prologue { emission, majorant, mut timed } = Prologue::new(density, params, emission)?;
    let emits = emission.is_some();
    let medium = DensityMedium { motion: None, density, majorant: &majorant, extinction: params.medium.extinction };
    let depths = timed.time("light tables", || params.light_depths(medium, photons, emits));
    let (plan, own_plan, mut stats) = CachePlan::for_bake(medium, params, &depths, photons, emits, timed);
    let multiple_plan = own_plan.as_ref().unwrap_or(&plan);
    let step = params.single_step(density);
    let camera = &params.camera;
    stats.light_table_nodes = depths.nodes();

    let mut nonfinite = 0;
    // f(voxel index in plan order, position, w_out, scratch).
    let mut bake = |what: &str, plan: &CachePlan, f: &(dyn Fn(usize, DVec3, Vec3, &mut Vec<u32>) -> Vec3 + Sync)| {
        let positions = plan.voxel_positions();
        let task = nimbus_progress::task(what, positions.len() as u64);
        let values: Vec<Vec3> = positions
            .par_iter()
            .enumerate()
            .map_init(Vec::new, |scratch, (i, &x)| {
                let value = f(i, x, toward_eye(camera, x), scratch);
                task.advance(1);
                value
            })
            .collect();
        let (volume, bad) = plan.volume_of(&values);
        nonfinite += bad;
        volume
    };
    let started = std::time::Instant::now();
    let li_single = params.bakes_single().then(|| {
        bake("single scattering", &plan, &|_, x, w_out, _| li_single(medium, &params.medium, &params.lights, &depths, x, w_out, step, params.min_transmittance))
    });
    stats.stages.push(("single", started.elapsed().as_millis() as u64));
    let li_multiple = match params.estimator {
        _ if !params.bakes_multiple(photons, emits) => None,
        MultipleEstimator::Photons => {
            let bins = PhotonBins::new(&photons.positions, gather_cell(photons, params.gather));
            let gathered = AtomicU64::new(0);
            let empty_below = empty_ball_density(&majorant);
            let volume = bake("photon gather", multiple_plan, &|_, x, w_out, scratch| {
                let (li, used) = li_multiple(density, empty_below, &params.medium, photons, &bins, params.gather, x, w_out, scratch);
                gathered.fetch_add(used as u64, Ordering::Relaxed);
                li
            });
            stats.photons_gathered = gathered.into_inner();
            Some(volume)
        }
        MultipleEstimator::Paths { per_voxel } => {
            let tracking = MajorantGrid::for_tracking(density, params.medium.extinction);
            let paths_medium = DensityMedium { majorant: &tracking, ..medium };
            let trace = |what: &str, _: &CachePlan, plan: &PathPlan, seed: u64| -> Result<Vec<PathMoments>, CacheError> {
                let task = nimbus_progress::task(what, plan.total());
                Ok((0..plan.counts.len())
                    .into_par_iter()
                    .map(|i| {
                        let paths = plan.counts[i];
                        let mut rng = Rng::with_domain(seed, i as u64, CACHE_PATHS_DOMAIN);
                        let sources = PathSources { environment: params.environment.as_ref(), emission };
                        let m = li_multiple_paths(paths_medium, &params.medium, &params.lights, &depths, sources, plan.origins_of(i), plan.octants_of(i), paths, params.path_max_depth, camera.eye(), &mut rng);
                        task.advance(paths as u64);
                        m
                    })
                    .collect())
            };
            let (volume, bad) = bake_paths(multiple_plan, density, &majorant, params, per_voxel, li_single.as_ref(), &mut stats, trace)?;
            nonfinite += bad;
            Some(volume)
        }
    };
    stats.nonfinite = nonfinite;
    let transmittance = stats.time("transmittance grids", || transmittance_grids(density, &depths));
    Ok((IlluminationCache { li_single, li_multiple, transmittance }, stats))
}

/// The transmittance toward each tabled light at the density's voxels, active where the
/// density is: what the table holds, on the lattice artists already have open.
pub fn transmittance_grids(density: &Volume<f32>, depths: &LightDepths) -> Vec<(usize, Volume<f32>)> {
    let origins: Vec<_> = density.bricks().map(|b| b.origin).collect();
    let transform = *density.transform();
    depths
        .per_light
        .iter()
        .enumerate()
        .filter_map(|(index, depth)| depth.as_ref().map(|d| (index, d)))
        .map(|(index, depth)| {
            let volume = Volume::from_brick_fn(transform, 0.0f32, &origins, |origin, values| {
                let brick = density.brick(density.brick_index(origin).expect("a density brick"));
                for (offset, value) in values.iter_mut().enumerate() {
                    *value = depth.transmittance(transform.to_world((origin + nimbus_volume::brick_local(offset)).as_dvec3())) as f32;
                }
                *brick.active
            });
            (index, volume)
        })
        .collect()
}

/// Cell size of the photon bins: the gather radius, or for k nearest the radius that holds k
/// photons on average over the photons' box (at most the largest radius).
pub fn gather_cell(photons: &PhotonMap, gather: Gather) -> f64 {
    match gather {
        Gather::Radius(r) => r,
        Gather::Neighbours { k, max_radius } => typical_radius(photons, k).min(max_radius),
    }
}

/// Mean density below which a gather ball counts as empty ([`EMPTY_BALL_FRACTION`]).
pub(crate) fn empty_ball_density(majorant: &MajorantGrid) -> f64 {
    EMPTY_BALL_FRACTION * majorant.max().max(0.0) as f64
}

/// Radius of a ball holding about `k` photons if they filled their bounding box evenly.
fn typical_radius(photons: &PhotonMap, k: u32) -> f64 {
    let (lo, hi) = photons.positions.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), &p| (a.min(p), b.max(p)));
    let volume = (hi - lo).max(DVec3::splat(1e-6)).element_product();
    (k as f64 * volume / (photons.len() as f64 * 4.0 / 3.0 * PI)).cbrt()
}

