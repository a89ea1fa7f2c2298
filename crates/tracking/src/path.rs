//! Volumetric path tracing: the light a path gathers by next-event estimation at each of its
//! collisions. The reference path tracer (vdbmarch --reference) starts its paths at the eye;
//! vdbcache's path-traced multiple scattering starts them at a cache voxel.

use glam::{DVec3, Vec3};
use nimbus_optics::{power_heuristic, Environment, HenyeyGreenstein, Light, Medium, Rng};

use crate::{DensityMedium, EmissionField, FreePath, MediumRay, Shadowing};

/// Bounce from which Russian roulette may end a path.
pub const ROULETTE_FROM_DEPTH: u32 = 3;
/// Ratio-tracking estimates below this go to Russian roulette (kept unbiased).
pub const RATIO_ROULETTE: f64 = 0.05;

/// One path's light, split by the collision it was scattered at: the first (`single`) and
/// every later one (`multiple`), and the medium's own emission (`emission`, from every
/// collision).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathLight {
    pub single: Vec3,
    pub multiple: Vec3,
    pub emission: Vec3,
}

impl PathLight {
    pub fn total(self) -> Vec3 {
        self.single + self.multiple + self.emission
    }
}

/// How a path's first direction was chosen, which decides what its escape adds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathStart {
    /// A camera ray: if it escapes it sees the background, which the caller adds (the
    /// reference tracer through its ratio-tracked transmittance).
    Camera,
    /// Drawn by the phase function at the origin for light arriving along `w_in` there
    /// (vdbcache's paths from a cache voxel): an escape adds the environment, weighed by
    /// multiple importance sampling against the caller's own [`environment_nee`] at the
    /// origin.
    Scattered { w_in: Vec3 },
}

/// What a path meets besides the lights: the environment and the medium's emission.
#[derive(Clone, Copy, Default)]
pub struct PathSources<'a> {
    pub environment: Option<&'a Environment>,
    pub emission: Option<&'a EmissionField<'a>>,
}

/// Next-event estimation of the environment at `x` toward `w_out`: one direction drawn
/// from the environment ([`Environment::sample`]), its transmittance to infinity by ratio
/// tracking, weighed by the power heuristic against the phase function's own sampling of
/// that direction (which [`trace_path`] adds when a flight escapes) unless `alone`, when no
/// phase-sampled direction follows. A uniform sky takes no next-event estimate but `alone`
/// ([`Environment::wants_next_event`]): escaping flights carry all of it, and draw nothing
/// here.
pub fn environment_nee(medium: DensityMedium, phase: HenyeyGreenstein, environment: &Environment, x: DVec3, w_out: Vec3, alone: bool, rng: &mut Rng) -> Vec3 {
    if !alone && !environment.wants_next_event() {
        return Vec3::ZERO;
    }
    let sample = environment.sample(rng.next_vec2());
    if sample.pdf <= 0.0 || sample.radiance == Vec3::ZERO {
        // Keep the stream's length independent of the draw.
        let _ = rng.next_f32();
        return Vec3::ZERO;
    }
    let p = phase.eval_dirs(-sample.toward, w_out);
    let weight = if alone { 1.0 } else { power_heuristic(sample.pdf, p) };
    if p * weight <= 0.0 {
        let _ = rng.next_f32();
        return Vec3::ZERO;
    }
    let tr = MediumRay::new(medium, x, sample.toward.as_dvec3(), 0.0, f64::INFINITY).transmittance_ratio(rng, RATIO_ROULETTE) as f32;
    sample.radiance * (tr * p * weight / sample.pdf)
}

/// The radiance arriving at `origin` from direction `-dir` (unit, world), scattered in the
/// medium, estimated by one path: free flights by delta tracking against the majorant grid;
/// at each real collision the throughput takes the albedo (sigma_s / sigma_t) and next-event
/// estimation adds each light's `E p(w_light, w_out) T`, with T as `shadowing` finds it (ratio
/// tracking, or a light's tabled optical depth); then
/// Henyey-Greenstein picks the next direction. Russian roulette on the throughput from
/// [`ROULETTE_FROM_DEPTH`]; at most `max_depth` collisions.
///
/// Suns and points are delta lights: next-event estimation is the only way their light
/// enters a path. A map (`sources.environment`) enters two ways, combined by the power
/// heuristic: [`environment_nee`] at each collision, and a phase-sampled flight that
/// escapes, which adds the environment's radiance in its direction (see [`PathStart`] for
/// the first flight); a uniform sky by escaping flights alone. At the last collision `max_depth` no flight follows, so its
/// next-event estimate takes the whole weight.
///
/// With `sources.emission`, every real collision at x also adds `beta e(x) / sigma_t(x)` (beta the
/// throughput before the collision's albedo), e the emitted radiance per unit length: the
/// collision estimator of emission. Real collisions along a flight fall with density
/// `T(t) sigma_t(x(t))`, so its expectation is `integral T e dt` over where sigma_t > 0,
/// the emission integral of design.md's convention (pbrt-v4's VolPathIntegrator adds
/// `beta sigma_a Le / sigma_maj` at every tentative collision instead, which reaches
/// emission where sigma_t = 0 too; ours emits only where the medium is, so the two agree,
/// and ours spends no lookups at null collisions).
///
/// Light scattered last at the first collision (or, for a [`PathStart::Scattered`] path, at
/// the origin) counts as `single`, later as `multiple`.
#[allow(clippy::too_many_arguments)]
pub fn trace_path(
    medium: DensityMedium,
    optics: &Medium,
    lights: &[Light],
    shadowing: Shadowing,
    origin: DVec3,
    dir: DVec3,
    start: PathStart,
    max_depth: u32,
    rng: &mut Rng,
    sources: PathSources,
) -> PathLight {
    let phase = optics.phase();
    let environment = sources.environment.filter(|e| !e.is_black());
    let mut light = PathLight::default();
    let (mut x, mut w) = (origin, dir);
    let mut beta = Vec3::ONE;
    // The phase pdf the current flight's direction was drawn with (None: a camera ray).
    let mut flight_pdf = match start {
        PathStart::Camera => None,
        PathStart::Scattered { w_in } => Some(phase.pdf(w_in, dir.as_vec3())),
    };
    for depth in 1..=max_depth {
        let FreePath::Interaction(t) = MediumRay::new(medium, x, w, 0.0, f64::INFINITY).sample_delta(rng) else {
            if let (Some(env), Some(pdf)) = (environment, flight_pdf) {
                let toward = w.as_vec3();
                let weight = if env.wants_next_event() { power_heuristic(pdf, env.pdf(toward)) } else { 1.0 };
                let seen = beta * env.radiance(toward) * weight;
                // Scattered last at collision depth - 1 (0: the origin).
                if depth <= 2 {
                    light.single += seen;
                } else {
                    light.multiple += seen;
                }
            }
            break;
        };
        x += w * t;
        if let Some(e) = sources.emission {
            let sigma_t = medium.extinction as f64 * medium.density_at(x).max(0.0) as f64;
            if sigma_t > 0.0 {
                let at = medium.motion.map_or(x, |m| m.back(x));
                light.emission += beta * e.at(at) * (1.0 / sigma_t) as f32;
            }
        }
        beta *= optics.albedo;
        let w_out = -w.as_vec3();
        let mut direct = Vec3::ZERO;
        for (index, l) in lights.iter().enumerate() {
            // A sun's disc: one direction over it per estimate (no draw for parallel light,
            // so its paths keep their random numbers).
            let incident = if l.has_disc() { l.incident_over_disc(x, rng.next_vec2()) } else { l.incident(x) };
            if incident.irradiance == Vec3::ZERO {
                continue;
            }
            let mut ray = || MediumRay::new(medium, x, incident.to_light.as_dvec3(), 0.0, incident.distance).transmittance_ratio(rng, RATIO_ROULETTE);
            let tr = match shadowing {
                Shadowing::Tabled(depths) => depths.transmittance(index, x, ray),
                Shadowing::RatioTracked => ray(),
            } as f32;
            if tr > 0.0 {
                direct += incident.irradiance * (tr * phase.eval_dirs(-incident.to_light, w_out));
            }
        }
        if let Some(env) = environment {
            direct += environment_nee(medium, phase, env, x, w_out, depth == max_depth, rng);
        }
        if depth == 1 {
            light.single += beta * direct;
        } else {
            light.multiple += beta * direct;
        }
        if depth >= ROULETTE_FROM_DEPTH {
            let q = beta.max_element();
            if q <= 0.0 {
                break;
            }
            if q < 1.0 {
                if rng.next_f32() >= q {
                    break;
                }
                beta /= q;
            }
        }
        let (next, pdf) = phase.sample_with_pdf(w.as_vec3(), rng.next_vec2());
        w = next.as_dvec3().normalize();
        flight_pdf = Some(pdf);
    }
    light
}
