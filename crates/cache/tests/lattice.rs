//! Li_single's lattice chosen per axis (nimbus_cache::choose_single_lattice): refined where
//! interpolating Li_single would miss, as measured against Li_single itself, and left alone
//! where it would not.

use glam::{DAffine3, DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_gpu, li_single, toward_eye, CacheParams, SINGLE_LATTICE_TOLERANCE};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_photon::PhotonMap;
use nimbus_tracking::{DensityMedium, LightDepths};
use nimbus_volume::{MajorantGrid, Transform, Volume};

mod support;

/// A sheet of flat voxels (0.04 x 0.04 x 0.01), `thickness` voxels thick, density `rho`
/// rising from its edges, away from the origin.
fn sheet(rho: f32, thickness: i32) -> Volume<f32> {
    let transform = Transform::new(DAffine3::from_scale_rotation_translation(DVec3::new(0.04, 0.04, 0.01), glam::DQuat::IDENTITY, DVec3::new(3.0, -2.0, 0.5))).unwrap();
    let mut v = Volume::new(transform, 0.0);
    for x in -20i32..=20 {
        for y in -20i32..=20 {
            for z in 0..thickness {
                let edge = (20 - x.abs().max(y.abs())).min(4) as f32 / 4.0;
                v.set(IVec3::new(x, y, z), rho * (0.25 + 0.75 * edge));
            }
        }
    }
    v
}

fn params(v: &Volume<f32>, tolerance: Option<f64>) -> CacheParams {
    let (lo, hi) = v.world_bounds().unwrap();
    let centre = 0.5 * (lo + hi);
    let medium = Medium { extinction: 1.0, albedo: Vec3::splat(0.9), g: 0.3 };
    // A grazing sun: its optical depth changes fastest across the sheet's thin axis.
    let sun = Light::sun(Vec3::new(0.8, 0.2, -0.45), Vec3::splat(3.0)).unwrap();
    let camera = Camera::new(centre + DVec3::new(-0.6, -1.6, 0.9), centre, DVec3::Z, 45.0, 96, 64).unwrap();
    CacheParams { single_tolerance: tolerance, ..support::params(medium, vec![sun], camera) }
}

/// The mean relative miss of the cache's trilinear Li_single against Li_single by shadow
/// rays, density-weighted, over points spread through the sheet's cells.
fn cache_miss(v: &Volume<f32>, p: &CacheParams, cache: &Volume<Vec3>) -> f64 {
    let majorant = MajorantGrid::build(v);
    let medium = DensityMedium { motion: None, density: v, majorant: &majorant, extinction: p.medium.extinction };
    let no_table = LightDepths::default();
    let (mut miss, mut total) = (0.0, 0.0);
    for k in 0..4000u32 {
        // A low-discrepancy spread over the inner index box.
        let f = |m: f64| (k as f64 * m).fract();
        let c = DVec3::new(-15.0 + 30.0 * f(0.7548776662), -15.0 + 30.0 * f(0.5698402910), 0.2 + (v.active_index_bbox().unwrap().1.z as f64 - 0.4) * f(0.6180339887));
        let x = v.transform().to_world(c);
        let rho = v.sample_world(x) as f64;
        let exact = li_single(medium, &p.medium, &p.lights, &no_table, x, toward_eye(&p.camera, x), p.single_step(v), 0.0).element_sum() as f64;
        let cached = cache.sample_world(x).element_sum() as f64;
        miss += rho * (cached - exact).abs();
        total += rho * exact;
    }
    miss / total
}

#[test]
fn a_flat_dense_sheet_refines_its_thin_axis_and_its_cache_comes_closer() {
    let v = sheet(30.0, 6);
    let uniform = params(&v, None);
    let refined = params(&v, Some(SINGLE_LATTICE_TOLERANCE));
    let (plain, plain_stats) = bake_cpu(&v, &PhotonMap::default(), &uniform).unwrap();
    let (fine, stats) = bake_cpu(&v, &PhotonMap::default(), &refined).unwrap();
    assert!(plain_stats.single_lattice.is_none(), "no tolerance, nothing measured");
    let lattice = stats.single_lattice.expect("the lattice was measured");
    eprintln!("chosen {:?}, estimate {:?} from {} voxels", lattice.scale, lattice.estimate, lattice.samples);
    assert!(lattice.samples > 1000);
    assert!(lattice.estimate.z > lattice.estimate.x && lattice.estimate.z > lattice.estimate.y, "the thin axis misses most: {:?}", lattice.estimate);
    assert!(lattice.scale.z < 1.0 && lattice.scale.z <= lattice.scale.x.min(lattice.scale.y), "{:?}", lattice.scale);
    assert!(lattice.remaining(1.0) <= SINGLE_LATTICE_TOLERANCE && !lattice.direct, "{lattice:?}");
    let fine_li = fine.li_single.unwrap();
    let expected = DVec3::splat(1.0) * v.transform().voxel_size() * lattice.scale;
    assert!((fine_li.transform().voxel_size() - expected).abs().max_element() < 1e-12, "the cache grid is on the chosen lattice");
    let (before, after) = (cache_miss(&v, &uniform, plain.li_single.as_ref().unwrap()), cache_miss(&v, &refined, &fine_li));
    eprintln!("mean relative miss of the cache: density lattice {before:.4}, chosen {after:.4}");
    assert!(after < 0.5 * before, "refining should at least halve the miss: {before} -> {after}");

    // The GPU bakes on the same lattice (chosen on the host from its read-back tables).
    if let Some(ctx) = nimbus_gpu::test_context() {
        let (gpu, gpu_stats) = bake_gpu(ctx, &v, &PhotonMap::default(), &refined).unwrap();
        assert_eq!(gpu_stats.single_lattice.as_ref().map(|l| l.scale), Some(lattice.scale));
        assert_eq!(gpu.li_single.as_ref().unwrap().transform(), fine_li.transform());
    }
}

/// Twice as dense, the sheet's thin axis would miss by more than the tolerance even a
/// quarter voxel apart: the lattice is left as requested and marked for the march to trace
/// single scattering's shadow rays itself (issue #47), which the cache's own values at its
/// nodes are (the same shadow rays).
#[test]
fn a_sheet_no_lattice_serves_is_left_to_the_march() {
    let v = sheet(60.0, 6);
    let (cache, stats) = bake_cpu(&v, &PhotonMap::default(), &params(&v, Some(SINGLE_LATTICE_TOLERANCE))).unwrap();
    let lattice = stats.single_lattice.expect("measured");
    eprintln!("estimate {:?}", lattice.estimate);
    assert!(lattice.direct && lattice.scale == DVec3::ONE, "{lattice:?}");
    assert!((lattice.estimate / 16.0).element_sum() > SINGLE_LATTICE_TOLERANCE, "the finest lattice would miss: {:?}", lattice.estimate);
    assert_eq!(lattice.image_error(1.0), 0.0, "the march's shadow rays leave the paths' budget nothing to spare for it");
    assert_eq!(cache.li_single.unwrap().transform(), v.transform(), "unrefined");
}

#[test]
fn an_optically_thin_medium_keeps_the_density_lattice() {
    // Optical depth 0.005 a voxel: Li_single is nearly flat between voxels.
    let v = sheet(0.5, 6);
    let (cache, stats) = bake_cpu(&v, &PhotonMap::default(), &params(&v, Some(SINGLE_LATTICE_TOLERANCE))).unwrap();
    let lattice = stats.single_lattice.expect("measured");
    assert_eq!(lattice.scale, DVec3::ONE, "estimate {:?}", lattice.estimate);
    assert!(lattice.estimate.element_sum() < 0.1 * SINGLE_LATTICE_TOLERANCE, "{:?}", lattice.estimate);
    assert_eq!(cache.li_single.unwrap().transform(), v.transform());
}

#[test]
fn a_bad_tolerance_is_a_parameter_error() {
    let v = sheet(1.0, 2);
    for t in [-0.1, f64::NAN, f64::INFINITY] {
        assert!(bake_cpu(&v, &PhotonMap::default(), &params(&v, Some(t))).is_err(), "{t}");
    }
}
