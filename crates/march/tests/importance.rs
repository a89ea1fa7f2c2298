//! vdbcache spends its paths by the camera's image derivatives
//! ([`nimbus_cache::CameraImportance`]); here they are checked against the march itself, one
//! cache voxel at a time: a cache holding 1 at voxel v and 0 elsewhere renders each pixel's
//! derivative with respect to v's value.

mod common;

use common::{camera, cloud, params};
use glam::{DVec3, Vec3};
use nimbus_cache::{pixel_samples_per_side, CachePlan, CameraImportance, IlluminationCache};
use nimbus_march::{march_ray, MarchParams};
use nimbus_optics::{Camera, Medium};
use nimbus_volume::{MajorantGrid, Volume};

/// The cloud, a `w` x `h` camera on it, its majorant and the plan of cache voxels `scale`
/// density voxels wide.
fn scene(w: u32, h: u32, scale: f64) -> (Volume<f32>, Camera, MajorantGrid, CachePlan) {
    let density = cloud(24, 25.0, DVec3::ZERO);
    let cam = camera(DVec3::ZERO, w, h);
    let majorant = MajorantGrid::build(&density);
    let plan = CachePlan::new(&density, &majorant, &cam, DVec3::splat(scale));
    (density, cam, majorant, plan)
}

/// The points of pixel (px, py) the importance's rays pass through, and each one's share of
/// the pixel: the centres of the march's n x n strata (n = [`pixel_samples_per_side`]; these
/// small images keep all of them within the importance's ray budget).
fn pixel_samples(cam: &Camera, density: &Volume<f32>, px: u32, py: u32) -> Vec<(f64, f64, f64)> {
    let n = pixel_samples_per_side(cam, density);
    let share = 1.0 / (n * n) as f64;
    (0..n * n)
        .map(|s| (px as f64 + ((s % n) as f64 + 0.5) / n as f64, py as f64 + ((s / n) as f64 + 0.5) / n as f64, share))
        .collect()
}

#[test]
fn importance_is_the_sum_of_squared_pixel_derivatives_of_the_march() {
    let (w, h) = (12, 8);
    let (density, cam, majorant, plan) = scene(w, h, 2.0);
    // Thin enough that no importance step holds more than a quarter optical depth: denser
    // steps are cut where the march's are not (the next test measures what that buys).
    let medium = Medium { extinction: 0.05, albedo: Vec3::splat(0.8), g: 0.0 };
    let half_voxel = 0.5 * plan.transform.voxel_size().min_element();
    assert!(medium.extinction as f64 * density.peak() as f64 * half_voxel <= 0.25);
    let importance = CameraImportance::new(&plan, &density, &majorant, medium.extinction, &cam, 0.0);
    let g = &importance.g;
    assert_eq!(g.len() as u64, plan.stats.baked);
    // The march on importance's own terms: its step (half the cache voxel), the sample
    // lattice at xi = 0.5, the centres of each pixel's strata.
    let march = MarchParams { medium, step: 0.5 * plan.transform.voxel_size().min_element(), max_step_factor: 1, offset_noise: 0.0, min_transmittance: 0.0, ..params(cam.clone()) };

    let mut order: Vec<usize> = (0..g.len()).collect();
    order.sort_by(|&a, &b| g[b].total_cmp(&g[a]));
    let seen = order.iter().filter(|&&v| g[v] > 0.0).count();
    assert!(seen > 10 && seen < g.len(), "some voxels are read by the camera's rays and some are not: {seen} of {}", g.len());
    // The most important voxel, a few down the order, the least seen, and unseen ones.
    let picked = [order[0], order[seen / 4], order[seen / 2], order[seen - 1], order[seen], order[g.len() - 1]];
    for &v in &picked {
        let mut values = vec![Vec3::ZERO; g.len()];
        values[v] = Vec3::ONE;
        let cache = IlluminationCache { li_single: None, li_multiple: Some(plan.volume_of(&values).0), ..Default::default() };
        let mut sum = 0.0f64;
        for py in 0..h {
            for px in 0..w {
                let mut a = 0.0;
                for (x, y, share) in pixel_samples(&cam, &density, px, py) {
                    let (origin, dir) = cam.ray(x, y);
                    let r = march_ray(&density, &majorant, &cache, &march, origin, dir, 0.5, 0.0);
                    a += share * r.multiple.x as f64 / medium.albedo.x as f64;
                }
                sum += a * a;
            }
        }
        eprintln!("voxel {v}: importance {:.6e}, march {sum:.6e}", g[v]);
        // G is summed in fixed point: terms under 2^-40 are dropped.
        let resolution = 2f64.powi(-40) * (w * h) as f64;
        if g[v] == 0.0 {
            assert!(sum <= resolution, "voxel {v}: the march reads it at {sum}, yet its importance is 0");
        } else {
            assert!((sum - g[v]).abs() <= 1e-4 * g[v] + resolution, "voxel {v}: importance {}, march {sum}", g[v]);
        }
    }
    // And they differ by orders of magnitude, which is what the paths follow.
    assert!(g[order[0]] > 100.0 * g[order[seen - 1]]);
}

/// The paths' origins make a coarse lattice faithful in the image's total: give each voxel
/// the mean of a field f over its origins (what its paths estimate when Li = f) and the
/// march's image sums to the image of f itself; give it f at its centre, as the bake did
/// before, and a field that falls steeply into the cloud (a lit surface, dark depths) comes
/// out far off (here nearly twice as bright: nodes in the clear air before the surface carry
/// its brightness into the depths; on the bundled cloud, where Li falls outward too, centre
/// values darkened the image by 2% at a lattice four voxels wide).
#[test]
fn voxels_averaged_over_their_path_origins_keep_the_image_total() {
    use nimbus_cache::{CacheParams, Gather, LightLattice, MultipleEstimator, ShadowMode};
    let (w, h) = (24, 16);
    // Four density voxels a cache voxel: far coarser than the field's fall-off.
    let (density, cam, majorant, plan) = scene(w, h, 4.0);
    // Thin enough that the importance cuts none of its steps (as in the test above).
    let medium = Medium { extinction: 0.035, albedo: Vec3::ONE, g: 0.0 };
    assert!(medium.extinction as f64 * density.peak() as f64 * 0.5 * plan.transform.voxel_size().min_element() <= 0.25);
    let cache_params = CacheParams {
        environment: None,
        medium,
        lights: vec![nimbus_optics::Light::default_sun()],
        camera: cam.clone(),
        step: 1.0,
        cache_scale: 4.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        single: false,
        multiple: true,
        gather: Gather::Neighbours { k: 1, max_radius: 1.0 },
        estimator: MultipleEstimator::Paths { per_voxel: 64 },
        seed: 3,
        min_transmittance: 0.0,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    };
    // Bright at the side facing the camera (-Y), falling over a tenth of the cloud's width.
    let f = |x: DVec3| (-(x.y + 1.2).max(0.0) / 0.12).exp();
    let positions = plan.voxel_positions();
    let voxel = plan.transform.voxel_size();
    // Each voxel's mean over its origins is an unbiased estimate of f's mean over what the
    // image reads through it, and one seed's draw is off by its noise (a few percent here,
    // where one voxel with a single origin on the lit surface carries much of the image):
    // the expectation is what holds, so several seeds' images are averaged.
    let seeds = 1..=16u64;
    let averaged: Vec<Vec<Vec3>> = seeds
        .clone()
        .map(|seed| {
            let path_plan = CameraImportance::path_plan(&plan, &density, &majorant, &CacheParams { seed, ..cache_params.clone() }, 64);
            assert_eq!(path_plan.total(), 64 * plan.stats.baked, "the budget is N per voxel");
            for (v, &c) in positions.iter().enumerate() {
                for o in path_plan.origins_of(v) {
                    assert!(((*o - c).abs() - voxel).max_element() < 1e-9, "voxel {v}: origin {o} outside its footprint around {c}");
                }
            }
            (0..positions.len())
                .map(|v| {
                    let origins = path_plan.origins_of(v);
                    Vec3::splat((origins.iter().map(|&o| f(o)).sum::<f64>() / origins.len().max(1) as f64) as f32)
                })
                .collect()
        })
        .collect();
    let centred: Vec<Vec3> = positions.iter().map(|&c| Vec3::splat(f(c) as f32)).collect();
    // The march on the importance's terms: its step, through its samples of each pixel.
    let march = MarchParams { medium, step: 0.5 * plan.transform.voxel_size().min_element(), max_step_factor: 1, offset_noise: 0.0, min_transmittance: 0.0, ..params(cam.clone()) };
    let samples: Vec<(f64, f64, f64)> = (0..h).flat_map(|py| (0..w).map(move |px| (px, py))).flat_map(|(px, py)| pixel_samples(&cam, &density, px, py)).collect();
    let total = |values: &[Vec3]| {
        let cache = IlluminationCache { li_single: None, li_multiple: Some(plan.volume_of(values).0), ..Default::default() };
        let mut sum = 0.0f64;
        for &(x, y, share) in &samples {
            let (origin, dir) = cam.ray(x, y);
            sum += share * march_ray(&density, &majorant, &cache, &march, origin, dir, 0.5, 0.0).multiple.x as f64;
        }
        sum
    };
    // The image of f itself, on the same samples.
    let mut truth = 0.0f64;
    let step = march.step;
    for &(px, py, share) in &samples {
        let (origin, dir) = cam.ray(px, py);
        let mut tr = 1.0f64;
        let mut t = 0.5 * step;
        while t < 12.0 && tr > 1e-9 {
            let x = origin + dir * t;
            let s = medium.extinction as f64 * density.sample_world(x).max(0.0) as f64;
            let st = (-s * step).exp();
            truth += share * tr * (1.0 - st) * f(x);
            tr *= st;
            t += step;
        }
    }
    let each: Vec<f64> = averaged.iter().map(|values| total(values) / truth).collect();
    let (a, c) = (each.iter().sum::<f64>() / each.len() as f64, total(&centred) / truth);
    eprintln!("image total over f's own: origin-averaged {a:.4} (seeds {each:.4?}), centre values {c:.4}");
    // Sixteen draws each off by about 5% leave their mean within about 1.3%: two of that.
    assert!((a - 1.0).abs() < 0.025, "origin-averaged voxels: {a}");
    assert!((c - 1.0).abs() > 0.2, "centre values should be far off on this field: {c}");
}
