//! Multiple-scattering sanity: baked Li_multiple in an optically thick homogeneous sphere
//! (optical radius 4, albedo 0.99) against an independent path-traced reference, and its
//! convergence as photons increase. `examples/multiple_sanity.rs` prints the full table.

mod support;

use glam::DVec3;
use support::sphere::{POINTS, THICK};

#[test]
fn li_multiple_approaches_a_path_traced_reference_as_photons_increase() {
    let points: Vec<DVec3> = POINTS.iter().map(|&p| DVec3::from_array(p)).collect();
    let reference: Vec<f64> = points
        .iter()
        .map(|&p| {
            let (v, e) = THICK.reference(p, 100_000, 1);
            assert!(e < 0.01 * v, "reference noise {e} at {p}");
            v
        })
        .collect();
    let mean_error = |photons, k| {
        let baked = THICK.baked(1.0 / 24.0, photons, k, 11, &points);
        baked.iter().zip(&reference).map(|(b, r)| (b / r - 1.0).abs()).sum::<f64>() / points.len() as f64
    };
    // Photons of one path are correlated, so the noise is well above 1/sqrt(k): measured mean
    // errors over two seeds are 18-26% at 10k photons and 9-10% at 160k (example table).
    let coarse = mean_error(10_000, 32);
    let fine = mean_error(160_000, 128);
    eprintln!("mean |relative error|: {:.1}% at 10k photons, {:.1}% at 160k", 100.0 * coarse, 100.0 * fine);
    assert!(fine < 0.15, "160k photons: mean relative error {fine}");
    assert!(fine < coarse, "error grows with photons: {coarse} -> {fine}");
}

#[test]
fn path_traced_li_multiple_matches_the_reference_to_its_noise() {
    let points: Vec<DVec3> = POINTS.iter().map(|&p| DVec3::from_array(p)).collect();
    let traced = THICK.path_traced(1.0 / 24.0, 16_000, 5, &points);
    for (p, (v, e)) in points.iter().zip(&traced) {
        let (r, re) = THICK.reference(*p, 100_000, 1);
        // The voxelized sphere's one-voxel surface ramp differs from the exact sphere by a
        // little: 2% of slack for it, plus four standard errors of both estimates.
        let tolerance = 0.02 * r + 4.0 * (e * e + re * re).sqrt();
        eprintln!("{p}: paths {v:.5} +- {e:.5}, reference {r:.5} +- {re:.5}");
        assert!((v - r).abs() < tolerance, "at {p}: path-traced {v} against reference {r} (tolerance {tolerance})");
        assert!(*e < 0.05 * v, "path-traced noise {e} at {p}: the batches disagree");
    }
}

#[test]
fn baked_paths_agree_with_the_reference_where_the_eye_sees() {
    // Points on the camera's side (the default camera looks from -Y), where voxels get most
    // of their paths.
    let points: Vec<DVec3> = [[0.0, -0.6, 0.0], [0.0, -0.5, 0.4], [0.3, -0.5, -0.3]].iter().map(|&p| DVec3::from_array(p)).collect();
    let baked = THICK.baked_paths(1.0 / 8.0, 1.0, 256, 3, &points);
    for (p, b) in points.iter().zip(&baked) {
        let (r, _) = THICK.reference(*p, 100_000, 2);
        eprintln!("{p}: baked {b:.5}, reference {r:.5}");
        // The cache lattice's interpolation and the coarse voxelization (1/8 of the radius)
        // add to the paths' noise: 15%.
        assert!((b / r - 1.0).abs() < 0.15, "at {p}: baked {b} against reference {r}");
    }
    let again = THICK.baked_paths(1.0 / 8.0, 1.0, 256, 3, &points);
    assert_eq!(baked, again, "same seed, same cache");
    let other = THICK.baked_paths(1.0 / 8.0, 1.0, 256, 4, &points);
    assert_ne!(baked, other, "the seed reaches the paths");
}
