use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_gpu, CacheParams, MultipleEstimator};
use nimbus_optics::{Camera, HenyeyGreenstein, Light, Medium};
use nimbus_photon::PhotonMap;
use nimbus_volume::Volume;

mod support;

use support::{block, VOXEL};

fn params(camera: Camera) -> CacheParams {
    support::params(Medium { extinction: 3.0, albedo: Vec3::splat(0.8), g: 0.3 }, vec![Light::sun(Vec3::NEG_Z, Vec3::new(1.0, 2.0, 3.0)).unwrap()], camera)
}

fn side_camera(v: &Volume<f32>) -> Camera {
    let (lo, hi) = v.world_bounds().unwrap();
    Camera::default_for_bounds(lo, hi).unwrap()
}

#[test]
fn single_scattering_in_a_slab_matches_the_closed_form() {
    let v = block(IVec3::new(-10, -10, 0), IVec3::new(10, 10, 20), |_| 1.0);
    let p = params(side_camera(&v));
    let (cache, stats) = bake_cpu(&v, &PhotonMap::default(), &p).unwrap();
    let li = cache.li_single.expect("single scattering baked");
    assert!(cache.li_multiple.is_none());
    assert_eq!(stats.nonfinite, 0);
    let hg = HenyeyGreenstein::new(0.3);
    for z in [0, 5, 12, 19] {
        for (x, y) in [(0, 0), (-5, 3)] {
            let ijk = IVec3::new(x, y, z);
            let world = v.transform().to_world(ijk.as_dvec3());
            // Optical depth from the voxel up to the top plane (z index 20) plus the half voxel
            // the interpolation ramps over above it.
            let depth = (20 - z) as f64 * VOXEL + 0.5 * VOXEL;
            let tr = (-3.0 * depth).exp() as f32;
            let w_out = (p.camera.eye() - world).normalize().as_vec3();
            let want = Vec3::new(1.0, 2.0, 3.0) * tr * hg.eval_dirs(Vec3::NEG_Z, w_out);
            let got = li.get(ijk);
            assert!((got - want).abs().max_element() <= 2e-5 * want.max_element(), "at {ijk}: {got} vs {want}");
        }
    }
}

#[test]
fn single_scattering_matches_a_fine_march_in_a_varying_medium() {
    let v = block(IVec3::new(-12, -12, -12), IVec3::new(12, 12, 12), |c| {
        let r = c.as_vec3().length() / 12.0;
        (1.0 - r).max(0.0) * 4.0 + 0.3 * ((c.x as f32) * 0.7).sin().abs()
    });
    let mut p = params(side_camera(&v));
    p.lights.push(Light::point(DVec3::new(0.3, -2.0, 1.5), Vec3::splat(2.0)).unwrap());
    let (cache, _) = bake_cpu(&v, &PhotonMap::default(), &p).unwrap();
    let li = cache.li_single.unwrap();
    let hg = HenyeyGreenstein::new(0.3);
    // Brute force: Riemann sums with 2000 steps per shadow ray, written independently.
    let optical_depth = |from: DVec3, to: DVec3| {
        let n = 2000;
        let d = to - from;
        (0..n).map(|i| v.sample_world(from + d * ((i as f64 + 0.5) / n as f64)).max(0.0) as f64).sum::<f64>() * 3.0 * d.length() / n as f64
    };
    let mut checked = 0;
    for n in 0..20 {
        let ijk = IVec3::new((n * 7) % 25 - 12, (n * 11) % 25 - 12, (n * 13) % 25 - 12);
        let x = v.transform().to_world(ijk.as_dvec3());
        let w_out = (p.camera.eye() - x).normalize().as_vec3();
        let sun = Vec3::new(1.0, 2.0, 3.0) * (-optical_depth(x, x + DVec3::Z * 5.0)).exp() as f32 * hg.eval_dirs(Vec3::NEG_Z, w_out);
        let lp = DVec3::new(0.3, -2.0, 1.5);
        let to_light = (lp - x).normalize();
        let point = Vec3::splat(2.0) / (lp - x).length_squared() as f32
            * (-optical_depth(x, lp)).exp() as f32
            * hg.eval_dirs(-to_light.as_vec3(), w_out);
        let want = sun + point;
        let got = li.get(ijk);
        assert!((got - want).abs().max_element() <= 2e-3 * want.max_element().max(1e-6), "at {ijk}: {got} vs {want}");
        checked += 1;
    }
    assert!(checked >= 10);
}

#[test]
fn voxels_out_of_view_are_not_baked_and_the_rest_are_unchanged() {
    let v = block(IVec3::new(-40, -8, -8), IVec3::new(40, 8, 8), |_| 1.0);
    let full_cam = side_camera(&v);
    // A camera looking at the +x half only: narrow field of view aimed at x = 2.
    let half_cam = Camera::new(DVec3::new(2.0, -3.0, 0.0), DVec3::new(2.0, 0.0, 0.0), DVec3::Z, 40.0, 320, 180).unwrap();
    let (full, full_stats) = bake_cpu(&v, &PhotonMap::default(), &params(full_cam)).unwrap();
    let (half, half_stats) = bake_cpu(&v, &PhotonMap::default(), &params(half_cam)).unwrap();
    assert!(half_stats.baked * 2 < full_stats.baked, "{half_stats:?} vs {full_stats:?}");
    assert!(half_stats.culled_view > 0);
    // A voxel both baked for: the same value up to the direction toward each eye.
    let (full, half) = (full.li_single.unwrap(), half.li_single.unwrap());
    assert!(half.active_voxel_count() < full.active_voxel_count());
    let _ = full;
    assert!(half.is_active(IVec3::new(20, 0, 0)));
    assert!(!half.is_active(IVec3::new(-38, 0, 0)));
}

#[test]
fn photons_give_a_multiple_scattering_estimate_in_a_constant_medium() {
    // Photons spread uniformly through a constant block with known power: the estimator's
    // expectation is sum(power) / box volume * (isotropic phase 1/4pi) / sigma_s.
    let v = block(IVec3::new(-20, -20, -20), IVec3::new(20, 20, 20), |_| 2.0);
    let mut photons = PhotonMap::default();
    let mut s = 99u64;
    let mut next = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let n = 200_000;
    for _ in 0..n {
        photons.positions.push(DVec3::new(next() * 4.0 - 2.0, next() * 4.0 - 2.0, next() * 4.0 - 2.0));
        photons.power.push(Vec3::splat(1e-3));
        photons.dir.push(Vec3::Z);
    }
    let mut p = params(side_camera(&v));
    p.medium.g = 0.0;
    p.single = false;
    p.multiple = true;
    p.cache_scale = 4.0;
    let (cache, stats) = bake_cpu(&v, &photons, &p).unwrap();
    let li = cache.li_multiple.unwrap();
    let sigma_s = 3.0 * 0.8 * 2.0;
    let want = (n as f32 * 1e-3) / 64.0 / (4.0 * std::f32::consts::PI) / sigma_s;
    // One k = 32 estimate has about 1/sqrt(32) = 18% noise: average the 27 cache voxels
    // around the centre (cache voxels are 0.4 apart, wider than the balls, so nearly
    // independent): about 3.5% noise, and the k-NN estimate's k/(k-1) bias of 3%.
    let mut mean = 0.0;
    for x in -1..=1 {
        for y in -1..=1 {
            for z in -1..=1 {
                mean += li.get(IVec3::new(x, y, z)).x / 27.0;
            }
        }
    }
    assert!((mean / want - 1.0).abs() < 0.12, "{mean} vs {want}");
    assert!(stats.photons_gathered > 0);
}

#[test]
fn stress_cases_bake_finite_values() {
    let v = block(IVec3::splat(-10), IVec3::splat(10), |c| 1.0 + 0.1 * c.x as f32);
    let photons = {
        let mut m = PhotonMap::default();
        for i in 0..500 {
            let f = i as f64 / 500.0;
            m.positions.push(DVec3::new(f - 0.5, 0.3 - f * 0.6, 0.2 * (f * 20.0).sin()));
            m.power.push(Vec3::splat(1e-3));
            m.dir.push(Vec3::new(0.0, 0.6, -0.8));
        }
        m
    };
    let no_photons = PhotonMap::default();
    let inside = Camera::new(DVec3::new(0.05, 0.02, 0.01), DVec3::new(1.0, 0.3, 0.0), DVec3::Z, 90.0, 32, 32).unwrap();
    let cases: Vec<(&str, CacheParams, &PhotonMap)> = vec![
        ("camera inside", CacheParams { multiple: true, ..params(inside) }, &photons),
        ("grazing sun", CacheParams { lights: vec![Light::sun(Vec3::new(1.0, 0.0, -1e-4), Vec3::ONE).unwrap()], ..params(side_camera(&v)) }, &photons),
        ("zero photons", CacheParams { multiple: true, ..params(side_camera(&v)) }, &no_photons),
        ("extinction 1e6", CacheParams { medium: Medium { extinction: 1e6, ..Medium::default() }, multiple: true, ..params(side_camera(&v)) }, &photons),
    ];
    let gpu = nimbus_gpu::test_context();
    for (name, p, map) in cases {
        // The GPU backend (when there is an adapter) must hold up the same way.
        if let Some(ctx) = gpu {
            let (cache, stats) = bake_gpu(ctx, &v, map, &p).unwrap_or_else(|e| panic!("{name} on the GPU: {e}"));
            assert_eq!(stats.nonfinite, 0, "{name} on the GPU");
            for grid in [&cache.li_single, &cache.li_multiple].into_iter().flatten() {
                for brick in grid.bricks() {
                    assert!(brick.values.iter().all(|li| li.is_finite() && li.min_element() >= 0.0), "{name} on the GPU");
                }
            }
        }
        let (cache, stats) = bake_cpu(&v, map, &p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(stats.nonfinite, 0, "{name}");
        for grid in [&cache.li_single, &cache.li_multiple].into_iter().flatten() {
            for brick in grid.bricks() {
                assert!(brick.values.iter().all(|li| li.is_finite() && li.min_element() >= 0.0), "{name}");
            }
        }
        if name == "zero photons" {
            assert!(cache.li_multiple.is_none(), "no photons: multiple scattering skipped");
        }
        if name == "camera inside" {
            assert!(stats.culled_view > 0 && stats.baked > 0, "{name}: {stats:?}");
        }
    }
}

/// The counts describe what was baked: with Li_multiple alone on its own lattice, its voxels,
/// not the unused single-scattering lattice's; with both, the two added up.
#[test]
fn counts_cover_the_lattices_baked() {
    let v = block(IVec3::new(-6, -6, 0), IVec3::new(6, 6, 8), |_| 1.0);
    let only = CacheParams { single: false, multiple: true, multiple_scale: Some(3.0), estimator: MultipleEstimator::Paths { per_voxel: 1 }, ..params(side_camera(&v)) };
    let (cache, stats) = bake_cpu(&v, &PhotonMap::default(), &only).unwrap();
    let li = cache.li_multiple.expect("paths need no photons");
    assert_eq!(stats.baked, li.active_voxel_count() as u64);
    assert_eq!(stats.paths, stats.baked, "one path each");
    let both = CacheParams { single: true, ..only };
    let (cache, stats) = bake_cpu(&v, &PhotonMap::default(), &both).unwrap();
    let total = cache.li_single.unwrap().active_voxel_count() + cache.li_multiple.unwrap().active_voxel_count();
    assert_eq!(stats.baked, total as u64);
}

/// A sun's disc softens a shadow edge: below the edge of an opaque plate, half the disc
/// is hidden, so single scattering there is half the unshadowed value, ramping to none and
/// to all within the penumbra, tan(angle / 2) times the plate's height either side; a
/// parallel sun (angle 0) leaves a sharp step there.
#[test]
fn a_sun_with_a_disc_casts_a_soft_shadow() {
    // The plate: x < 0, z from 1 to 1.2, opaque (optical depth 2000 through it).
    let plate = block(IVec3::new(-30, -10, 10), IVec3::new(-1, 10, 12), |_| 1000.0);
    let majorant = nimbus_volume::MajorantGrid::build(&plate);
    let medium = nimbus_tracking::DensityMedium { motion: None, density: &plate, majorant: &majorant, extinction: 1.0 };
    let optics = Medium { extinction: 1.0, albedo: Vec3::ONE, g: 0.0 };
    let w_out = Vec3::X;
    let at = |light: &Light, x: f64| {
        let depths = nimbus_tracking::LightDepths::default();
        let lit = nimbus_cache::li_single(medium, &optics, std::slice::from_ref(light), &depths, DVec3::new(x, 0.0, 0.0), w_out, 0.01, 0.0);
        lit.x / (1.0 / (4.0 * std::f32::consts::PI))
    };
    let sharp = Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap();
    let soft = Light::sun_with_angle(Vec3::NEG_Z, Vec3::ONE, 20.0).unwrap();
    // The plate's face ramps over the voxel below x = 0, opaque within a hair of x = 0.
    let edge = 0.0;
    // tan(10 degrees) x 1.3 (the plate's top through its ramp): past this the whole disc
    // is (un)hidden.
    let half_width = (10.0f64).to_radians().tan() * 1.3;
    assert!(at(&sharp, edge + 0.03) > 0.99 && at(&sharp, edge - 0.03) < 0.01, "a parallel sun's shadow is not sharp");
    let middle = at(&soft, edge);
    assert!((middle - 0.5).abs() < 0.15, "under the edge half the disc is seen: {middle}");
    assert!(at(&soft, edge + 0.03) < 0.95 && at(&soft, edge - 0.03) > 0.05, "the disc's penumbra is missing");
    assert!(at(&soft, edge + half_width + 0.02) > 0.99 && at(&soft, edge - half_width - 0.02) < 0.01, "past the penumbra the shadow is whole");
    // And the penumbra falls monotonically (up to the 8 rays' stratification).
    let ramp: Vec<f32> = (0..=10).map(|i| at(&soft, edge - half_width + 2.0 * half_width * i as f64 / 10.0)).collect();
    assert!(ramp.windows(2).all(|w| w[1] >= w[0] - 0.15), "{ramp:?}");
    assert_eq!(soft.to_string().parse::<Light>().unwrap(), soft, "the angle round-trips through text");
    assert!(Light::parse_sun("angle=180").is_err() && Light::parse_sun("angle=-1").is_err());
}
