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
