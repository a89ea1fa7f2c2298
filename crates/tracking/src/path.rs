//! Volumetric path tracing: the light a path gathers by next-event estimation at each of its
//! collisions. The reference path tracer (vdbmarch --reference) starts its paths at the eye;
//! vdbcache's path-traced multiple scattering starts them at a cache voxel.

use glam::{DVec3, Vec3};
use nimbus_optics::{Light, Medium, Rng};

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

/// The radiance arriving at `origin` from direction `-dir` (unit, world), scattered in the
/// medium, estimated by one path: free flights by delta tracking against the majorant grid;
/// at each real collision the throughput takes the albedo (sigma_s / sigma_t) and next-event
/// estimation adds each light's `E p(w_light, w_out) T`, with T as `shadowing` finds it (ratio
/// tracking, or a light's tabled optical depth); then
/// Henyey-Greenstein picks the next direction. Russian roulette on the throughput from
/// [`ROULETTE_FROM_DEPTH`]; at most `max_depth` collisions.
///
/// Lights are suns and points (delta lights), so next-event estimation is the only way light
/// enters a path and needs no MIS; paths that escape add nothing.
///
/// With `emission`, every real collision at x also adds `beta e(x) / sigma_t(x)` (beta the
/// throughput before the collision's albedo), e the emitted radiance per unit length: the
/// collision estimator of emission. Real collisions along a flight fall with density
/// `T(t) sigma_t(x(t))`, so its expectation is `integral T e dt` over where sigma_t > 0,
/// the emission integral of design.md's convention (pbrt-v4's VolPathIntegrator adds
/// `beta sigma_a Le / sigma_maj` at every tentative collision instead, which reaches
/// emission where sigma_t = 0 too; ours emits only where the medium is, so the two agree,
/// and ours spends no lookups at null collisions).
#[allow(clippy::too_many_arguments)]
pub fn trace_path(
    medium: DensityMedium,
    optics: &Medium,
    lights: &[Light],
    shadowing: Shadowing,
    origin: DVec3,
    dir: DVec3,
    max_depth: u32,
    rng: &mut Rng,
    emission: Option<&EmissionField>,
) -> PathLight {
    let phase = optics.phase();
    let mut light = PathLight::default();
    let (mut x, mut w) = (origin, dir);
    let mut beta = Vec3::ONE;
    for depth in 1..=max_depth {
        let FreePath::Interaction(t) = MediumRay::new(medium, x, w, 0.0, f64::INFINITY).sample_delta(rng) else {
            break;
        };
        x += w * t;
        if let Some(e) = emission {
            let sigma_t = medium.extinction as f64 * medium.density.sample_world(x).max(0.0) as f64;
            if sigma_t > 0.0 {
                light.emission += beta * e.at(x) * (1.0 / sigma_t) as f32;
            }
        }
        beta *= optics.albedo;
        let w_out = -w.as_vec3();
        let mut direct = Vec3::ZERO;
        for (index, l) in lights.iter().enumerate() {
            let incident = l.incident(x);
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
        w = phase.sample(w.as_vec3(), rng.next_vec2()).as_dvec3().normalize();
    }
    light
}
