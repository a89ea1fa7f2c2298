//! The per-grid-point mathematics of design.md section 8, as small pure f32 functions.
//!
//! Everything here is what a WGSL compute shader computes per grid point, written so the
//! shader can mirror it line by line: no allocation, no branching on anything but the
//! arguments, f32 throughout (the CPU backend calls these exact functions).

use std::f32::consts::PI;

/// Support radius of the kernel in units of h: W(r, h) = 0 for r >= KAPPA * h.
pub const KAPPA: f32 = 2.0;

/// The M4 cubic spline without its normalisation, as a function of q = r/h:
/// `1 - 1.5 q^2 + 0.75 q^3` for q < 1, `0.25 (2 - q)^3` for 1 <= q < 2, 0 beyond.
///
/// Evaluated in its B-spline form `0.25 max(2-q, 0)^3 - max(1-q, 0)^3`, which equals the
/// piecewise form and has no branch: the CPU loops over a z column vectorise (a select here
/// would be lowered to branches and block that), and a shader mirrors it with `max`.
#[inline(always)]
pub fn m4_shape(q: f32) -> f32 {
    let a = (2.0 - q).max(0.0);
    let b = (1.0 - q).max(0.0);
    0.25 * a * a * a - b * b * b
}

/// The normalised M4 kernel W(r, h) = m4_shape(r/h) / (pi h^3); its integral over space is 1.
#[inline]
pub fn m4(r: f32, h: f32) -> f32 {
    m4_shape(r / h) / (PI * h * h * h)
}

/// Step 1 (predict): the smoothing length that would hold `n_star` particles if the `n0`
/// found within KAPPA*h0 were spread uniformly; never above h0, and h0 where n0 = 0.
#[inline]
pub fn predict_h1(n0: u32, n_star: f32, h0: f32) -> f32 {
    if n0 == 0 {
        return h0;
    }
    (h0 * (n_star / n0 as f32).cbrt()).min(h0)
}

/// Step 2 (correct, asl3): from the counts n0 within KAPPA*h0 and n1 within KAPPA*h1.
/// Too few (n1 < N*): interpolate the count linearly in sphere volume between h1 and h0
/// (h0 when n0 = n1, where the shell between them is empty). Too many (n1 > N*): shrink by
/// the cube root of the excess, times the relaxation alpha = 1 - s n1/n0.
#[inline]
pub fn correct_h(n0: u32, n1: u32, n_star: f32, h0: f32, h1: f32, relax: f32) -> f32 {
    let (n0f, n1f) = (n0 as f32, n1 as f32);
    if n1f < n_star {
        if n0 == n1 {
            return h0;
        }
        let (h0c, h1c) = (h0 * h0 * h0, h1 * h1 * h1);
        ((n_star - n1f) * (h0c - h1c) / (n0f - n1f) + h1c).cbrt()
    } else if n1f > n_star {
        let alpha = 1.0 - relax * n1f / n0f;
        alpha * h1 * (n_star / n1f).cbrt()
    } else {
        h1
    }
}

/// The final clamp to [h_min, h0]; h0 wins when h_min > h0 (the user's upper bound is a
/// hard limit, h_min only a floor against kernels narrower than the grid).
#[inline]
pub fn clamp_h(h: f32, h_min: f32, h0: f32) -> f32 {
    h.max(h_min).min(h0)
}

/// ici: the most rungs of the ladder of smoothing lengths ([`ici_ladder`]); eight fit the
/// GPU's uniforms (two vec4s of lengths); its ladder pass writes this many sums and as many
/// sums of squares per voxel.
pub const ICI_MAX_RUNGS: usize = 8;

/// ici: the largest ratio between neighbouring rungs. The rule interpolates between rungs
/// (crate docs), so the ladder only has to resolve where the error turns; each rung costs a
/// kernel evaluation per (particle, voxel) pair within its support and two box means. 1.4
/// measured no better (knots, shell, plume, Cloud1-class 0.1076, 0.2134, 0.0716, 0.1382
/// against 0.1078, 0.2115, 0.0720, 0.1378) at one more rung.
pub const ICI_RUNG_RATIO: f32 = 1.5;

/// ici: the ladder of smoothing lengths, h_min to h0 geometrically (h0 exactly the top), the
/// fewest rungs whose ratio is at most [`ICI_RUNG_RATIO`], at most [`ICI_MAX_RUNGS`]; one
/// rung (h0) when h_min >= h0. Returns the lengths and how many are used.
#[inline]
pub fn ici_ladder(h_min: f32, h0: f32) -> ([f32; ICI_MAX_RUNGS], usize) {
    let mut h = [h0; ICI_MAX_RUNGS];
    if h_min >= h0 {
        return (h, 1);
    }
    let span = (h0 / h_min).ln();
    let rungs = ((span / ICI_RUNG_RATIO.ln()).ceil() as usize + 1).clamp(2, ICI_MAX_RUNGS);
    for (k, hk) in h.iter_mut().enumerate().take(rungs - 1) {
        *hk = h_min * (span * k as f32 / (rungs - 1) as f32).exp();
    }
    (h, rungs)
}

/// Per rung of `h`: 1 / h_k^3 (a kernel sum's scale) and (h_k / h_top)^3 (the ball's volume
/// relative to the top rung's, which scales the variance floor: [`crate::ici`]).
#[inline]
pub fn ici_scales(h: &[f32]) -> ([f32; ICI_MAX_RUNGS], [f32; ICI_MAX_RUNGS]) {
    let top = h.len() - 1;
    let mut scale = [0.0f32; ICI_MAX_RUNGS];
    let mut volume = [0.0f32; ICI_MAX_RUNGS];
    for k in 0..h.len() {
        scale[k] = 1.0 / (h[k] * h[k] * h[k]);
        let ratio = h[k] / h[top];
        volume[k] = ratio * ratio * ratio;
    }
    (scale, volume)
}

/// ici: the variance of the difference of two kernel estimates over the same particles, at
/// lengths h and `ratio` h (ratio > 1), as a fraction of the shorter one's variance:
/// int (W_h - W_ratio*h)^2 dV / int W_h^2 dV, for any locally uniform medium and any masses.
/// Nested balls would give 1 - ratio^-3; smooth kernels share more (0.38 of that at 1.35,
/// 0.90 at 3), so that form overstated the noise of a difference. Midpoint rule in r, f64.
pub fn ici_pair_noise(ratio: f32) -> f32 {
    let k = ratio as f64;
    let w = |r: f64, h: f64| m4_shape((r / h) as f32) as f64 / (h * h * h);
    let steps = 4000;
    let dr = 2.0 * k / steps as f64;
    let (mut diff, mut own) = (0.0, 0.0);
    for i in 0..steps {
        let r = (i as f64 + 0.5) * dr;
        let (a, b) = (w(r, 1.0), w(r, k));
        diff += (a - b) * (a - b) * r * r;
        own += a * a * r * r;
    }
    (diff / own) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_matches_the_piecewise_form() {
        for i in 0..=300 {
            let q = i as f32 * 0.01;
            let piecewise = if q < 1.0 {
                1.0 - 1.5 * q * q + 0.75 * q * q * q
            } else if q < 2.0 {
                0.25 * (2.0 - q).powi(3)
            } else {
                0.0
            };
            assert!((m4_shape(q) - piecewise).abs() < 1e-6, "q {q}");
        }
    }

    #[test]
    fn kernel_is_continuous_at_the_joints() {
        assert!((m4_shape(1.0 - 1e-6) - m4_shape(1.0)).abs() < 1e-5);
        assert!(m4_shape(2.0 - 1e-4).abs() < 1e-10);
        assert_eq!(m4_shape(0.0), 1.0);
    }

    #[test]
    fn corrector_cases() {
        // n1 = N*: keep h1.
        assert_eq!(correct_h(100, 32, 32.0, 2.0, 1.0, 0.0), 1.0);
        // n0 = n1 < N*: the shell is empty, fall back to h0.
        assert_eq!(correct_h(10, 10, 32.0, 2.0, 2.0, 0.0), 2.0);
        // n1 > N*, s = 0: shrink by the cube root.
        assert!((correct_h(100, 64, 32.0, 2.0, 1.0, 0.0) - 0.5f32.cbrt()).abs() < 1e-6);
        // n1 < N*: between h1 and h0.
        let h = correct_h(100, 16, 32.0, 2.0, 1.0, 0.0);
        assert!(h > 1.0 && h < 2.0);
    }

    #[test]
    fn ici_ladder_spans_h_min_to_h0() {
        let (h, n) = ici_ladder(1.2, 3.4);
        assert_eq!(n, 4);
        assert!((h[0] - 1.2).abs() < 1e-6 && h[n - 1] == 3.4);
        for k in 1..n {
            assert!(h[k] / h[k - 1] <= ICI_RUNG_RATIO + 1e-5 && h[k] > h[k - 1]);
        }
        assert_eq!(ici_ladder(2.0, 2.0).1, 1);
        assert_eq!(ici_ladder(1.0, 100.0).1, ICI_MAX_RUNGS);
    }

    #[test]
    fn a_difference_of_estimates_is_quieter_than_nested_balls_say() {
        // Far apart rungs share little: the difference's variance tends to the shorter's.
        assert!((ici_pair_noise(50.0) - 1.0).abs() < 0.01);
        // Close rungs share most of their particles and weights.
        let close = ici_pair_noise(1.35);
        assert!(close > 0.0 && close < 0.4 * (1.0 - 1.35f32.powi(-3)), "{close}");
        assert!(ici_pair_noise(1.2) < ici_pair_noise(1.5));
    }
}
