//! The medium's emission in the cache (issue #19): the paths gather emitted light the medium
//! scatters, against closed forms.

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_cpu_emitting, li_multiple_paths, CacheParams, Gather, LightLattice, MultipleEstimator, ShadowMode};
use nimbus_optics::{Camera, Emission, Medium, Rng};
use nimbus_photon::PhotonMap;
use nimbus_tracking::{DensityMedium, EmissionField, LightDepths};
use nimbus_volume::{MajorantGrid, Transform, Volume};

/// Density 1 on the voxels 0..n of edge `voxel`.
fn cube(n: i32, voxel: f64) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(voxel, DVec3::ZERO), 0.0);
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                v.set(IVec3::new(x, y, z), 1.0);
            }
        }
    }
    v
}

/// Emission `S c grid` with S = 2, c = (1, 0.5, 0.25): e = (2, 1, 0.5) where the grid is 1.
fn glow() -> Emission {
    Emission { grid: Some("glow".into()), strength: 2.0, color: Vec3::new(1.0, 0.5, 0.25), ..Emission::default() }
}

const E: Vec3 = Vec3::new(2.0, 1.0, 0.5);

fn params(camera: Camera, medium: Medium) -> CacheParams {
    CacheParams {
        environment: None,
        medium,
        lights: vec![],
        camera,
        step: 0.5,
        cache_scale: 1.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: Some(2.0),
        multiple_tolerance: None,
        single: true,
        multiple: true,
        gather: Gather::Neighbours { k: 32, max_radius: 1.0 },
        estimator: MultipleEstimator::Paths { per_voxel: 8 },
        seed: 0,
        min_transmittance: 1e-4,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    }
}

/// Deep inside a uniform emitting, scattering medium far larger than its mean free path the
/// radiance is isotropic and balances emission against absorption, L = e / (sigma_t (1 - a)),
/// so Li (the phase-weighted incident radiance) is that too, at any g. Every order of
/// scattering counts: without emission the paths give 0, with emission only at their first
/// collision (single scattering) e / sigma_t, twice counted 2 e / sigma_a.
#[test]
fn deep_inside_a_uniform_emitting_medium_li_is_emission_over_absorption() {
    let (n, voxel) = (48, 0.125);
    let density = cube(n, voxel);
    let optics = Medium { extinction: 10.0, albedo: Vec3::splat(0.5), g: 0.3 };
    let emission = glow();
    let field = EmissionField { grid: Some(&density), temperature: None, params: &emission };
    let majorant = MajorantGrid::for_tracking(&density, optics.extinction);
    let medium = DensityMedium { motion: None, density: &density, majorant: &majorant, extinction: optics.extinction };
    let centre = DVec3::splat(0.5 * (n - 1) as f64 * voxel);
    // The optical depth to the nearest face is 29: no path gets out.
    let paths = 20_000;
    let mut rng = Rng::new(3, 0);
    let li = li_multiple_paths(medium, &optics, &[], &LightDepths::default(), nimbus_tracking::PathSources { environment: None, emission: Some(&field) }, &[centre], &[], paths, nimbus_cache::PATH_MAX_DEPTH, centre + DVec3::X, &mut rng).mean;
    let expected = E / (optics.extinction * 0.5);
    for k in 0..3 {
        let rel = (li[k] / expected[k] - 1.0).abs();
        assert!(rel < 0.01, "channel {k}: Li {li} against e / sigma_a = {expected} ({rel:.4} off)");
    }
}

/// An emitting medium with no lights still bakes the paths (they have the fire to gather);
/// without emission there is nothing to bake. Li_single stays the lights' alone (none).
/// Near the middle of an optically thick emitting cube, where the camera's rays still read
/// it, the baked Li_multiple sits below the deep-interior balance e / sigma_a and well above
/// the unscattered share e / sigma_t.
#[test]
fn an_emitting_medium_without_lights_bakes_its_scattered_emission() {
    let (n, voxel) = (16, 0.125);
    let density = cube(n, voxel);
    let optics = Medium { extinction: 4.0, albedo: Vec3::splat(0.9), g: 0.0 };
    let (lo, hi) = density.world_bounds().unwrap();
    let centre = 0.5 * (lo + hi);
    let camera = Camera::new(DVec3::new(centre.x, lo.y - 4.0, centre.z), centre, DVec3::Z, 40.0, 24, 24).unwrap();
    let p = params(camera, optics);
    let (dark, stats) = bake_cpu(&density, &PhotonMap::default(), &p).unwrap();
    assert!(dark.li_multiple.is_none() && dark.li_single.is_none() && stats.paths == 0, "no lights, no emission: nothing to bake");

    let emission = glow();
    let field = EmissionField { grid: Some(&density), temperature: None, params: &emission };
    let (lit, stats) = bake_cpu_emitting(&density, &PhotonMap::default(), &p, Some(&field)).unwrap();
    assert!(lit.li_single.is_none(), "Li_single is the lights' alone");
    let li = lit.li_multiple.expect("the paths gather the emission");
    assert!(stats.paths > 0 && stats.nonfinite == 0);
    // The voxel on the camera's side of the middle, half a cube's optical depth (4) from
    // every other face: the camera reads it through optical depth 3.
    let face = DVec3::new(0.5 * (n - 1) as f64 * voxel, lo.y + 0.75, 0.5 * (n - 1) as f64 * voxel);
    let value = li.sample_world(face);
    let (balance, unscattered) = (E / (optics.extinction * 0.1), E / optics.extinction);
    for k in 0..3 {
        assert!(value[k] < balance[k] && value[k] > 2.0 * unscattered[k], "channel {k}: Li {value} against e / sigma_a {balance}, e / sigma_t {unscattered}");
    }
}
