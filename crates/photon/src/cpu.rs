//! The CPU backend: photon paths in parallel with rayon; batching and accounting are
//! [`crate::batch::run_batches`], shared with the GPU backend.

use glam::{DVec3, Vec3};
use nimbus_optics::Rng;
use nimbus_tracking::{DensityMedium, FreePath, MediumRay};
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
        if interaction > 0 {
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
    let setup = match prepare(density, params)? {
        Prepared::Trace(setup) => setup,
        Prepared::Skip(map, stats) => return Ok((map, stats)),
    };
    let medium = DensityMedium { density, majorant: &setup.majorant, extinction: params.medium.extinction };
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
