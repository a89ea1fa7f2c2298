//! The CPU backend: photon paths in parallel with rayon; batching and accounting are
//! [`crate::batch::run_batches`], shared with the GPU backend.

use glam::{DVec3, Vec3};
use nimbus_optics::Rng;
use nimbus_tracking::{DensityMedium, EmissionField, FreePath, MediumRay};
use nimbus_volume::Volume;
use rayon::prelude::*;

use crate::batch::{prepare, run_batches, Batch, BatchPhoton, Emitter, PathEnd, PathSummary, Prepared, PHOTON_DOMAIN};
use crate::{DistanceSampling, PhotonError, PhotonMap, PhotonParams, TraceStats};

struct StoredPhoton {
    position: DVec3,
    power: Vec3,
    dir: Vec3,
}

struct PathResult {
    stored: Vec<StoredPhoton>,
    interactions: u32,
    end: PathEnd,
}

/// Traces photon `index`'s whole path. Stored powers are still to be divided by the number
/// of photons emitted.
fn trace_path(index: u64, emitter: &Emitter, medium: DensityMedium, params: &PhotonParams, step: f64) -> PathResult {
    let mut rng = Rng::with_domain(params.seed, index, PHOTON_DOMAIN);
    let emission = emitter.emit(&mut rng);
    let albedo = params.medium.albedo;
    let survival = params.medium.albedo_mean();
    let phase = params.medium.phase();
    let (mut x, mut w, mut power) = (emission.origin, emission.dir, emission.weight);
    let mut stored = Vec::new();
    if power == Vec3::ZERO {
        // A medium photon drawn where nothing emits (a cell's face at zero density) carries
        // nothing: counted as emitted and escaped, not traced.
        return PathResult { stored, interactions: 0, end: PathEnd::Escaped };
    }
    for interaction in 0..params.max_interactions {
        let ray = MediumRay::new(medium, x, w, 0.0, f64::INFINITY);
        let path = match params.distance {
            DistanceSampling::Simpson => ray.sample_simpson(-(1.0 - rng.next_f64()).ln(), step),
            DistanceSampling::Exponential => ray.sample_exponential(-(1.0 - rng.next_f64()).ln(), step),
            DistanceSampling::Delta => ray.sample_delta(&mut rng),
        };
        let FreePath::Interaction(t) = path else {
            return PathResult { stored, interactions: interaction, end: PathEnd::Escaped };
        };
        x += w * t;
        let w_in = w.as_vec3();
        if interaction > 0 || emission.store_first {
            stored.push(StoredPhoton { position: x, power: power * albedo, dir: w_in });
        }
        if rng.next_f32() >= survival {
            return PathResult { stored, interactions: interaction + 1, end: PathEnd::Absorbed };
        }
        power *= albedo / survival;
        w = phase.sample(w_in, rng.next_vec2()).as_dvec3().normalize();
    }
    PathResult { stored, interactions: params.max_interactions, end: PathEnd::Truncated }
}

/// Traces photons through `density` until `params.photons` are stored (or
/// `params.max_emitted` have left the lights).
pub fn trace_cpu(density: &Volume<f32>, params: &PhotonParams) -> Result<(PhotonMap, TraceStats), PhotonError> {
    trace_cpu_emitting(density, params, None)
}

/// [`trace_cpu`] with photons also leaving the medium's emission (`crate::medium`), stored
/// from their first interaction on, chosen among the sources in proportion to power.
pub fn trace_cpu_emitting(density: &Volume<f32>, params: &PhotonParams, emission: Option<&EmissionField>) -> Result<(PhotonMap, TraceStats), PhotonError> {
    let setup = match prepare(density, params, emission)? {
        Prepared::Trace(setup) => setup,
        Prepared::Skip(map, stats) => return Ok((map, stats)),
    };
    let medium = DensityMedium { motion: None, density, majorant: &setup.majorant, extinction: params.medium.extinction };
    run_batches(params, |range| {
        let paths: Vec<PathResult> =
            range.into_par_iter().map(|i| trace_path(i, &setup.emitter, medium, params, setup.step)).collect();
        let mut batch = Batch { paths: Vec::with_capacity(paths.len()), photons: Vec::new() };
        for (i, path) in paths.into_iter().enumerate() {
            batch.paths.push(PathSummary { interactions: path.interactions, end: path.end });
            batch.photons.extend(path.stored.into_iter().map(|p| BatchPhoton {
                path: i as u32,
                position: p.position,
                power: p.power,
                dir: p.dir,
            }));
        }
        Ok(batch)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch::{Setup, Source};
    use crate::emission::{PointEmission, DIRECTION_COLUMNS, DIRECTION_ROWS};
    use glam::IVec3;
    use nimbus_optics::{Light, Medium};
    use nimbus_volume::Transform;

    /// A cube of `n`^3 voxels of density `d`, voxel `voxel`, lowest voxel at the origin.
    fn cube(n: i32, d: f32, voxel: f64) -> Volume<f32> {
        let mut v = Volume::new(Transform::uniform(voxel, DVec3::ZERO), 0.0);
        for x in 0..n {
            for y in 0..n {
                for z in 0..n {
                    v.set(IVec3::new(x, y, z), d);
                }
            }
        }
        v
    }

    /// The fraction of `paths` photons of `emitter` that interact at least once.
    fn meeting_fraction(v: &Volume<f32>, setup: &Setup, emitter: &Emitter, params: &PhotonParams, paths: u64) -> f64 {
        let medium = DensityMedium { motion: None, density: v, majorant: &setup.majorant, extinction: params.medium.extinction };
        let met = (0..paths).into_par_iter().filter(|&i| trace_path(i, emitter, medium, params, setup.step).interactions > 0).count();
        met as f64 / paths as f64
    }

    /// A point light outside a cube: the power meeting it from the marked directions only
    /// equals the power meeting it from emission into every direction (the whole table,
    /// power 4 pi I), so the skipped directions carried nothing and the marked solid angle
    /// sets the power right.
    #[test]
    fn a_point_light_loses_nothing_by_skipping_directions() {
        let v = cube(16, 5.0, 0.1);
        let intensity = glam::Vec3::splat(3.0);
        let params = PhotonParams {
            lights: vec![Light::point(DVec3::new(0.5, 1.1, 3.0), intensity).unwrap()],
            medium: Medium { extinction: 1.0, ..Medium::default() },
            distance: DistanceSampling::Delta,
            ..PhotonParams::default()
        };
        let Prepared::Trace(setup) = prepare(&v, &params, None).unwrap() else { panic!("nothing to trace") };
        let Source::Point(table) = &setup.emitter.sources[0] else { panic!("a point light") };
        let all = (0..DIRECTION_ROWS).flat_map(|r| (0..DIRECTION_COLUMNS).map(move |c| [c, r])).collect();
        let every_direction = PointEmission { cells: all, ..table.clone() };
        let full_power = intensity * (4.0 * std::f32::consts::PI);
        let full = Emitter { sources: vec![Source::Point(every_direction)], power: vec![full_power], weight: vec![full_power], cdf: vec![1.0] };
        let (n_marked, n_full) = (100_000, 400_000);
        let (p_marked, p_full) = (meeting_fraction(&v, &setup, &setup.emitter, &params, n_marked), meeting_fraction(&v, &setup, &full, &params, n_full));
        let (power_marked, power_full) = (setup.emitter.power[0].x as f64, full_power.x as f64);
        let (marked, every) = (p_marked * power_marked, p_full * power_full);
        let sigma = (power_marked.powi(2) * p_marked * (1.0 - p_marked) / n_marked as f64 + power_full.powi(2) * p_full * (1.0 - p_full) / n_full as f64).sqrt();
        assert!((marked - every).abs() < 4.0 * sigma, "power meeting the cube: marked directions {marked}, every direction {every} (+- {sigma})");
        // The skip is real: the cube subtends a small part of the sphere.
        assert!(power_marked < 0.15 * power_full && p_marked > 0.5, "marked power {power_marked} of {power_full}, {p_marked} of its photons meet the cube");
    }

    /// The power that reaches the medium, E x the integral over the sun's plane of
    /// 1 - exp(-tau), against the photons that interact at least once times the power each
    /// carries: an emitter that missed part of the medium's shadow, or whose power did not
    /// match its area, fails it.
    #[test]
    fn the_power_meeting_the_medium_is_irradiance_times_its_shadow() {
        // A cube of N^3 voxels of density d: trilinear sampling makes it d F(x) F(y) F(z), F
        // one over the voxels and ramping to zero over the voxel beyond each face, so a
        // vertical ray at (x, y) sees tau = extinction d N voxel F(x) F(y).
        let (n, d, voxel) = (16, 5.0f32, 0.1);
        let v = cube(n, d, voxel);
        let f = |x: f64| (x + 1.0).min(n as f64 - x).clamp(0.0, 1.0);
        let tau0 = d as f64 * n as f64 * voxel;
        let steps = 2000;
        let h = (n + 1) as f64 / steps as f64;
        let mut shadow = 0.0;
        for i in 0..steps {
            for j in 0..steps {
                let (x, y) = (-1.0 + (i as f64 + 0.5) * h, -1.0 + (j as f64 + 0.5) * h);
                shadow += 1.0 - (-tau0 * f(x) * f(y)).exp();
            }
        }
        let expected = shadow * h * h * voxel * voxel * 2.0;

        let params = PhotonParams {
            lights: vec![Light::sun(glam::Vec3::NEG_Z, glam::Vec3::splat(2.0)).unwrap()],
            medium: Medium { extinction: 1.0, ..Medium::default() },
            distance: DistanceSampling::Delta,
            ..PhotonParams::default()
        };
        let Prepared::Trace(setup) = prepare(&v, &params, None).unwrap() else { panic!("nothing to trace") };
        let medium = DensityMedium { motion: None, density: &v, majorant: &setup.majorant, extinction: 1.0 };
        let paths = 100_000;
        let met = (0..paths).into_par_iter().filter(|&i| trace_path(i, &setup.emitter, medium, &params, setup.step).interactions > 0).count();
        let power = setup.emitter.power[0].x as f64;
        let p = met as f64 / paths as f64;
        let estimate = p * power;
        let sigma = power * (p * (1.0 - p) / paths as f64).sqrt();
        assert!((estimate - expected).abs() < 4.0 * sigma, "power meeting the medium {estimate} (+- {sigma}), expected {expected}; emitted {power}");
        // The emitter's slack around the shadow is small: most photons meet the cube.
        assert!(p > 0.7, "{p}");
    }
}
