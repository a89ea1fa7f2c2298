//! Free-path sampling against closed forms: a homogeneous slab, where the first-interaction
//! depth is exponential, and a step in density, where Eq. 1 is known to be wrong.

use glam::{DVec3, IVec3};
use nimbus_optics::Rng;
use nimbus_tracking::{DensityMedium, FreePath, MediumRay};
use nimbus_volume::{MajorantGrid, Transform, Volume, BRICK_DIM};

/// Density `value` on voxels with z in [z0, z1] over an x,y patch; voxel size 0.1.
fn slab(z0: i32, z1: i32, value: impl Fn(i32) -> f32) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0);
    for x in -24..24 {
        for y in -24..24 {
            for z in z0..=z1 {
                v.set(IVec3::new(x, y, z), value(z));
            }
        }
    }
    v
}

fn sample_depths(v: &Volume<f32>, extinction: f32, mode: &str, n: u64, start_z: f64) -> Vec<Option<f64>> {
    let majorant = MajorantGrid::build(v);
    let medium = DensityMedium { motion: None, density: v, majorant: &majorant, extinction };
    // Straight down, in the middle of the patch.
    let origin = DVec3::new(0.05, 0.05, start_z);
    let ray = MediumRay::new(medium, origin, DVec3::NEG_Z, 0.0, f64::INFINITY);
    (0..n)
        .map(|i| {
            let mut rng = Rng::new(7, i);
            let tau = -(1.0 - rng.next_f64()).ln();
            let path = match mode {
                "simpson" => ray.sample_simpson(tau, 0.05),
                "exponential" => ray.sample_exponential(tau, 0.05),
                "delta" => ray.sample_delta(&mut rng),
                _ => unreachable!(),
            };
            match path {
                FreePath::Interaction(t) => Some(start_z - t),
                FreePath::Escaped => None,
            }
        })
        .collect()
}

#[test]
fn homogeneous_slab_depths_are_exponential() {
    // Density 1 on z in [0, 2] world (voxels 0..=20); the top voxel plane is at z = 2.0 and
    // interpolation ramps from 0 at z = 2.1 to 1 at z = 2.0, so the slab effectively starts at
    // 2.05 on average. Test the part below z = 2.0, where sigma_t is exactly the constant.
    // Eq. 1 freezes sigma_t where the ray first finds density, which for a ray from outside is
    // on the ramp: it is only exact for rays that start inside, so it starts at z = 2.0 here.
    let extinction = 2.0f32;
    let v = slab(0, 20, |_| 1.0);
    let n = 40_000;
    for (mode, start_z) in [("simpson", 10.0), ("delta", 10.0), ("exponential", 2.0)] {
        let depths = sample_depths(&v, extinction, mode, n, start_z);
        // Depth below the plane z = 2.0 of paths that reached it and interacted above z = 0.3.
        let below: Vec<f64> = depths.iter().flatten().map(|z| 2.0 - z).filter(|d| *d >= 0.0 && *d < 1.7).collect();
        // Exponential with rate 2 truncated to [0, 1.7): compare the CDF at several depths
        // (a Kolmogorov-Smirnov bound: with ~30k samples, 1.63/sqrt(n) ~ 0.01 at p = 0.01).
        let rate = extinction as f64;
        let norm = 1.0 - (-rate * 1.7).exp();
        let mut worst = 0.0f64;
        for k in 1..17 {
            let d = k as f64 * 0.1;
            let empirical = below.iter().filter(|&&x| x < d).count() as f64 / below.len() as f64;
            let exact = (1.0 - (-rate * d).exp()) / norm;
            worst = worst.max((empirical - exact).abs());
        }
        let bound = 1.63 / (below.len() as f64).sqrt();
        assert!(worst < bound, "{mode}: KS distance {worst:.4} over {bound:.4} ({} samples)", below.len());
        // Mean free path in the constant part: 1/rate, corrected for the truncation.
        let mean = below.iter().sum::<f64>() / below.len() as f64;
        let exact_mean = 1.0 / rate - 1.7 * (-rate * 1.7).exp() / norm;
        assert!((mean - exact_mean).abs() < 4.0 * 0.5 / (below.len() as f64).sqrt(), "{mode}: mean {mean} vs {exact_mean}");
    }
}

#[test]
fn density_step_separates_eq1_from_eq2() {
    // A thin layer (density 0.05) above a dense one (density 5): photons coming from above
    // see the thin layer first. Eq. 1 freezes the thin value and flies far into the dense
    // layer; Eq. 2 and delta tracking stop soon after the step.
    let v = slab(0, 40, |z| if z >= 20 { 0.05 } else { 5.0 });
    let n = 20_000;
    let mean_depth = |mode| {
        let d = sample_depths(&v, 1.0, mode, n, 10.0);
        let hits: Vec<f64> = d.iter().flatten().copied().collect();
        (hits.iter().sum::<f64>() / hits.len() as f64, hits.len())
    };
    let (simpson, simpson_hits) = mean_depth("simpson");
    let (delta, delta_hits) = mean_depth("delta");
    let (_, exponential_hits) = mean_depth("exponential");
    // Simpson and delta agree to sampling noise (both unbiased up to Simpson's tiny error).
    assert!((simpson - delta).abs() < 0.02, "simpson {simpson} vs delta {delta}");
    // The slab's optical depth is 10.1: nearly every photon interacts.
    let p_interact = 1.0 - (-10.1f64).exp();
    for (mode, hits) in [("simpson", simpson_hits), ("delta", delta_hits)] {
        assert!((hits as f64 / n as f64 - p_interact).abs() < 0.01, "{mode}: {hits} of {n}");
    }
    // Eq. 1 freezes sigma_t where the ray first finds density (on the interpolation ramp
    // above the thin layer, at most 0.05) and sends most photons straight through the dense
    // layer: at most 1 - exp(-0.05 * 4.1) = 19% interact.
    let fraction = exponential_hits as f64 / n as f64;
    assert!(fraction > 0.02 && fraction < 1.0 - (-0.05f64 * 4.1).exp() + 0.01, "exponential: {exponential_hits} of {n}");
}

#[test]
fn optical_depth_is_exact_for_piecewise_linear_density() {
    // Trilinear interpolation along an axis-aligned ray through voxel centres is piecewise
    // linear, which Simpson integrates exactly when the panels match the voxels.
    let v = slab(0, 9, |z| 1.0 + z as f32);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
    let ray = MediumRay::new(medium, DVec3::new(0.0, 0.0, 0.0), DVec3::Z, 0.0, 0.9);
    // Integral of (1 + 10 z) dz from 0 to 0.9 (density 1 + z_index, z_index = 10 z).
    let exact = 0.9 + 5.0 * 0.81;
    let got = ray.optical_depth(0.1);
    assert!((got - exact).abs() < 1e-5, "{got} vs {exact}");
    let _ = BRICK_DIM;
}

#[test]
fn a_nonzero_background_does_not_hang_any_sampler() {
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.01f32);
    v.set(IVec3::ZERO, 1.0);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
    let ray = MediumRay::new(medium, DVec3::new(0.0, 0.0, -5.0), DVec3::Z, 0.0, f64::INFINITY);
    let mut rng = Rng::new(1, 1);
    assert!(ray.optical_depth(0.05).is_finite());
    let _ = ray.sample_simpson(1e9, 0.05);
    let _ = ray.sample_exponential(1e9, 0.05);
    let _ = ray.sample_delta(&mut rng);
    assert!(ray.transmittance_ratio(&mut rng, 0.1).is_finite());
}

/// Delta and ratio tracking carry one exponential draw across majorant segments: through a
/// slab of one-voxel majorant cells whose density changes from layer to layer (every cell a
/// segment with its own majorant, 21 of them along the ray), the escape probability of delta
/// tracking and the mean of ratio tracking must both be the closed-form transmittance
/// exp(-optical depth) (Simpson is exact on the trilinear density), and the interaction
/// depths below each layer must follow it too. A carry that lost or double-counted the
/// remainder at a boundary would miss by far more than the four standard errors allowed.
#[test]
fn tracking_across_many_segments_keeps_the_closed_form_transmittance() {
    let v = slab(0, 20, |z| if z % 2 == 0 { 0.4 } else { 1.6 } + 0.05 * z as f32);
    let extinction = 0.5f32;
    let majorant = MajorantGrid::with_cell_log2(&v, 0);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction };
    let origin = DVec3::new(0.05, 0.05, 10.0);
    let ray = MediumRay::new(medium, origin, DVec3::NEG_Z, 0.0, f64::INFINITY);
    let n = 40_000u64;
    let tau = ray.optical_depth(0.01);
    let exact = (-tau).exp();
    let escaped = (0..n).filter(|&i| ray.sample_delta(&mut Rng::new(11, i)) == FreePath::Escaped).count() as f64 / n as f64;
    let se = (exact * (1.0 - exact) / n as f64).sqrt();
    assert!((escaped - exact).abs() < 4.0 * se, "delta tracking escapes {escaped}, exp(-{tau}) = {exact} (se {se})");
    let ratios: Vec<f64> = (0..n).map(|i| ray.transmittance_ratio(&mut Rng::new(12, i), 0.05)).collect();
    let mean = ratios.iter().sum::<f64>() / n as f64;
    let sd = (ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    assert!((mean - exact).abs() < 4.0 * sd / (n as f64).sqrt() + 1e-12, "ratio tracking {mean}, exp(-{tau}) = {exact}");
    // The depth distribution: the fraction that interacts above each layer plane is
    // 1 - exp(-optical depth down to it).
    let depths: Vec<Option<f64>> = (0..n)
        .map(|i| match ray.sample_delta(&mut Rng::new(13, i)) {
            FreePath::Interaction(t) => Some(t),
            FreePath::Escaped => None,
        })
        .collect();
    for z in [1.7, 1.35, 1.0, 0.45] {
        let t = 10.0 - z;
        let cut = MediumRay::new(medium, origin, DVec3::NEG_Z, 0.0, t).optical_depth(0.01);
        let p = 1.0 - (-cut).exp();
        let empirical = depths.iter().filter(|d| d.is_some_and(|d| d < t)).count() as f64 / n as f64;
        let se = (p * (1.0 - p) / n as f64).sqrt();
        assert!((empirical - p).abs() < 4.0 * se, "above z = {z}: {empirical} interacted, closed form {p}");
    }
}
