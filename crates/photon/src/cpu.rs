//! The CPU backend: photon paths in parallel with rayon, emitted in index-ordered batches.

use glam::{DVec3, Vec3};
use nimbus_optics::{sample_uniform_sphere, EmissionDisc, Light, Rng};
use nimbus_tracking::{DensityMedium, FreePath, MediumRay};
use nimbus_volume::{MajorantGrid, Volume};
use rayon::prelude::*;

use crate::{DistanceSampling, PhotonError, PhotonMap, PhotonParams, TraceStats};

/// Random-number domain of photon paths (kept apart from other uses of the same seed).
pub(crate) const PHOTON_DOMAIN: u32 = 0x5048_4f54; // "PHOT"

/// Photons emitted before the tracer decides whether anything can be stored at all.
const FIRST_BATCH: u64 = 1 << 14;

/// Where and how photons leave the lights: per light its power and the probability of
/// choosing it (proportional to its mean power), plus the sun discs for the volume's bounds.
pub(crate) struct Emitter {
    lights: Vec<Light>,
    /// Light power / choice probability: the power a photon carries before dividing by the
    /// number emitted.
    weight: Vec<Vec3>,
    cdf: Vec<f32>,
    /// Each sun's emission disc over the volume's bounds (None for point lights).
    discs: Vec<Option<EmissionDisc>>,
}

/// One photon leaving a light: origin, unit direction, power times photons emitted.
pub(crate) struct Emission {
    pub origin: DVec3,
    pub dir: DVec3,
    pub weight: Vec3,
}

impl Emitter {
    pub fn new(lights: &[Light], bounds: (DVec3, DVec3)) -> Option<Emitter> {
        let power: Vec<Vec3> = lights.iter().map(|l| l.emitted_power(bounds.0, bounds.1)).collect();
        let total: f32 = power.iter().map(|p| p.element_sum()).sum();
        if !(total > 0.0) {
            return None;
        }
        let mut acc = 0.0;
        let cdf = power
            .iter()
            .map(|p| {
                acc += p.element_sum() / total;
                acc
            })
            .collect();
        let weight = power.iter().map(|p| if p.element_sum() > 0.0 { *p * (total / p.element_sum()) } else { Vec3::ZERO }).collect();
        let discs = lights.iter().map(|l| l.emission_disc(bounds.0, bounds.1)).collect();
        Some(Emitter { lights: lights.to_vec(), weight, cdf, discs })
    }

    pub fn emit(&self, rng: &mut Rng) -> Emission {
        let u = rng.next_f32();
        let i = self.cdf.iter().position(|&c| u < c).unwrap_or(self.lights.len() - 1);
        match (self.lights[i], &self.discs[i]) {
            (_, Some(disc)) => {
                Emission { origin: disc.sample_point(rng.next_vec2()), dir: disc.normal, weight: self.weight[i] }
            }
            (Light::Point { position, .. }, None) => Emission {
                origin: position,
                dir: sample_uniform_sphere(rng.next_vec2()).as_dvec3().normalize(),
                weight: self.weight[i],
            },
            (Light::Sun { .. }, None) => unreachable!("every sun has an emission disc"),
        }
    }
}

/// How one path ended.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PathEnd {
    Escaped,
    Absorbed,
    Truncated,
}

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
    params.validate()?;
    let mut stats = TraceStats::default();
    let skip = |why: &str, mut stats: TraceStats| {
        stats.skipped = Some(why.to_string());
        Ok((PhotonMap::default(), stats))
    };
    if params.photons == 0 {
        return skip("no photons requested", stats);
    }
    if params.medium.albedo_mean() <= 0.0 || params.medium.extinction <= 0.0 {
        return skip("the medium does not scatter (albedo or extinction 0)", stats);
    }
    let Some(bounds) = density.world_bounds() else {
        return skip("the density grid is empty", stats);
    };
    let Some(emitter) = Emitter::new(&params.lights, bounds) else {
        return skip("the lights emit no power", stats);
    };
    let majorant = MajorantGrid::build(density);
    let medium = DensityMedium { density, majorant: &majorant, extinction: params.medium.extinction };
    let step = params.step * density.transform().voxel_size().min_element();

    let mut map = PhotonMap::default();
    let mut next = 0u64;
    let mut batch = FIRST_BATCH.min(params.max_emitted);
    while next < params.max_emitted && (map.len() as u64) < params.photons {
        let end = (next + batch).min(params.max_emitted);
        let paths: Vec<PathResult> =
            (next..end).into_par_iter().map(|i| trace_path(i, &emitter, medium, params, step)).collect();
        // Keep paths in index order up to the one that completes the count, so the map does
        // not depend on batch sizes or thread count.
        for path in paths {
            stats.emitted += 1;
            stats.interactions += path.interactions as u64;
            match path.end {
                PathEnd::Escaped => stats.escaped += 1,
                PathEnd::Absorbed => stats.absorbed += 1,
                PathEnd::Truncated => stats.truncated += 1,
            }
            for p in path.stored {
                map.positions.push(p.position);
                map.power.push(p.power);
                map.dir.push(p.dir);
            }
            if map.len() as u64 >= params.photons {
                break;
            }
        }
        next = end;
        if stats.interactions == 0 {
            return skip("no density in the lights' paths", stats);
        }
        // Size the next batch from the yield so far, aiming a little past the target.
        let per_photon = (map.len() as f64 / stats.emitted as f64).max(1e-3);
        let wanted = ((params.photons - (map.len() as u64).min(params.photons)) as f64 / per_photon * 1.05) as u64;
        batch = wanted.clamp(1024, 1 << 22);
    }
    map.positions.truncate(params.photons as usize);
    map.power.truncate(params.photons as usize);
    map.dir.truncate(params.photons as usize);
    let scale = 1.0 / stats.emitted.max(1) as f32;
    map.power.iter_mut().for_each(|p| *p *= scale);
    stats.stored = map.len() as u64;
    Ok((map, stats))
}
