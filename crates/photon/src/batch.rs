//! What both backends share: the set-up (what to skip, the emitter, the majorant grid, the
//! Simpson step) and the batch loop with its accounting and stopping rule. A backend only
//! supplies "trace photons `start..end` and return what each path did"; the map's order,
//! the emitted count and the final power scale are decided here, once.

use std::ops::Range;

use glam::{DVec3, Vec3};
use nimbus_optics::{Environment, Light, Rng};
use nimbus_volume::{MajorantGrid, Volume};

use crate::emission::{PointEmission, SunEmission};
use crate::medium::MediumEmission;
use nimbus_tracking::EmissionField;
use crate::{PhotonError, PhotonMap, PhotonParams, TraceStats};

/// Random-number domain of photon paths (kept apart from other uses of the same seed).
pub(crate) const PHOTON_DOMAIN: u32 = 0x5048_4f54; // "PHOT"

/// Photons emitted before the tracer decides whether anything can be stored at all.
const FIRST_BATCH: u64 = 1 << 14;

/// Where photons leave one light from.
pub(crate) enum Source<'a> {
    /// A sun's emitting lattice over the medium's projection.
    Sun(SunEmission),
    /// A point light's directions toward the medium.
    Point(PointEmission),
    /// The medium's emitting cells (after the lights).
    Medium(MediumEmission<'a>),
    /// The sky or environment map (last).
    Environment(EnvironmentEmission),
}

/// Photons from the environment: a direction drawn from it ([`Environment::sample`]), then
/// a point uniform on the disc of the medium's bounding sphere facing that direction, outside
/// the sphere; each carries `L(w) pi R^2 / pdf(w)` (the flux through the disc from around
/// w), so the source's power is `pi R^2` times the integral of L over the sphere.
pub(crate) struct EnvironmentEmission {
    pub environment: Environment,
    pub centre: DVec3,
    pub radius: f64,
}

impl EnvironmentEmission {
    fn new(environment: &Environment, density: &Volume<f32>) -> Option<EnvironmentEmission> {
        let (lo, hi) = density.world_bounds()?;
        // Trilinear sampling reaches a voxel beyond the active ones.
        let radius = (hi - lo).length() * 0.5 + density.transform().voxel_size().max_element() * 2.0;
        (!environment.is_black()).then(|| EnvironmentEmission { environment: environment.clone(), centre: (lo + hi) * 0.5, radius })
    }

    fn disc_area(&self) -> f64 {
        std::f64::consts::PI * self.radius * self.radius
    }

    fn power(&self) -> Vec3 {
        self.environment.mean_radiance() * (4.0 * std::f64::consts::PI * self.disc_area()) as f32
    }

    /// Origin, unit direction of travel, and the flux the photon carries.
    fn sample(&self, rng: &mut Rng) -> (DVec3, DVec3, Vec3) {
        let s = self.environment.sample(rng.next_vec2());
        let disc = nimbus_optics::sample_uniform_disk_concentric(rng.next_vec2()).as_dvec2() * self.radius;
        let toward = s.toward.as_dvec3().normalize();
        let (t, b) = nimbus_optics::orthonormal_basis(s.toward);
        let origin = self.centre + toward * (2.0 * self.radius) + t.as_dvec3() * disc.x + b.as_dvec3() * disc.y;
        let flux = if s.pdf > 0.0 { s.radiance * (self.disc_area() / s.pdf as f64) as f32 } else { Vec3::ZERO };
        (origin, -toward, flux)
    }
}

/// Where and how photons leave the lights and the emitting medium: per source its power and
/// the probability of choosing it (proportional to its mean power).
pub(crate) struct Emitter<'a> {
    pub sources: Vec<Source<'a>>,
    /// Each source's emitted power: E x emitting area for a sun, I x emitting solid angle for a
    /// point light, 4 pi integral e dV for the medium.
    pub power: Vec<Vec3>,
    /// Light power / choice probability: the power a photon carries before dividing by the
    /// number emitted.
    pub weight: Vec<Vec3>,
    pub cdf: Vec<f32>,
}

/// One photon leaving a light: origin, unit direction, power times photons emitted, and
/// whether its first interaction is stored.
pub(crate) struct Emission {
    pub origin: DVec3,
    pub dir: DVec3,
    pub weight: Vec3,
    /// A light's photon arrives at its first interaction as direct light, which vdbcache
    /// counts as single scattering, so it is not stored there; the medium's emission has no
    /// such separate term (the cache's Li_single is the lights' alone), so its photons are
    /// stored from their first interaction on (design.md section 5).
    pub store_first: bool,
}

impl<'a> Emitter<'a> {
    /// The lights' sources over `density`, which must hold a positive voxel, and the medium's
    /// where `emission` emits; None when they emit no power.
    pub fn new(lights: &[Light], environment: Option<&Environment>, density: &'a Volume<f32>, emission: Option<&EmissionField<'a>>) -> Option<Emitter<'a>> {
        let mut sources = Vec::with_capacity(lights.len());
        let mut power = Vec::with_capacity(lights.len());
        for light in lights {
            let (source, extent) = match *light {
                Light::Sun { dir, .. } => {
                    let emission = SunEmission::new(dir, density).expect("the density holds a positive voxel");
                    let area = emission.area();
                    (Source::Sun(emission), area)
                }
                Light::Point { position, .. } => {
                    let emission = PointEmission::new(position, density);
                    let solid_angle = emission.solid_angle();
                    (Source::Point(emission), solid_angle)
                }
            };
            sources.push(source);
            power.push(light.emitted_power(extent));
        }
        if let Some(medium) = emission.and_then(|e| MediumEmission::new(density, *e)) {
            power.push(medium.power());
            sources.push(Source::Medium(medium));
        }
        if let Some(sky) = environment.and_then(|e| EnvironmentEmission::new(e, density)) {
            power.push(sky.power());
            sources.push(Source::Environment(sky));
        }
        let total: f32 = power.iter().map(|p| p.element_sum()).sum();
        if total.is_nan() || total <= 0.0 {
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
        Some(Emitter { sources, power, weight, cdf })
    }

    /// Source `i`'s share of the total power: the probability of choosing it (weight[i] sums
    /// to the total).
    pub fn share(&self, i: usize) -> f32 {
        self.power[i].element_sum() / self.weight[i].element_sum()
    }

    /// Which light photon with first draw `u` leaves from (mirrored in photon.wgsl).
    pub fn choose(&self, u: f32) -> usize {
        self.cdf.iter().position(|&c| u < c).unwrap_or(self.sources.len() - 1)
    }

    pub fn emit(&self, rng: &mut Rng) -> Emission {
        let i = self.choose(rng.next_f32());
        match &self.sources[i] {
            Source::Sun(emission) => Emission { origin: emission.sample_point(rng), dir: emission.normal, weight: self.weight[i], store_first: false },
            Source::Point(emission) => Emission { origin: emission.position, dir: emission.sample_direction(rng), weight: self.weight[i], store_first: false },
            Source::Environment(sky) => {
                // weight[i] sums to the total power: the flux over this source's share of it
                // (the probability of choosing it).
                let (origin, dir, flux) = sky.sample(rng);
                Emission { origin, dir, weight: flux / self.share(i), store_first: true }
            }
            Source::Medium(emission) => {
                // weight[i] sums to the total power over all sources; the cell's importance
                // weight is in the ratio (medium.rs).
                let (origin, dir, ratio) = emission.sample(rng);
                Emission { origin, dir, weight: ratio * self.weight[i].element_sum(), store_first: true }
            }
        }
    }
}

/// How one path ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PathEnd {
    Escaped,
    Absorbed,
    Truncated,
}

/// What one path did, for the statistics.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PathSummary {
    pub interactions: u32,
    pub end: PathEnd,
}

/// A photon stored by path `path` of its batch (0 = the batch's first photon index). Its
/// power is still to be divided by the number of photons emitted.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BatchPhoton {
    pub path: u32,
    pub position: DVec3,
    pub power: Vec3,
    pub dir: Vec3,
}

/// A traced batch: one summary per path in index order, and the stored photons sorted by
/// (path, interaction).
#[derive(Default)]
pub(crate) struct Batch {
    pub paths: Vec<PathSummary>,
    pub photons: Vec<BatchPhoton>,
}

/// What a trace needs once it is known there is something to trace.
pub(crate) struct Setup<'a> {
    pub emitter: Emitter<'a>,
    pub bounds: (DVec3, DVec3),
    pub majorant: MajorantGrid,
    /// Simpson step (and exponential search step) in world units.
    pub step: f64,
}

/// Either a [`Setup`], or the finished (empty) result of a trace with nothing to do.
pub(crate) enum Prepared<'a> {
    Trace(Setup<'a>),
    Skip(PhotonMap, TraceStats),
}

fn skipped(why: &str, mut stats: TraceStats) -> (PhotonMap, TraceStats) {
    stats.skipped = Some(why.to_string());
    (PhotonMap::default(), stats)
}

/// Validates `params` and decides whether anything can be stored (design.md section 7:
/// work whose contribution is zero is not done); `emission`, the medium's, emits photons too.
pub(crate) fn prepare<'a>(density: &'a Volume<f32>, params: &PhotonParams, emission: Option<&EmissionField<'a>>) -> Result<Prepared<'a>, PhotonError> {
    params.validate()?;
    let skip = |why: &str| {
        let (map, stats) = skipped(why, TraceStats::default());
        Ok(Prepared::Skip(map, stats))
    };
    if params.photons == 0 {
        return skip("no photons requested");
    }
    if params.medium.albedo_mean() <= 0.0 || params.medium.extinction <= 0.0 {
        return skip("the medium does not scatter (albedo or extinction 0)");
    }
    let Some(bounds) = density.world_bounds() else {
        return skip("the density grid is empty");
    };
    if !density.bricks().any(|b| b.values.iter().any(|&d| d > 0.0)) {
        return skip("no voxel of the density grid is above 0");
    }
    let Some(emitter) = Emitter::new(&params.lights, params.environment.as_ref(), density, emission) else {
        return skip(if emission.is_some() { "neither the lights nor the medium emit power" } else { "the lights emit no power" });
    };
    let majorant = MajorantGrid::for_tracking(density, params.medium.extinction);
    let step = params.step * density.transform().voxel_size().min_element();
    Ok(Prepared::Trace(Setup { emitter, bounds, majorant, step }))
}

/// Emits photons in index-ordered batches, `trace(start..end)` tracing each batch, until
/// `params.photons` are stored or `params.max_emitted` have left the lights; then scales the
/// powers by 1 / emitted. Paths are kept in index order up to the one that completes the
/// count, so the map depends neither on batch sizes nor on the backend's scheduling.
pub(crate) fn run_batches(
    params: &PhotonParams,
    mut trace: impl FnMut(Range<u64>) -> Result<Batch, PhotonError>,
) -> Result<(PhotonMap, TraceStats), PhotonError> {
    let mut stats = TraceStats::default();
    let mut map = PhotonMap::default();
    let mut next = 0u64;
    let mut batch = FIRST_BATCH.min(params.max_emitted);
    let task = nimbus_progress::task("photons", params.photons);
    'batches: while next < params.max_emitted && (map.len() as u64) < params.photons {
        let end = (next + batch).min(params.max_emitted);
        let traced = trace(next..end)?;
        let before = map.len() as u64;
        debug_assert_eq!(traced.paths.len() as u64, end - next);
        let mut photons = traced.photons.iter().peekable();
        for (i, path) in traced.paths.iter().enumerate() {
            stats.emitted += 1;
            stats.interactions += path.interactions as u64;
            match path.end {
                PathEnd::Escaped => stats.escaped += 1,
                PathEnd::Absorbed => stats.absorbed += 1,
                PathEnd::Truncated => stats.truncated += 1,
            }
            while let Some(p) = photons.next_if(|p| p.path as usize == i) {
                map.positions.push(p.position);
                map.power.push(p.power);
                map.dir.push(p.dir);
            }
            if map.len() as u64 >= params.photons {
                break 'batches;
            }
        }
        task.advance((map.len() as u64).min(params.photons) - before.min(params.photons));
        next = end;
        if stats.interactions == 0 {
            let (map, stats) = skipped("no photon of the first batch met the medium (too thin along the lights' paths)", stats);
            return Ok((map, stats));
        }
        // Size the next batch from the yield so far, aiming a little past the target.
        let per_photon = (map.len() as f64 / stats.emitted as f64).max(1e-3);
        let mut remaining = params.photons - (map.len() as u64).min(params.photons);
        if task.shown() {
            // A bar on a terminal moves in eighths (which photons are stored does not
            // depend on the batches: each path's random numbers are keyed by its index).
            remaining = remaining.min(params.photons.div_ceil(8));
        }
        let wanted = (remaining as f64 / per_photon * 1.05) as u64;
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
