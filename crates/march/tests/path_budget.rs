//! vdbcache predicts the noise its paths leave in the image (nimbus_cache's budget.rs) and
//! tops the paths up to a tolerance: here the prediction is held to the noise the march's
//! images actually show, seed against seed, and the top-up to the noise it promises.

mod common;

use common::{camera, cloud, params};
use glam::{DVec3, Vec3};
use nimbus_cache::{bake_cpu, BakeStats, CacheParams, Gather, LightLattice, MultipleEstimator, ShadowMode};
use nimbus_march::{render_cpu, MarchParams};
use nimbus_optics::{Light, Medium};
use nimbus_photon::PhotonMap;
use nimbus_volume::Volume;

const PATHS: u32 = 8;

fn medium() -> Medium {
    // Forward scattering with probes toward the sun: the paths' spread differs from voxel
    // to voxel, as it does in the scenes the top-up is for.
    Medium { extinction: 1.2, albedo: Vec3::new(0.95, 0.9, 0.85), g: 0.7 }
}

/// The cloud's image with its multiple scattering baked by paths at `seed` (`tolerance` as
/// `--path-tolerance`), and the bake's stats. Single scattering is left out: the noise is
/// the paths' alone, and its level theirs alone.
fn render(density: &Volume<f32>, seed: u64, tolerance: f64) -> (Vec<f64>, BakeStats) {
    let cam = camera(DVec3::ZERO, 40, 30);
    let cache_params = CacheParams {
        environment: None,
        medium: medium(),
        lights: vec![Light::default_sun()],
        camera: cam.clone(),
        step: 1.0,
        cache_scale: 1.0,
        single_tolerance: None,
        path_tolerance: Some(tolerance),
        multiple_scale: Some(2.0),
        multiple_tolerance: None,
        single: false,
        multiple: true,
        gather: Gather::Neighbours { k: 1, max_radius: 1.0 },
        estimator: MultipleEstimator::Paths { per_voxel: PATHS },
        seed,
        min_transmittance: 0.0,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    };
    let (cache, stats) = bake_cpu(density, &PhotonMap::default(), &cache_params).unwrap();
    let march = MarchParams { medium: medium(), background: Vec3::ZERO, aovs: false, ..params(cam) };
    let image = render_cpu(density, &cache, &march).unwrap();
    (image.rgba.iter().map(|p| ((p.x + p.y + p.z) / 3.0) as f64).collect(), stats)
}

/// The relative RMSE between two images of the same noise, over the pixels either covers:
/// one image's noise is this over sqrt 2.
fn seed_to_seed(a: &[f64], b: &[f64]) -> f64 {
    let covered: Vec<(f64, f64)> = a.iter().zip(b).map(|(&x, &y)| (x, y)).filter(|&(x, y)| x > 0.0 || y > 0.0).collect();
    let n = covered.len() as f64;
    let mse = covered.iter().map(|(x, y)| (x - y).powi(2)).sum::<f64>() / n;
    let level = covered.iter().map(|(x, y)| 0.5 * (x + y)).sum::<f64>() / n;
    (mse.sqrt() / level) / 2f64.sqrt()
}

#[test]
fn the_predicted_noise_is_the_noise_the_images_show_and_the_top_up_meets_its_tolerance() {
    let density = cloud(24, 25.0, DVec3::ZERO);
    // A tolerance no image misses: the first pass alone, with its noise predicted.
    let (a, sa) = render(&density, 1, 1.0);
    let (b, sb) = render(&density, 2, 1.0);
    let (pa, pa_after) = sa.path_noise.expect("the bake predicts the noise where a tolerance is given");
    let pb = sb.path_noise.unwrap().0;
    assert_eq!(pa, pa_after, "no top-up under a tolerance of 100%");
    assert_eq!(sa.paths, sb.paths, "the first pass alone");
    let measured = seed_to_seed(&a, &b);
    let predicted = 0.5 * (pa + pb);
    eprintln!("first pass: predicted {:.5}% and {:.5}%, measured {:.2}%", 100.0 * pa, 100.0 * pb, 100.0 * measured);
    assert!(measured > 0.005, "a noise to measure: {measured}");
    assert!((0.6..1.6).contains(&(predicted / measured)), "predicted {predicted}, measured {measured}");

    // Half that tolerance: four times the paths in all, and half the noise.
    let tolerance = 0.5 * predicted;
    let (c, sc) = render(&density, 1, tolerance);
    let (d, sd) = render(&density, 2, tolerance);
    let growth = sc.paths as f64 / sa.paths as f64;
    let after = 0.5 * (sc.path_noise.unwrap().1 + sd.path_noise.unwrap().1);
    let measured_after = seed_to_seed(&c, &d);
    eprintln!("topped up: {growth:.2}x the paths, predicted {:.2}%, measured {:.2}%", 100.0 * after, 100.0 * measured_after);
    assert!((3.3..5.0).contains(&growth), "about four times the paths: {growth}");
    assert!(after < 1.15 * tolerance, "the tolerance is met as predicted: {after} against {tolerance}");
    assert!((1.6..2.6).contains(&(measured / measured_after)), "the images' noise halves: {measured} -> {measured_after}");
}
