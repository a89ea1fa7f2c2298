//! Properties of the integrator and the free-path inversion over random density fields
//! (proptest): composite Simpson is exact on the trilinear density, sample_simpson inverts
//! the optical depth, sample_exponential inverts a homogeneous one, and the sampled distance
//! converges at fourth order in the step.

use glam::{DVec3, IVec3};
use nimbus_tracking::{DensityMedium, FreePath, MediumRay};
use nimbus_volume::{MajorantGrid, Transform, Volume};
use proptest::prelude::*;

/// A 6^3 block of voxels (0.1 wide, at `offset`) with values from an LCG seeded by `seed`,
/// scaled by `scale`; a fraction of them zero, so rays cross empty gaps.
fn random_field(seed: u64, scale: f32, offset: DVec3) -> Volume<f32> {
    let mut s = seed.wrapping_mul(2862933555777941757).wrapping_add(3037000493);
    let mut v = Volume::new(Transform::uniform(0.1, offset), 0.0f32);
    for k in 0..6 {
        for j in 0..6 {
            for i in 0..6 {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                v.set(IVec3::new(i, j, k), if u < 0.2 { 0.0 } else { u * scale });
            }
        }
    }
    v
}

/// Optical depth over [0, t] along the ray by the midpoint rule on 20000 sub-steps per
/// unit length: an independent reference, accurate to ~1e-6 relative on these fields.
fn reference_depth(v: &Volume<f32>, extinction: f32, origin: DVec3, dir: DVec3, t: f64) -> f64 {
    let n = ((t * 20_000.0).ceil() as usize).max(1);
    let h = t / n as f64;
    (0..n).map(|i| extinction as f64 * v.sample_world(origin + dir * ((i as f64 + 0.5) * h)).max(0.0) as f64 * h).sum()
}

fn unit(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Simpson with panels split at voxel boundaries integrates the trilinear density exactly
    /// (it is a cubic in t within a cell), whatever the step, along oblique rays.
    #[test]
    fn optical_depth_is_the_integral_of_the_trilinear_density(
        seed in any::<u64>(), theta in 0.0f64..3.14, phi in 0.0f64..6.28, step in 0.002f64..0.5,
        start in prop::array::uniform3(0.0f64..0.5),
    ) {
        let v = random_field(seed, 4.0, DVec3::ZERO);
        let majorant = MajorantGrid::build(&v);
        let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.5 };
        let (origin, dir) = (DVec3::from(start), unit(theta, phi));
        let ray = MediumRay::new(medium, origin, dir, 0.0, 0.6);
        let got = ray.optical_depth(step);
        let want = reference_depth(&v, 1.5, origin, dir, 0.6);
        prop_assert!((got - want).abs() <= 1e-5 * (1.0 + want), "{} vs {}", got, want);
    }

    /// sample_simpson(tau) lands where the optical depth from the origin is tau; when it
    /// reports an escape the whole ray's depth is below tau. Also far from the origin (a
    /// world offset of 1e6), where positions carry 1e-10 relative rounding.
    #[test]
    fn sample_simpson_inverts_the_optical_depth(
        seed in any::<u64>(), theta in 0.0f64..3.14, phi in 0.0f64..6.28, step in 0.005f64..0.3,
        u in 0.0f64..0.999, scale in prop::sample::select(vec![0.5f32, 5.0, 50.0]),
        far in any::<bool>(),
    ) {
        let offset = if far { DVec3::splat(1e6) } else { DVec3::ZERO };
        let v = random_field(seed, scale, offset);
        let majorant = MajorantGrid::build(&v);
        let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
        let dir = unit(theta, phi);
        let origin = offset + DVec3::splat(0.25) - dir * 0.5;
        let tau = -(1.0 - u).ln();
        let ray = MediumRay::new(medium, origin, dir, 0.0, f64::INFINITY);
        match ray.sample_simpson(tau, step) {
            FreePath::Interaction(t) => {
                let depth = MediumRay::new(medium, origin, dir, 0.0, t).optical_depth(step);
                // The depth up to t is exact; t itself carries the last panel's quadratic fit
                // of a cubic sigma_t: off by at most ~|cubic coefficient| h^4 / 50, the
                // coefficient bounded by 8 max(sigma) / voxel^3 for a trilinear cell.
                let h = step.min(0.1 * 3f64.sqrt());
                let fit = 8.0 * scale as f64 / 1e-3 * h.powi(4) / 50.0;
                let tol = 1e-6 * (1.0 + tau) + fit + if far { 1e-4 * tau } else { 0.0 };
                prop_assert!((depth - tau).abs() <= tol, "depth at t = {} is {}, wanted {} (tolerance {})", t, depth, tau, tol);
            }
            FreePath::Escaped => {
                let total = ray.optical_depth(step);
                prop_assert!(total < tau * (1.0 + 1e-9), "escaped with total depth {} >= {}", total, tau);
            }
        }
    }

    /// In a homogeneous medium Eq. 1 is exact: sample_exponential(tau) = tau / sigma_t
    /// past the entry point, the same distance Simpson finds.
    #[test]
    fn sample_exponential_inverts_a_homogeneous_depth(
        sigma in 0.5f32..200.0, u in 0.0f64..0.99, step in 0.001f64..0.05, x in 0.15f64..0.35, y in 0.15f64..0.35,
    ) {
        let mut v = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0f32);
        for k in -2..12 {
            for j in -2..8 {
                for i in -2..8 {
                    v.set(IVec3::new(i, j, k), sigma);
                }
            }
        }
        let majorant = MajorantGrid::build(&v);
        let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
        // Start inside the uniform region, straight up through 0.8 world units of it.
        let origin = DVec3::new(x, y, 0.1);
        let tau = -(1.0 - u).ln();
        let ray = MediumRay::new(medium, origin, DVec3::Z, 0.0, 0.8);
        let want = tau / sigma as f64;
        prop_assume!(want < 0.8);
        let FreePath::Interaction(e) = ray.sample_exponential(tau, step) else { panic!("escaped before {want}") };
        let FreePath::Interaction(s) = ray.sample_simpson(tau, step) else { panic!("escaped before {want}") };
        prop_assert!((e - want).abs() <= 1e-9 + 1e-6 * want, "exponential {} vs {}", e, want);
        prop_assert!((s - want).abs() <= 1e-9 + 1e-6 * want, "simpson {} vs {}", s, want);
    }
}

/// The one approximation in sample_simpson is the last panel: sigma_t there is taken as the
/// quadratic through its three Simpson samples. Along a diagonal through a voxel cell the
/// trilinear density is a true cubic in t, so the sampled distance is off by O(h^4): halving
/// the step must cut the error about 16-fold (4th order), while the optical depth itself is
/// exact at every step.
#[test]
fn sampled_distance_converges_at_fourth_order() {
    // One cell [0,1]^3 in index space: density 0.2 + 40 x y z, a cubic s^3 along the diagonal.
    let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0f32);
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                v.set(IVec3::new(i, j, k), 0.2 + 40.0 * (i * j * k) as f32);
            }
        }
    }
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
    let dir = DVec3::ONE.normalize();
    let length = 3f64.sqrt();
    // sigma(t) = 0.2 + 40 (t / sqrt 3)^3: its integral in closed form, inverted by bisection.
    let depth = |t: f64| 0.2 * t + 10.0 * t.powi(4) / (3.0 * length);
    let exact = |tau: f64| {
        let (mut lo, mut hi) = (0.0, length);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if depth(mid) < tau {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    };
    let ray = MediumRay::new(medium, DVec3::ZERO, dir, 0.0, length);
    assert!((ray.optical_depth(length) - depth(length)).abs() < 1e-5 * depth(length), "one panel integrates the cubic exactly");
    // Mean absolute error over targets spread through the cell, at steps h, h/2, h/4, ...
    let taus: Vec<f64> = (1..40).map(|i| depth(length) * i as f64 / 40.0).collect();
    let error = |step: f64| {
        taus.iter()
            .map(|&tau| match ray.sample_simpson(tau, step) {
                FreePath::Interaction(t) => (t - exact(tau)).abs(),
                FreePath::Escaped => panic!("escaped at tau {tau}"),
            })
            .sum::<f64>()
            / taus.len() as f64
    };
    let steps = [length / 2.0, length / 4.0, length / 8.0, length / 16.0];
    let errors: Vec<f64> = steps.iter().map(|&h| error(h)).collect();
    eprintln!("mean |t - t_exact| at steps L/2, L/4, L/8, L/16: {errors:?}");
    for w in errors.windows(2) {
        let ratio = w[0] / w[1];
        assert!((10.0..26.0).contains(&ratio), "error ratio {ratio:.2} on halving the step (errors {errors:?}); 16 is fourth order");
    }
}
