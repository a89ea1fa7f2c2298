//! Henyey-Greenstein: sampling matches the density, the density is normalised, and both stay
//! accurate as |g| -> 1.

mod common;

use common::{chi_square, chi_square_limit};
use glam::{DVec3, Vec2, Vec3};
use nimbus_optics::{HenyeyGreenstein, Rng, HG_G_MAX};

/// P(cos <= mu) for HG, in f64 from the textbook formula, written in x = 1 - mu so that
/// it stays accurate at the forward peak: 1 + g^2 - 2 g mu = (1 - g)^2 + 2 g x.
fn hg_cdf(g: f64, one_minus_mu: f64) -> f64 {
    if g == 0.0 {
        return 1.0 - 0.5 * one_minus_mu;
    }
    let s = (1.0 - g) * (1.0 - g) + 2.0 * g * one_minus_mu;
    ((1.0 - g * g) / (2.0 * g) * (1.0 / s.sqrt() - 1.0 / (1.0 + g))).clamp(0.0, 1.0)
}

/// The phase function in f64, as a reference.
fn hg_f64(g: f64, one_minus_mu: f64) -> f64 {
    let s = (1.0 - g) * (1.0 - g) + 2.0 * g * one_minus_mu;
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * s * s.sqrt())
}

/// 1 - cos from a sampled (cos, sin), in f64, taking whichever of 1 -+ cos is small from
/// sin^2 = (1 - cos)(1 + cos) rather than from the f32 cos (whose rounding near +-1 is a large
/// relative error in the small one).
fn one_minus(cos: f32, sin: f32) -> f64 {
    let (c, s) = (cos as f64, sin as f64);
    if c > 0.0 {
        s * s / (1.0 + c)
    } else {
        2.0 - s * s / (1.0 - c)
    }
}

/// Histogram test of the sampled angle: 100 bins of equal probability under the f64 CDF, so
/// each expects N / 100 samples wherever the lobe is (at g = 0.99 half the mass lies within
/// 1e-4 of cos = 1). N = 400k, threshold dof + 6 sqrt(2 dof) = 183 for 99 dof.
#[test]
fn sampled_cos_theta_follows_the_hg_density() {
    const BINS: usize = 100;
    const N: usize = 400_000;
    for (k, &g) in [-0.9f32, 0.0, 0.5, 0.99].iter().enumerate() {
        let hg = HenyeyGreenstein::new(g);
        let mut rng = Rng::with_domain(2009, k as u64, 1);
        let mut counts = [0u64; BINS];
        for _ in 0..N {
            let (cos, sin) = hg.sample_cos_theta(rng.next_f32());
            let f = hg_cdf(g as f64, one_minus(cos, sin));
            counts[((f * BINS as f64) as usize).min(BINS - 1)] += 1;
        }
        let chi2 = chi_square(&counts, &[N as f64 / BINS as f64; BINS]);
        println!("g = {g}: chi2 = {chi2:.1} (limit {:.1})", chi_square_limit(BINS - 1));
        assert!(chi2 < chi_square_limit(BINS - 1), "g = {g}: chi2 {chi2} over {BINS} bins");
    }
}

/// The full direction: joint histogram of (CDF of cos, azimuth) in 20 x 12 cells, azimuth
/// measured in a frame built independently of the sampler's (glam's any_orthonormal_pair),
/// for incoming directions on both sides of the basis' z = 0 switch. Also checks unit length.
#[test]
fn sampled_directions_follow_the_hg_density() {
    const NC: usize = 20;
    const NPHI: usize = 12;
    const N: usize = 480_000;
    for (k, &g) in [-0.9f32, 0.0, 0.5, 0.99].iter().enumerate() {
        for (j, w_in) in [Vec3::new(1.0, 2.0, -3.0).normalize(), Vec3::Z, Vec3::new(0.3, -0.2, 0.5).normalize()].into_iter().enumerate() {
            let hg = HenyeyGreenstein::new(g);
            let w = w_in.as_dvec3();
            let (a, b) = w.any_orthonormal_pair();
            let mut rng = Rng::with_domain(2009, (10 * k + j) as u64, 2);
            let mut counts = vec![0u64; NC * NPHI];
            for _ in 0..N {
                let w_out = hg.sample(w_in, rng.next_vec2());
                assert!((w_out.length() - 1.0).abs() < 1e-5, "|w_out| = {}", w_out.length());
                let d: DVec3 = w_out.as_dvec3();
                let perp = d - d.dot(w) * w;
                let cos = d.dot(w);
                let one_minus_cos = if cos > 0.0 { perp.length_squared() / (1.0 + cos) } else { 2.0 - perp.length_squared() / (1.0 - cos) };
                let f = hg_cdf(g as f64, one_minus_cos);
                let phi = perp.dot(b).atan2(perp.dot(a)).rem_euclid(std::f64::consts::TAU);
                let ic = ((f * NC as f64) as usize).min(NC - 1);
                let ip = ((phi / std::f64::consts::TAU * NPHI as f64) as usize).min(NPHI - 1);
                counts[ic * NPHI + ip] += 1;
            }
            let cells = NC * NPHI;
            let chi2 = chi_square(&counts, &vec![N as f64 / cells as f64; cells]);
            assert!(chi2 < chi_square_limit(cells - 1), "g = {g}, w_in = {w_in}: chi2 {chi2} over {cells} cells");
        }
    }
}

/// integral over the sphere of p = 2 pi integral_{-1}^{1} p(mu) dmu = 1, by composite Simpson
/// on a partition of x = 1 - mu (or 1 + mu for g < 0) that is geometric toward the peak, so
/// even the g = 0.999 lobe (width ~1e-6 in x) is resolved. The integrand is the f32 `eval`,
/// fed cos values as f32; tolerance 1e-4 (2e-3 at |g| = 0.999, where f32 cos itself is
/// quantised at 6e-8, a tenth of the lobe width).
#[test]
fn hg_integrates_to_one_over_the_sphere() {
    for &g in &[-0.999f32, -0.9, -0.3, 0.0, 0.5, 0.9, 0.99, 0.999] {
        let hg = HenyeyGreenstein::new(g);
        // Distance from the peak, 0..2; the peak is at cos = 1 for g >= 0, at -1 for g < 0.
        let p = |x: f64| {
            let cos = if g >= 0.0 { 1.0 - x } else { x - 1.0 };
            hg.eval(cos as f32) as f64
        };
        let mut edges = vec![0.0];
        let mut e = 1e-12;
        while e < 2.0 {
            edges.push(e);
            e *= 1.05;
        }
        edges.push(2.0);
        let mut integral = 0.0;
        for w in edges.windows(2) {
            let (a, b) = (w[0], w[1]);
            integral += (b - a) / 6.0 * (p(a) + 4.0 * p(0.5 * (a + b)) + p(b));
        }
        integral *= 2.0 * std::f64::consts::PI;
        let tol = if g.abs() > 0.99 { 2e-3 } else { 1e-4 };
        println!("g = {g}: integral {integral}");
        assert!((integral - 1.0).abs() < tol, "g = {g}: integral {integral}");
    }
}

/// HG's mean cosine is g: a sample-mean check, tolerance 5 standard errors, including the
/// extreme g = +-0.999 where the textbook sampling formula breaks down in f32.
#[test]
fn mean_cosine_is_g() {
    const N: usize = 200_000;
    for (k, &g) in [-0.999f32, -0.9, 0.0, 0.5, 0.99, 0.999].iter().enumerate() {
        let hg = HenyeyGreenstein::new(g);
        let mut rng = Rng::with_domain(7, k as u64, 3);
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for _ in 0..N {
            let c = hg.sample_cos_theta(rng.next_f32()).0 as f64;
            sum += c;
            sum2 += c * c;
        }
        let mean = sum / N as f64;
        let sigma = ((sum2 / N as f64 - mean * mean).max(0.0) / N as f64).sqrt();
        assert!((mean - g as f64).abs() < 5.0 * sigma + 1e-6, "g = {g}: mean cos {mean} +- {sigma}");
    }
}

/// Extremes of xi and g: everything finite, in range, cos^2 + sin^2 = 1, and the endpoints
/// xi = 0 -> forward (cos = 1), xi -> 1 -> backward.
#[test]
fn sampling_is_stable_at_the_extremes() {
    let xis = [0.0f32, 1e-7, 1e-4, 0.25, 0.5, 0.75, 1.0 - 1e-4, 1.0 - 1.0 / 16_777_216.0];
    for &g in &[-HG_G_MAX, -0.999, -0.5, -1e-4, 0.0, 1e-4, 0.5, 0.999, HG_G_MAX, 1.0, -1.0, 5.0] {
        let hg = HenyeyGreenstein::new(g);
        for &xi in &xis {
            let (c, s) = hg.sample_cos_theta(xi);
            assert!(c.is_finite() && s.is_finite() && (-1.0..=1.0).contains(&c) && (0.0..=1.0).contains(&s), "g {g} xi {xi}: {c} {s}");
            assert!((c * c + s * s - 1.0).abs() < 1e-6, "g {g} xi {xi}: cos^2+sin^2 = {}", c * c + s * s);
            let (w, pdf) = hg.sample_with_pdf(Vec3::new(0.0, 0.6, -0.8), Vec2::new(xi, 0.3));
            assert!(w.is_finite() && (w.length() - 1.0).abs() < 1e-5 && pdf.is_finite() && pdf > 0.0, "g {g} xi {xi}: {w} {pdf}");
        }
        assert_eq!(hg.sample_cos_theta(0.0).0, 1.0, "g {g}");
        assert!(hg.sample_cos_theta(1.0 - 1.0 / 16_777_216.0).0 < 0.0 || g.abs() >= 0.999, "g {g}");
    }
}

/// f32 `eval` and `sample_cos_theta` against f64 references at g = +-0.999 and 0.5, where
/// the textbook forms lose most of their digits near the peak.
#[test]
fn eval_and_sampling_keep_their_precision_near_the_peak() {
    for &g in &[0.999f32, -0.999, 0.5] {
        let hg = HenyeyGreenstein::new(g);
        let gd = g as f64;
        for i in 0..=2000 {
            let cos = -1.0 + i as f32 / 1000.0;
            let reference = hg_f64(gd, 1.0 - cos as f64);
            let got = hg.eval(cos) as f64;
            assert!((got / reference - 1.0).abs() < 2e-6, "g {g} cos {cos}: {got} vs {reference}");
        }
        for i in 0..1000 {
            let xi = (i as f32 + 0.5) / 1000.0;
            let (c, s) = hg.sample_cos_theta(xi);
            // Where the f64 CDF puts this angle: should be xi measured from the forward end.
            let f = hg_cdf(gd, one_minus(c, s));
            assert!(((1.0 - f) - xi as f64).abs() < 2e-6, "g {g} xi {xi}: cos {c} sin {s} has CDF {f}");
        }
    }
}

/// The pdf returned with a sample is the phase function of the sampled pair.
#[test]
fn pdf_is_eval() {
    let mut rng = Rng::new(1, 2);
    for &g in &[-0.7f32, 0.0, 0.3, 0.9] {
        let hg = HenyeyGreenstein::new(g);
        let w_in = Vec3::new(-0.48, 0.6, 0.64);
        for _ in 0..1000 {
            let (w_out, pdf) = hg.sample_with_pdf(w_in, rng.next_vec2());
            let expected = hg.pdf(w_in, w_out);
            assert!((pdf / expected - 1.0).abs() < 1e-3, "g {g}: {pdf} vs {expected}");
        }
    }
    assert!((HenyeyGreenstein::new(0.0).eval(0.3) - 1.0 / (4.0 * std::f32::consts::PI)).abs() < 1e-8);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]

    /// Over random g up to |g| = 0.999, random incoming directions and random draws: the
    /// sample is a unit vector, the pdf it reports is the phase function of the pair (the one
    /// `pdf` computes from the directions) to the precision dot(w_in, w_out) allows, positive
    /// and finite, and the sampled angle inverts the CDF at the draw.
    #[test]
    fn sampling_and_pdf_agree_for_any_g(
        g in -0.999f32..0.999, theta in 0.0f32..3.14159, phi in 0.0f32..6.28318,
        u in proptest::array::uniform2(0.0f32..1.0),
    ) {
        let hg = HenyeyGreenstein::new(g);
        let w_in = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()).normalize();
        let (w_out, pdf) = hg.sample_with_pdf(w_in, Vec2::from(u));
        proptest::prop_assert!((w_out.length() - 1.0).abs() < 1e-5, "|w_out| = {}", w_out.length());
        proptest::prop_assert!(pdf.is_finite() && pdf > 0.0, "pdf {}", pdf);
        // Near the forward peak of a sharp lobe the pdf from dot() is limited by f32 rounding
        // of the dot product; compare in f64 from the same dot with a tolerance for that.
        let cos = w_in.as_dvec3().dot(w_out.as_dvec3()).clamp(-1.0, 1.0);
        let from_dirs = hg_f64(g as f64, 1.0 - cos);
        let slope = {
            // The step stays inside 1 - cos in [0, 2]: past 2 (a backward lobe sampled within
            // 1e-6 of its peak) the phase function's base goes negative and the slope NaN.
            let dx = if 1.0 - cos + 1e-6 <= 2.0 { 1e-6 } else { -1e-6 };
            ((hg_f64(g as f64, 1.0 - cos + dx) - from_dirs) / dx).abs()
        };
        proptest::prop_assert!((pdf as f64 - from_dirs).abs() <= 2e-3 * from_dirs + slope * 2e-6,
            "g {}: pdf {} vs {} from the directions", g, pdf, from_dirs);
        let (c, s) = hg.sample_cos_theta(u[0]);
        let f = hg_cdf(g as f64, one_minus(c, s));
        proptest::prop_assert!(((1.0 - f) - u[0] as f64).abs() < 1e-4, "g {}: CDF {} at draw {}", g, 1.0 - f, u[0]);
    }
}
