//! Rays through the density volume: the one place that knows how to integrate extinction
//! along a ray and how to sample where along it light interacts.
//!
//! Every stage walks rays through `sigma_t(x) = extinction * density(x)`: vdbphoton samples
//! free paths, vdbcache integrates transmittance toward the lights, vdbmarch marches camera
//! rays, and the reference path tracer tracks unbiasedly. They all go through a
//! [`MediumRay`], which walks the [`MajorantGrid`] so empty cells are stepped over in one
//! move (design.md section 7), and offers:
//!
//! - [`MediumRay::optical_depth`]: composite Simpson over non-empty segments, panels split
//!   at voxel boundaries so the trilinear density is integrated exactly;
//! - [`MediumRay::sample_simpson`]: the paper's Eq. 2, inverting the Simpson-integrated
//!   optical depth, `integral_0^d sigma_t = -ln(1 - xi)`, exactly within the last step by a
//!   quadratic fit of sigma_t;
//! - [`MediumRay::sample_exponential`]: the paper's Eq. 1, sigma_t frozen at the first
//!   non-empty point (biased; kept for comparison);
//! - [`MediumRay::sample_delta`]: delta (Woodcock) tracking against the majorant grid,
//!   unbiased;
//! - [`MediumRay::transmittance_ratio`]: ratio tracking, an unbiased transmittance estimate.
//!
//! - [`OpticalDepthVolume`]: the optical depth toward a sun tabled once on a light-aligned
//!   lattice, so single scattering and next-event estimation look it up instead of tracing
//!   a shadow ray per point ([`LightDepths`] per light, [`Shadowing`] for the paths).
//!
//! On these, [`trace_path`] traces a volumetric path with next-event estimation: the
//! reference path tracer's paths from the eye and vdbcache's path-traced multiple scattering;
//! with an [`EmissionField`] also the medium's emission, by the collision estimator
//! `beta e / sigma_t` at each real collision (the reference's paths, and vdbcache's, which so
//! hold emitted light the medium scatters).
//!
//! The WGSL twin is `shaders/tracking.wgsl` ([`TRACKING_WGSL`], with [`GpuMajorantInfo`] and
//! [`majorant_buffer`] for the host side), and `shaders/path.wgsl` ([`PATH_WGSL`]) that of
//! [`trace_path`].
//!
//! Rays are given in world space with a unit direction, so every distance is a world length;
//! they are carried into index space once (the transform is affine, so the parameter t is the
//! same in both).

mod gpu;
mod optical_depth;
mod path;

pub use gpu::{emission_wgsl, light_tables_wgsl, majorant_buffer, medium_stage, tracking_wgsl_moving, wgsl_mirror, wgsl_mirrors, GpuEmission, GpuLightTables, GpuMajorantInfo, GpuMotion, GpuMotionInfo, NO_LIGHT_TABLES_WGSL, OPTICAL_DEPTH_WGSL, PATH_WGSL, TRACKING_WGSL};
pub use optical_depth::{along_ray, ray_optical_depths, LightDepths, LightLattice, LightTablePlan, OpticalDepthVolume, Shadowing, TabledTransmittance, SINGLE_SPREAD, TABLED_SPREAD, TABLE_BRICK_VALUES, ALONG_RAY_FLOOR};
pub use path::{environment_nee, long_path_loop_iterations, trace_path, PathLight, PathSources, PathStart, PROBE_FROM_G, RATIO_ROULETTE, ROULETTE_FROM_DEPTH};

use glam::DVec3;
use nimbus_optics::Rng;
use nimbus_volume::{MajorantGrid, Volume};

/// A density volume seen as a medium: the density, its majorant grid and the extinction scale;
/// with `motion`, the medium at another time than the frame's (Eulerian motion blur: the
/// majorant must then bound the moved density, [`MotionBlur::majorant_radius`]).
#[derive(Clone, Copy)]
pub struct DensityMedium<'a> {
    pub density: &'a Volume<f32>,
    pub majorant: &'a MajorantGrid,
    pub extinction: f32,
    pub motion: Option<Motion<'a>>,
}

impl DensityMedium<'_> {
    /// The density at world position `x` (at the motion's time, where it has one).
    #[inline]
    pub fn density_at(&self, x: DVec3) -> f32 {
        match self.motion {
            Some(m) => self.density.sample_world(m.back(x)),
            None => self.density.sample_world(x),
        }
    }
}

/// Eulerian motion blur (issue #20), as Cycles and Arnold blur volumes: at `time` seconds
/// from the frame, what is at x was at `x - time v(x)` in the frame, v the velocity grid
/// (world units per second) looked up at x. Every lookup of the medium (density, the cache's
/// Li, emission) is made at that point.
#[derive(Clone, Copy)]
pub struct Motion<'a> {
    pub velocity: &'a Volume<glam::Vec3>,
    pub time: f64,
}

impl Motion<'_> {
    /// Where the medium at `x` at this time was in the frame.
    #[inline]
    pub fn back(&self, x: DVec3) -> DVec3 {
        x - self.velocity.sample_world(x).as_dvec3() * self.time
    }
}

/// A shutter over a velocity grid: each camera sample takes a time in it.
#[derive(Clone, Copy)]
pub struct MotionBlur<'a> {
    pub velocity: &'a Volume<glam::Vec3>,
    /// Seconds the shutter is open, centred on the frame (Blender's Shutter, in frames,
    /// over the frame rate; Blender's default position is the centre).
    pub shutter: f64,
}

impl<'a> MotionBlur<'a> {
    /// The motion at shutter fraction `u` in [0, 1): time `(u - 1/2) shutter`.
    pub fn at(&self, u: f64) -> Motion<'a> {
        Motion { velocity: self.velocity, time: (u - 0.5) * self.shutter }
    }

    /// The fastest speed in the velocity grid (its active values and background).
    pub fn max_speed(&self) -> f64 {
        let active = self.velocity.bricks().flat_map(|b| b.values.iter()).map(|v| v.length() as f64).fold(0.0, f64::max);
        active.max(self.velocity.background().length() as f64)
    }

    /// How far (index units of `density`, per axis) the medium can move within the shutter:
    /// the radius to dilate a majorant grid by so that it bounds the density at every time.
    pub fn majorant_radius(&self, density: &Volume<f32>) -> DVec3 {
        let reach = self.max_speed() * 0.5 * self.shutter.abs();
        reach / density.transform().voxel_size()
    }
}

/// Emission over the volume (issue #19; [`nimbus_optics::Emission`]): the emission and
/// temperature grids, looked up trilinearly in their own index spaces, and what they mean.
/// The medium carries it: only where the density is positive does anything emit (the march
/// and the reference both count it there alone, so they agree).
#[derive(Clone, Copy)]
pub struct EmissionField<'a> {
    pub grid: Option<&'a Volume<f32>>,
    pub temperature: Option<&'a Volume<f32>>,
    pub params: &'a nimbus_optics::Emission,
}

impl EmissionField<'_> {
    /// The emitted radiance per unit length at world position `x`.
    pub fn at(&self, x: DVec3) -> glam::Vec3 {
        let g = if self.params.has_grid_term() { self.grid.map_or(0.0, |v| v.sample_world(x)) } else { 0.0 };
        let t = if self.params.has_blackbody_term() { self.temperature.map_or(0.0, |v| v.sample_world(x)) } else { 0.0 };
        self.params.emitted(g, t)
    }
}

/// Where along a ray a free path ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FreePath {
    /// An interaction at distance `t`.
    Interaction(f64),
    /// The ray left the medium (or reached `t_max`) without interacting.
    Escaped,
}

/// A ray `origin + t * dir` (world space, |dir| = 1) through a [`DensityMedium`], over
/// `t_min..t_max`.
pub struct MediumRay<'a> {
    medium: DensityMedium<'a>,
    origin_index: DVec3,
    dir_index: DVec3,
    t_min: f64,
    t_max: f64,
}

impl<'a> MediumRay<'a> {
    pub fn new(medium: DensityMedium<'a>, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64) -> Self {
        let transform = medium.density.transform();
        MediumRay {
            medium,
            origin_index: transform.to_index(origin),
            dir_index: transform.dir_to_index(dir),
            t_min,
            t_max,
        }
    }

    /// sigma_t at distance `t`; density below zero (ringing in third-party grids) counts as
    /// empty, so optical depth never decreases.
    #[inline]
    pub fn sigma_t(&self, t: f64) -> f32 {
        let p = self.origin_index + self.dir_index * t;
        let d = match self.medium.motion {
            Some(m) => self.medium.density.sample_world(m.back(self.medium.density.transform().to_world(p))),
            None => self.medium.density.sample_index(p),
        };
        self.medium.extinction * d.max(0.0)
    }

    /// Segments of the ray with a non-zero majorant of sigma_t, in order. Beyond the majorant
    /// grid a volume holds only its background; a non-zero background there would make an
    /// infinite medium, so the unbounded stretch past the grid counts as empty (the GPU
    /// kernels do the same).
    fn segments(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        let ext = self.medium.extinction as f64;
        self.medium
            .majorant
            .walk(self.origin_index, self.dir_index, self.t_min, self.t_max)
            .filter(move |s| s.majorant > 0.0 && ext > 0.0 && s.t_end.is_finite())
            .map(move |s| (s.t_start, s.t_end, s.majorant as f64 * ext))
    }

    /// Calls `f` on the composite Simpson panels over the non-empty segments, in order, until
    /// it returns false. Panels are at most `step` long and never straddle a voxel boundary:
    /// within one voxel cell the trilinear density along a ray is a cubic in t, which Simpson's
    /// rule integrates exactly, so the optical depth is that of the interpolated density up to
    /// rounding, whatever the step.
    fn simpson_panels(&self, step: f64, mut f: impl FnMut(&SimpsonPanel) -> bool) {
        let (o, d) = (self.origin_index, self.dir_index);
        for (a, b, _) in self.segments() {
            // The next lattice-plane crossing on each axis, as in a voxel DDA.
            let mut next = DVec3::INFINITY;
            let mut inc = DVec3::INFINITY;
            for axis in 0..3 {
                if d[axis] != 0.0 {
                    let c = o[axis] + a * d[axis];
                    let plane = if d[axis] > 0.0 { c.floor() + 1.0 } else { c.ceil() - 1.0 };
                    next[axis] = (plane - o[axis]) / d[axis];
                    inc[axis] = 1.0 / d[axis].abs();
                }
            }
            let mut t = a;
            let mut left = self.sigma_t(t) as f64;
            while t < b {
                let cross = next.min_element().min(b);
                if cross > t {
                    let n = ((cross - t) / step).ceil().max(1.0);
                    let h = (cross - t) / n;
                    for i in 0..n as usize {
                        let t0 = t + i as f64 * h;
                        let t1 = if i + 1 == n as usize { cross } else { t0 + h };
                        let hh = t1 - t0;
                        let mid = self.sigma_t(t0 + 0.5 * hh) as f64;
                        let right = self.sigma_t(t1) as f64;
                        let panel = SimpsonPanel { t: t0, h: hh, left, mid, right, integral: hh / 6.0 * (left + 4.0 * mid + right) };
                        if !f(&panel) {
                            return;
                        }
                        left = right;
                    }
                    t = cross;
                }
                for axis in 0..3 {
                    while next[axis] <= t {
                        next[axis] += inc[axis];
                    }
                }
            }
        }
    }

    /// Optical depth over the ray's interval by composite Simpson with steps of at most
    /// `step` (world length) within each non-empty segment.
    pub fn optical_depth(&self, step: f64) -> f64 {
        let mut tau = 0.0;
        self.simpson_panels(step, |p| {
            tau += p.integral;
            true
        });
        tau
    }

    /// Transmittance exp(-optical depth), stopping early once it falls below `cutoff`
    /// (returns 0 then): shadow rays into dense cores need not be integrated to the end.
    pub fn transmittance(&self, step: f64, cutoff: f64) -> f64 {
        let tau_cut = -cutoff.max(1e-300).ln();
        let mut tau = 0.0;
        self.simpson_panels(step, |p| {
            tau += p.integral;
            tau <= tau_cut
        });
        if tau > tau_cut {
            0.0
        } else {
            (-tau).exp()
        }
    }

    /// The paper's Eq. 2: the distance d with integral_0^d sigma_t = `tau_target`
    /// (= -ln(1 - xi)), the integral by composite Simpson with steps of at most `step`.
    /// Within the panel where the target is crossed, sigma_t is taken as the quadratic through
    /// its three Simpson samples, whose integral is solved for the remainder by safeguarded
    /// Newton iteration, so the sampled point is as accurate as the integral.
    pub fn sample_simpson(&self, tau_target: f64, step: f64) -> FreePath {
        let mut tau = 0.0;
        let mut hit = FreePath::Escaped;
        self.simpson_panels(step, |p| {
            if tau + p.integral >= tau_target && p.integral > 0.0 {
                hit = FreePath::Interaction(p.t + solve_quadratic_step(p.left, p.mid, p.right, p.h, tau_target - tau));
                return false;
            }
            tau += p.integral;
            true
        });
        hit
    }

    /// The paper's Eq. 1: d = -ln(1 - xi) / sigma_t(x0), with sigma_t frozen at the first
    /// point of the ray's lattice t = k * `step` where the medium is not empty. Biased where
    /// density varies; kept to compare against. The lattice is the ray's, not the majorant
    /// cells': starting at each non-empty segment would put the first sample on the plane
    /// where the support begins (cells end on voxel planes), freeze sigma_t at the rounding
    /// noise there and send the photon out of the medium.
    pub fn sample_exponential(&self, tau_target: f64, step: f64) -> FreePath {
        let mut segments = self.segments();
        let mut hit = None;
        for (a, b, _) in segments.by_ref() {
            let mut t = (a / step).ceil() * step;
            while t < b && hit.is_none() {
                let s = self.sigma_t(t) as f64;
                if s > 0.0 {
                    hit = Some((t + tau_target / s, b));
                }
                t += step;
            }
            if hit.is_some() {
                break;
            }
        }
        let Some((d, mut medium_end)) = hit else { return FreePath::Escaped };
        // Eq. 1 can send a photon past everything: beyond the last non-empty segment it has
        // left the medium, and interacting there would store photons in empty space.
        for (_, b, _) in segments {
            medium_end = b;
        }
        if d < medium_end.min(self.t_max) {
            FreePath::Interaction(d)
        } else {
            FreePath::Escaped
        }
    }

    /// Delta (Woodcock) tracking: tentative collisions against each segment's majorant,
    /// accepted with probability sigma_t / majorant. Unbiased; needs no step size.
    ///
    /// One exponential draw of majorant optical depth per tentative collision, carried across
    /// segment boundaries (what is left of it when a segment ends is spent in the next): the
    /// collisions fall as with a fresh draw per segment (the exponential is memoryless), but a
    /// flight crossing many thin cells costs one draw, not one per cell. Measured on the
    /// Cloud1-class scene (vdbcache's paths): 20.4 non-empty majorant segments a path against
    /// 3.5 tentative collisions (2.4 real), so a draw (a Philox block's half and a logarithm)
    /// per segment had been most of a path's draws.
    pub fn sample_delta(&self, rng: &mut Rng) -> FreePath {
        let mut tau = -(1.0 - rng.next_f64()).ln();
        for (a, b, majorant) in self.segments() {
            let mut t = a;
            loop {
                let dt = tau / majorant;
                if t + dt >= b {
                    tau -= (b - t) * majorant;
                    break;
                }
                t += dt;
                if (rng.next_f32() as f64) * majorant < self.sigma_t(t) as f64 {
                    return FreePath::Interaction(t);
                }
                tau = -(1.0 - rng.next_f64()).ln();
            }
        }
        FreePath::Escaped
    }

    /// Ratio tracking: an unbiased estimate of transmittance over the interval, the product
    /// of (1 - sigma_t / majorant) at tentative collisions. Stops with 0 by Russian roulette
    /// once the estimate is below `roulette_below`, keeping it unbiased.
    /// One exponential draw per tentative collision, carried across segment boundaries as in
    /// [`MediumRay::sample_delta`].
    pub fn transmittance_ratio(&self, rng: &mut Rng, roulette_below: f64) -> f64 {
        let mut tr = 1.0;
        let mut tau = -(1.0 - rng.next_f64()).ln();
        for (a, b, majorant) in self.segments() {
            let mut t = a;
            loop {
                let dt = tau / majorant;
                if t + dt >= b {
                    tau -= (b - t) * majorant;
                    break;
                }
                t += dt;
                tr *= 1.0 - self.sigma_t(t) as f64 / majorant;
                if tr < roulette_below {
                    if rng.next_f64() >= 0.5 {
                        return 0.0;
                    }
                    tr *= 2.0;
                }
                tau = -(1.0 - rng.next_f64()).ln();
            }
        }
        tr
    }
}

/// One composite Simpson panel: sigma_t at `t`, `t + h/2`, `t + h` and its integral.
struct SimpsonPanel {
    t: f64,
    h: f64,
    left: f64,
    mid: f64,
    right: f64,
    integral: f64,
}

/// Solves integral_0^s q(u) du = `remaining` for s in [0, h], where q is the quadratic through
/// (0, l), (h/2, m), (h, r). Falls back to bisection where Newton would leave the bracket.
fn solve_quadratic_step(l: f64, m: f64, r: f64, h: f64, remaining: f64) -> f64 {
    // q(u) = l + b u + c u^2 with q(h/2) = m, q(h) = r.
    let c = 2.0 * (l - 2.0 * m + r) / (h * h);
    let b = (r - l) / h - c * h;
    let integral = |s: f64| s * (l + s * (b / 2.0 + s * c / 3.0));
    let q = |s: f64| (l + s * (b + s * c)).max(0.0);
    let (mut lo, mut hi) = (0.0, h);
    // Start where a linear cumulative would put it.
    let total = integral(h);
    let mut s = if total > 0.0 { (remaining / total * h).clamp(0.0, h) } else { 0.5 * h };
    for _ in 0..50 {
        let f = integral(s) - remaining;
        if f.abs() <= 1e-12 * remaining.max(1e-300) {
            break;
        }
        if f > 0.0 {
            hi = s;
        } else {
            lo = s;
        }
        let slope = q(s);
        let newton = s - f / slope;
        s = if slope > 0.0 && newton > lo && newton < hi { newton } else { 0.5 * (lo + hi) };
        if hi - lo <= 1e-15 * h {
            break;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_step_inverts_its_integral() {
        for &(l, m, r) in &[(1.0, 1.0, 1.0), (0.0, 2.0, 0.0), (0.0, 0.5, 1.0), (3.0, 0.1, 0.0)] {
            let h = 0.7;
            let c = 2.0 * (l - 2.0 * m + r) / (h * h);
            let b = (r - l) / h - c * h;
            let integral = |s: f64| s * (l + s * (b / 2.0 + s * c / 3.0));
            for k in 1..10 {
                let target = integral(h) * k as f64 / 10.0;
                let s = solve_quadratic_step(l, m, r, h, target);
                assert!((integral(s) - target).abs() < 1e-9, "{l},{m},{r}: {s}");
            }
        }
    }
}
