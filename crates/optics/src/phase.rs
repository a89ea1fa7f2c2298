//! The Henyey-Greenstein phase function (design.md section 3).
//!
//! Convention: `cos_theta = dot(w_in, w_out)` with `w_in` the direction light travels
//! *before* scattering and `w_out` the direction after, so g > 0 keeps light going the way
//! it went (forward scattering). pbrt-v4 uses the opposite convention (both vectors point away
//! from the scattering point, `1 + g^2 + 2 g cos`); the formulas below are pbrt-v4's with
//! that sign folded in.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::sampling::orthonormal_basis;

/// |g| is clamped to this inside [`HenyeyGreenstein`]'s methods (and their WGSL twins).
/// At 0.9999 the lobe's peak is 1.6e7 sr^-1 and still finite in f32; a validated
/// [`crate::Medium`] has |g| < 1 anyway, so the clamp only guards hand-built values.
pub const HG_G_MAX: f32 = 0.9999;

// The f32 nearest 1 / (4 pi), written out so the WGSL twin uses the same constant.
#[allow(clippy::excessive_precision)]
const INV_4PI: f32 = 0.079_577_471_545_947_67;

/// Henyey-Greenstein: `p(cos t) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos t)^1.5)`, normalised
/// over the sphere, with mean cosine `g`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HenyeyGreenstein {
    pub g: f32,
}

impl HenyeyGreenstein {
    pub fn new(g: f32) -> Self {
        HenyeyGreenstein { g }
    }

    #[inline]
    fn g_clamped(&self) -> f32 {
        self.g.clamp(-HG_G_MAX, HG_G_MAX)
    }

    /// Phase function value (sr^-1) for `cos_theta = dot(w_in, w_out)`.
    ///
    /// The textbook denominator `1 + g^2 - 2 g cos` cancels catastrophically near the peak
    /// when |g| -> 1 (at g = 0.999, cos = 1 it is 1e-6 built from terms of size 2, so f32
    /// keeps about one digit). Written as a sum of non-negative terms,
    /// `(1 - g)^2 + 2 g (1 - cos)` for g >= 0 and `(1 + g)^2 - 2 g (1 + cos)` for g < 0,
    /// it keeps full relative precision; likewise `1 - g^2 = (1 - g)(1 + g)`.
    #[inline]
    pub fn eval(&self, cos_theta: f32) -> f32 {
        let c = cos_theta.clamp(-1.0, 1.0);
        self.eval_sided(1.0 - c, 1.0 + c)
    }

    /// [`HenyeyGreenstein::eval`] from `1 - cos` and `1 + cos` given separately, for callers
    /// (the sampler) that know them more precisely than cos itself.
    #[inline]
    fn eval_sided(&self, one_minus_cos: f32, one_plus_cos: f32) -> f32 {
        let g = self.g_clamped();
        let denom = if g >= 0.0 {
            (1.0 - g) * (1.0 - g) + 2.0 * g * one_minus_cos
        } else {
            (1.0 + g) * (1.0 + g) - 2.0 * g * one_plus_cos
        };
        INV_4PI * (1.0 - g) * (1.0 + g) / (denom * denom.sqrt())
    }

    /// Phase function value for a pair of directions (both unit length).
    #[inline]
    pub fn eval_dirs(&self, w_in: Vec3, w_out: Vec3) -> f32 {
        self.eval(w_in.dot(w_out))
    }

    /// Density of [`HenyeyGreenstein::sample`] with respect to solid angle: the phase function
    /// itself, since the sampling is exact.
    #[inline]
    pub fn pdf(&self, w_in: Vec3, w_out: Vec3) -> f32 {
        self.eval_dirs(w_in, w_out)
    }

    /// Samples the scattering angle: returns `(cos_theta, sin_theta)` with cos_theta
    /// distributed exactly as the HG density of `dot(w_in, w_out)`. `xi` in [0,1).
    ///
    /// This is the inversion pbrt-v4 uses,
    /// `cos = (1 + g^2 - ((1 - g^2) / (1 + g - 2 g xi))^2) / (2 g)`, rearranged so that no
    /// step cancels: with `d = 1 + g - 2 g xi` (summed from non-negative terms),
    ///
    /// ```text
    /// 1 - cos = (1 - g)^2 xi       (1 + g + d) / d^2
    /// 1 + cos = (1 + g)^2 (1 - xi) (1 - g + d) / d^2
    /// ```
    ///
    /// Both are products of non-negative factors, so each has full relative precision; cos
    /// is taken from the smaller one and `sin^2 = (1 - cos)(1 + cos)` from both. That keeps
    /// the tiny angles of a g = 0.999 lobe (1 - cos ~ 1e-7, below f32's resolution near 1)
    /// resolved in sin_theta, needs no special case at g = 0 (where it reduces to
    /// `cos = 1 - 2 xi`), and never divides by zero for |g| < 1. pbrt-v4 instead clamps
    /// |g| to 0.99 and switches to the isotropic formula below |g| = 1e-3.
    #[inline]
    pub fn sample_cos_theta(&self, xi: f32) -> (f32, f32) {
        let (cos_theta, sin_theta, _, _) = self.sample_angle(xi);
        (cos_theta, sin_theta)
    }

    /// `(cos, sin, 1 - cos, 1 + cos)` of a sampled scattering angle.
    #[inline]
    fn sample_angle(&self, xi: f32) -> (f32, f32, f32, f32) {
        let g = self.g_clamped();
        let d = if g >= 0.0 { (1.0 - g) + 2.0 * g * (1.0 - xi) } else { (1.0 + g) - 2.0 * g * xi };
        let inv_d2 = 1.0 / (d * d);
        let one_minus_cos = (1.0 - g) * (1.0 - g) * xi * (1.0 + g + d) * inv_d2;
        let one_plus_cos = (1.0 + g) * (1.0 + g) * (1.0 - xi) * (1.0 - g + d) * inv_d2;
        let cos_theta = if one_minus_cos < one_plus_cos { 1.0 - one_minus_cos } else { one_plus_cos - 1.0 };
        let sin_theta = (one_minus_cos * one_plus_cos).max(0.0).sqrt().min(1.0);
        (cos_theta.clamp(-1.0, 1.0), sin_theta, one_minus_cos, one_plus_cos)
    }

    /// Samples the direction after scattering, `w_out`, for light travelling along `w_in`
    /// (unit length), with density [`HenyeyGreenstein::eval`]`(dot(w_in, w_out))`.
    /// `u.x` picks the angle to `w_in`, `u.y` the azimuth around it; both in [0,1).
    #[inline]
    pub fn sample(&self, w_in: Vec3, u: Vec2) -> Vec3 {
        self.sample_with_pdf(w_in, u).0
    }

    /// [`HenyeyGreenstein::sample`] and its pdf, evaluated from the sampled angle's `1 - cos`
    /// rather than from `dot(w_in, w_out)`, which would round the lobe's small angles away.
    #[inline]
    pub fn sample_with_pdf(&self, w_in: Vec3, u: Vec2) -> (Vec3, f32) {
        let (cos_theta, sin_theta, one_minus_cos, one_plus_cos) = self.sample_angle(u.x);
        let phi = 2.0 * PI * u.y;
        let (t, b) = orthonormal_basis(w_in);
        let w_out = sin_theta * (phi.cos() * t + phi.sin() * b) + cos_theta * w_in;
        (w_out, self.eval_sided(one_minus_cos, one_plus_cos))
    }
}

/// At most this many lights get a lobe in [`LightLobes`] (the first ones with light at the
/// collision; the rest are still reached by the path's own phase-sampled flights, so the
/// estimate stays unbiased). The WGSL twin (path.wgsl) keeps the same bound.
pub const GUIDED_LIGHTS: usize = 4;

/// The phase function's lobes about the directions *toward* the lights at a collision: a
/// second way to reach the delta lights' next-event estimate at the next collision.
///
/// Why: suns and points enter a path only by next-event estimation, and the estimate at the
/// next collision, `p(w_light, -w)`, is for a strongly forward-scattering medium (g near 1) a
/// narrow peak around `w` = toward the light. Phase sampling about the path's direction
/// rarely lands in it when the light comes from behind the eye (the light must turn round),
/// and the paths that do carry weights in the hundreds: fireflies in the reference tracer,
/// blotches in Li_multiple. The lobe about the light has exactly that peak's shape.
///
/// The lobes are not used to continue the path (a mixture's weights `phase / pdf`, near 2 on
/// every direction the lobes miss, would compound along a long path: measured, a g 0.9
/// medium's reference at depth 512 went from 96% to 137% noise). A collision instead sends
/// one probe flight along a direction drawn from the lobes, and the two strategies' next
/// estimates are combined by the balance heuristic ([`LightLobes::phase_weight`]).
#[derive(Debug, Clone, Copy)]
pub struct LightLobes {
    phase: HenyeyGreenstein,
    toward: [Vec3; GUIDED_LIGHTS],
    /// Each lobe's share of the probes, unnormalised (a light's luminance at the collision).
    share: [f32; GUIDED_LIGHTS],
    count: usize,
}

impl LightLobes {
    pub fn new(phase: HenyeyGreenstein) -> Self {
        LightLobes { phase, toward: [Vec3::ZERO; GUIDED_LIGHTS], share: [0.0; GUIDED_LIGHTS], count: 0 }
    }

    /// A lobe about `toward` (unit, from the collision to the light), drawn in proportion to
    /// `strength` (the light's luminance there before shadowing). Ignored past
    /// [`GUIDED_LIGHTS`] lobes or for a strength that is not positive.
    pub fn add(&mut self, toward: Vec3, strength: f32) {
        if self.count < GUIDED_LIGHTS && strength > 0.0 && strength.is_finite() {
            self.toward[self.count] = toward;
            self.share[self.count] = strength;
            self.count += 1;
        }
    }

    /// How many lobes it has.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The lobes' density for `w` (solid angle; 0 without lobes).
    pub fn pdf(&self, w: Vec3) -> f32 {
        let total: f32 = self.share[..self.count].iter().sum();
        (0..self.count).map(|i| self.share[i] / total * self.phase.pdf(self.toward[i], w)).sum()
    }

    /// A direction from the lobes: `pick` in [0,1) chooses the lobe, `u` the direction in it.
    /// Call only with lobes.
    pub fn sample(&self, pick: f32, u: Vec2) -> Vec3 {
        let total: f32 = self.share[..self.count].iter().sum();
        let mut rest = pick * total;
        let mut axis = self.toward[self.count - 1];
        for i in 0..self.count {
            rest -= self.share[i];
            if rest < 0.0 {
                axis = self.toward[i];
                break;
            }
        }
        self.phase.sample(axis, u).normalize()
    }

    /// The balance heuristic's weight of the phase-sampled flight along `w` leaving a
    /// collision whose path travelled along `w_in`, against one probe from these lobes; the
    /// probe's weight is one less this.
    pub fn phase_weight(&self, w_in: Vec3, w: Vec3) -> f32 {
        let phase = self.phase.pdf(w_in, w);
        let lobes = self.pdf(w);
        if phase + lobes > 0.0 { phase / (phase + lobes) } else { 0.0 }
    }
}

#[cfg(test)]
mod light_lobe_tests {
    use super::*;
    use crate::{sample_uniform_sphere, Rng};

    fn lobes() -> LightLobes {
        let mut lobes = LightLobes::new(HenyeyGreenstein::new(0.8));
        lobes.add(Vec3::new(0.0, 0.6, 0.8), 3.0);
        lobes.add(Vec3::new(1.0, 0.0, 0.0), 1.0);
        lobes.add(Vec3::Z, 0.0); // no light there: no lobe
        lobes
    }

    #[test]
    fn the_lobes_density_is_normalised_and_their_draws_follow_it() {
        let lobes = lobes();
        assert_eq!(lobes.count(), 2);
        let n = 400_000;
        let mut rng = Rng::new(3, 0);
        // Over the sphere the density integrates to one ...
        let integral: f64 = (0..n).map(|_| lobes.pdf(sample_uniform_sphere(rng.next_vec2())) as f64 * 4.0 * std::f64::consts::PI).sum::<f64>() / n as f64;
        assert!((integral - 1.0).abs() < 0.02, "{integral}");
        // ... and the draws have that density: E[f / pdf] over them is the integral of f,
        // here the phase function about another axis (1).
        let phase = HenyeyGreenstein::new(0.8);
        let w_in = Vec3::new(0.0, -1.0, 0.0);
        let mean: f64 = (0..n)
            .map(|_| {
                let w = lobes.sample(rng.next_f32(), rng.next_vec2());
                (phase.pdf(w_in, w) / lobes.pdf(w)) as f64
            })
            .sum::<f64>()
            / n as f64;
        assert!((mean - 1.0).abs() < 0.03, "{mean}");
        // The share of draws in a cap about each light is the density's mass there (the
        // brighter light's lobe takes three quarters of the draws).
        for axis in [Vec3::new(0.0, 0.6, 0.8), Vec3::X] {
            let drawn = (0..n).filter(|_| lobes.sample(rng.next_f32(), rng.next_vec2()).dot(axis) > 0.9).count() as f64 / n as f64;
            let mass: f64 = (0..n)
                .map(|_| {
                    let w = sample_uniform_sphere(rng.next_vec2());
                    if w.dot(axis) > 0.9 { lobes.pdf(w) as f64 * 4.0 * std::f64::consts::PI } else { 0.0 }
                })
                .sum::<f64>()
                / n as f64;
            assert!((drawn - mass).abs() < 0.02, "{axis}: {drawn} drawn, {mass} by the density");
        }
    }

    #[test]
    fn the_balance_weights_of_a_flight_and_a_probe_sum_to_one() {
        let lobes = lobes();
        let w_in = Vec3::new(0.0, 0.0, -1.0);
        for w in [Vec3::X, Vec3::Y, Vec3::new(0.0, 0.6, 0.8), -Vec3::Z] {
            let phase = HenyeyGreenstein::new(0.8).pdf(w_in, w);
            let weight = lobes.phase_weight(w_in, w);
            assert!((weight * (phase + lobes.pdf(w)) - phase).abs() < 1e-5 * phase.max(1e-3), "{w}");
            assert!((0.0..=1.0).contains(&weight));
        }
        // Without lobes the phase function's flight takes the whole weight.
        assert_eq!(LightLobes::new(HenyeyGreenstein::new(0.8)).phase_weight(w_in, Vec3::X), 1.0);
    }
}
