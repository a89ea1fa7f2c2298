//! The tabled optical depth toward a sun against shadow rays traced from each point: exact
//! when the sun falls along an index axis (every density node is then a lattice node, and the
//! depth is bilinear across the rays), bounded elsewhere by the interpolation between rays
//! half a voxel apart.

use glam::{DAffine3, DMat3, DVec3, Vec3};
use nimbus_optics::Rng;
use nimbus_tracking::{ray_optical_depths, DensityMedium, LightLattice, MediumRay, OpticalDepthVolume};
use nimbus_volume::{MajorantGrid, Transform};

mod common;
use common::blob;

/// The optical depth from `x` toward the light by composite Simpson along a shadow ray.
fn shadow_ray(medium: DensityMedium, x: DVec3, sun: Vec3, step: f64) -> f64 {
    MediumRay::new(medium, x, -sun.as_dvec3(), 0.0, f64::INFINITY).optical_depth(step)
}

#[test]
fn along_an_index_axis_every_density_node_holds_its_shadow_rays_depth() {
    let v = blob(Transform::uniform(0.05, DVec3::new(0.3, -1.2, 2.0)), 16);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 8.0 };
    for sun in [Vec3::NEG_Z, Vec3::X, Vec3::NEG_Y] {
        let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
        let mut worst = 0.0f64;
        let mut peak = 0.0f64;
        for b in v.bricks() {
            for offset in 0..512 {
                let x = v.transform().to_world((b.origin + nimbus_volume::brick_local(offset)).as_dvec3());
                let tau = shadow_ray(medium, x, sun, 0.01);
                let got = table.transmittance(x);
                // Relative to the transmittance itself: deep shadow is resolved too (within
                // f32's normal range).
                if tau < 60.0 {
                    worst = worst.max((got / (-tau).exp() - 1.0).abs());
                }
                peak = peak.max(tau);
            }
        }
        assert!(peak > 5.0, "the blob must cast a deep shadow (peak depth {peak})");
        // f32 storage and f32 lerps in the density sampler: rounding only.
        assert!(worst <= 1e-5 * peak, "sun {sun}: worst relative difference {worst} (peak depth {peak})");
    }
}

/// Along an index axis the lattice is unsheared: the trilinear density, and so the optical
/// depth, is bilinear across every 2 x 2 block of rays, and the lookup, interpolating depth
/// across them, is exact between the nodes too, where interpolating transmittance (the chord
/// of a convex exp) reads bright wherever the depth changes across a cell.
#[test]
fn along_an_index_axis_lookups_between_the_nodes_are_exact() {
    let v = blob(Transform::uniform(0.05, DVec3::new(0.3, -1.2, 2.0)), 16);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 8.0 };
    let mut rng = Rng::new(11, 0);
    let points: Vec<DVec3> = (0..4000)
        .map(|_| v.transform().to_world((DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0) * 16.0))
        .filter(|&x| v.sample_world(x) > 0.0)
        .collect();
    for sun in [Vec3::NEG_Z, Vec3::X, Vec3::NEG_Y] {
        let mut table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
        assert!(table.depth_across, "sun {sun} falls along an index axis");
        let worst = |table: &OpticalDepthVolume| {
            let mut worst = 0.0f64;
            for &x in &points {
                let tau = shadow_ray(medium, x, sun, 0.005);
                if tau < 30.0 {
                    worst = worst.max((table.transmittance(x) - (-tau).exp()).abs());
                }
            }
            worst
        };
        let depth = worst(&table);
        assert!(depth < 1e-4, "sun {sun}: worst |dT| {depth} with depth interpolated");
        // The same lattice interpolating transmittance across the rays misses by far more.
        table.depth_across = false;
        let transmittance = worst(&table);
        assert!(transmittance > 30.0 * depth.max(1e-5), "sun {sun}: transmittance across {transmittance} against depth {depth}");
    }
}

#[test]
fn oblique_suns_stay_within_the_interpolation_bound_on_sheared_anisotropic_lattices() {
    // Anisotropic, sheared voxels far from the origin (the anvil case).
    let m = DMat3::from_cols(DVec3::new(0.06, 0.0, 0.0), DVec3::new(0.01, 0.04, 0.0), DVec3::new(0.0, 0.0, 0.02));
    let transform = Transform::new(DAffine3::from_mat3_translation(m, DVec3::new(1e6, -2e6, 3e5))).unwrap();
    let v = blob(transform, 14);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 2.0 };
    let centre = transform.to_world(DVec3::ZERO);
    for sun in [Vec3::new(0.5, 0.3, -0.8).normalize(), Vec3::new(-0.7, 0.5, -0.5).normalize(), Vec3::new(0.0, 1.0, 0.05).normalize()] {
        let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
        let mut rng = Rng::new(5, 0);
        let (mut sum_t, mut sum_err, mut worst_t) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..3000 {
            let u = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0;
            let x = transform.to_world(u * 14.0);
            if v.sample_world(x) <= 0.0 {
                continue;
            }
            let want = (-shadow_ray(medium, x, sun, 0.002)).exp();
            let got = table.transmittance(x);
            sum_t += want;
            sum_err += (got - want).abs();
            worst_t = worst_t.max((got - want).abs());
        }
        assert!(!table.depth_across, "sun {sun} is oblique: a sheared lattice");
        assert!(sum_t > 10.0, "enough lit points inside the medium");
        // Interpolating between rays half a voxel apart: bounded by how much the shadow moves
        // within half a voxel. Measured mean 0.05-0.1%, worst 0.4-0.9% of unit transmittance
        // on this blob; allowed 0.5% and 3%.
        let mean = sum_err / sum_t;
        assert!(mean < 5e-3, "sun {sun} at {centre}: mean |dT| / mean T = {mean}");
        assert!(worst_t < 0.03, "sun {sun}: worst |dT| = {worst_t}");
    }
}

/// The paths' spread (TABLED_SPREAD) hands a lookup to the shadow ray sooner than the wider
/// one they had kept ([0.1, 0.15]), and single scattering's (SINGLE_SPREAD) sooner still:
/// under an oblique sun into a medium optically thick within a voxel, interpolating across
/// the sheared lattice misses where the depth changes across a cell, and a lower spread takes
/// those points to the ray.
#[test]
fn lookups_take_the_shadow_ray_from_a_lower_spread_than_the_old_paths_spread() {
    let v = blob(Transform::uniform(0.05, DVec3::new(0.3, -1.2, 2.0)), 16);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 3000.0 };
    let sun = Vec3::new(0.6, 0.3, -0.74).normalize();
    let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
    assert!(!table.depth_across);
    let mut rng = Rng::new(3, 0);
    let (mut lit, mut err_default, mut err_wide, mut err_single, mut asked_default, mut asked_wide) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0usize, 0usize);
    for _ in 0..20000 {
        let x = v.transform().to_world((DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0) * 16.0);
        if v.sample_world(x) <= 0.0 {
            continue;
        }
        let ray = (-shadow_ray(medium, x, sun, 0.005)).exp();
        let (default, wide, single) = (table.lookup(x), table.lookup_within(x, [0.1, 0.15]), table.lookup_within(x, nimbus_tracking::SINGLE_SPREAD));
        lit += ray;
        err_single += (single.resolve(|| ray) - ray).abs();
        err_default += (default.resolve(|| ray) - ray).abs();
        err_wide += (wide.resolve(|| ray) - ray).abs();
        asked_default += (default.ray_weight > 0.0) as usize;
        asked_wide += (wide.ray_weight > 0.0) as usize;
    }
    eprintln!(
        "lit {lit:.1}: mean |dT| / mean T {:.4} (paths) against {:.4} ([0.1, 0.15]), {:.4} (single); rays asked {asked_default} against {asked_wide}",
        err_default / lit,
        err_wide / lit,
        err_single / lit
    );
    assert!(lit > 20.0, "enough lit points ({lit})");
    assert!(asked_default > asked_wide, "the lower spread asks for more rays");
    assert!(err_default < 0.5 * err_wide, "the lookups must follow the rays more closely: {err_default} against {err_wide}");
    assert!(err_single <= err_default, "single scattering's lower spread follows them closer still: {err_single} against {err_default}");
}

#[test]
fn nodes_along_a_ray_hold_the_closed_form_depth_and_stop_past_the_opaque_depth() {
    let v = blob(Transform::uniform(0.1, DVec3::ZERO), 12);
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 4.0 };
    let dir_world = DVec3::new(0.3, -0.2, -0.9).normalize();
    let (origin_world, step) = (DVec3::new(-0.2, 0.4, 2.0), 0.07);
    let (o, d) = (v.transform().to_index(origin_world), v.transform().dir_to_index(dir_world));
    let mut out = vec![0.0; 60];
    ray_optical_depths(medium, o, d, step, f64::INFINITY, &mut out);
    for (k, &tau) in out.iter().enumerate() {
        let want = MediumRay::new(medium, origin_world, dir_world, 0.0, k as f64 * step).optical_depth(0.01);
        assert!((tau - want).abs() <= 1e-6 * want.max(1.0), "node {k}: {tau} against {want}");
    }
    assert!(out[59] > 2.0, "the ray crosses the blob ({})", out[59]);
    let mut capped = vec![0.0; 60];
    ray_optical_depths(medium, o, d, step, 1.0, &mut capped);
    let first_past = out.iter().position(|&t| t > 1.0).unwrap();
    assert_eq!(&capped[..first_past], &out[..first_past], "exact up to the opaque depth");
    let past = &capped[first_past..];
    assert!(past.iter().all(|&t| t > 1.0) && past.windows(2).all(|w| w[0] <= w[1]), "opaque and non-decreasing past it");
    assert!(capped[59] < out[59] && past.iter().filter(|&&t| t == capped[59]).count() > past.len() / 2, "integration stopped soon after");
}

/// Where the medium is optically thick within a voxel the shadow edge is sharper than any
/// lattice: the lookup hands those points to the shadow ray (blending across
/// TABLED_SPREAD), so the transmittance it resolves stays with the ray's where the
/// interpolation alone lights the far side; where the medium is smooth the ray is seldom asked
/// for; and the answer is continuous across cell faces.
#[test]
fn lookups_hand_shadow_edges_sharper_than_the_lattice_to_the_shadow_ray() {
    use nimbus_volume::Volume;
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0f32);
    for x in -10..=10 {
        for y in -10..=10 {
            for z in -10..=10 {
                v.set(glam::IVec3::new(x, y, z), 1.0);
            }
        }
    }
    let majorant = MajorantGrid::build(&v);
    // Optical depth 250 a voxel: a lattice node is either lit or black.
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 2500.0 };
    let sun = Vec3::new(0.3, 0.2, -1.0).normalize();
    let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
    let mut rng = Rng::new(9, 0);
    let (mut err_lookup, mut err_table, mut n, mut asked) = (0.0f64, 0.0f64, 0, 0);
    for _ in 0..4000 {
        // Points in the block's top cell, where the density falls to zero and the sun enters.
        let x = DVec3::new(rng.next_f64() * 1.6 - 0.8, rng.next_f64() * 1.6 - 0.8, 1.0 + rng.next_f64() * 0.1);
        let ray = (-shadow_ray(medium, x, sun, 0.0005)).exp();
        let look = table.lookup(x);
        err_lookup += (look.resolve(|| ray) - ray).abs();
        err_table += (look.table - ray).abs();
        asked += (look.ray_weight > 0.0) as usize;
        n += 1;
    }
    let (err_lookup, err_table) = (err_lookup / n as f64, err_table / n as f64);
    eprintln!("sharp edge: mean |dT| lookup {err_lookup:.4}, interpolation alone {err_table:.4}; {asked} of {n} asked for a ray");
    // The block's top face is lit across a cell: the chord between nodes missed it by more
    // than 0.05 on average; the density-shaped profile along the rays (along_ray) by 0.017,
    // what is left being the terminator across the rays.
    assert!(err_table > 0.01, "the interpolation alone must miss the edge here ({err_table})");
    assert!(err_lookup < 0.2 * err_table, "the lookup resolves the edge: {err_lookup} against {err_table}");

    // A smooth blob: the table answers alone.
    let b = blob(Transform::uniform(0.05, DVec3::ZERO), 16);
    let majorant = MajorantGrid::build(&b);
    let smooth = DensityMedium { motion: None, density: &b, majorant: &majorant, extinction: 2.0 };
    let table = OpticalDepthVolume::build(smooth, sun, LightLattice::default(), f64::INFINITY);
    let asked = (0..2000)
        .filter(|_| table.lookup((DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0) * 0.8).ray_weight > 0.0)
        .count();
    eprintln!("smooth blob: {asked} of 2000 asked for a ray");
    // With TABLED_SPREAD from 0.02 the blob's rim, where its density's kink crosses a cell,
    // asks for a few (56 of 2000 measured; none from 0.1, which left dense media 1-2% bright).
    assert!(asked < 100, "a smooth medium needs few shadow rays: {asked} of 2000");

    // Continuity: points a hair apart on either side of the thick block's lattice cell faces.
    let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
    let mut worst = 0.0f64;
    for _ in 0..2000 {
        let x = DVec3::new(rng.next_f64() * 1.6 - 0.8, rng.next_f64() * 1.6 - 0.8, 1.0 + rng.next_f64() * 0.1);
        let (a, b) = (table.lookup(x), table.lookup(x + DVec3::splat(1e-9)));
        worst = worst.max((a.ray_weight - b.ray_weight).abs()).max((a.table - b.table).abs());
    }
    assert!(worst < 1e-5, "the lookup jumps by {worst} over 1e-9");
}

/// A sheet six flat voxels thick (0.04 x 0.04 x 0.01) whose density reaches 60 under a
/// grazing sun: one node step along the light crosses an optical depth near 1, so the
/// transmittance falls as exp(-c s^2) where the light enters, concave, and a straight line
/// between the nodes lies below it. Between nodes the table spreads the nodes' exact depth as
/// the integral of the density along the ray ([`nimbus_tracking::along_ray`]), exact here
/// where the density is linear between nodes along the ray (measured: mean error below 1e-5
/// of the mean transmittance, the chord's 2.9%; allowed 0.2%).
#[test]
fn a_thin_dense_sheet_under_a_grazing_sun_is_resolved_between_nodes() {
    let transform = Transform::new(DAffine3::from_mat3_translation(DMat3::from_diagonal(DVec3::new(0.04, 0.04, 0.01)), DVec3::new(-2.0, 5.0, 0.5))).unwrap();
    let mut v = nimbus_volume::Volume::new(transform, 0.0f32);
    for i in -20..=20 {
        for j in -20..=20 {
            for k in -3..=3 {
                v.set(glam::IVec3::new(i, j, k), 60.0 * (1.0 - (k as f32 / 3.5).powi(2)));
            }
        }
    }
    let majorant = MajorantGrid::build(&v);
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1.0 };
    let sun = Vec3::new(0.3, 0.1, -0.2).normalize();
    let table = OpticalDepthVolume::build(medium, sun, LightLattice::default(), f64::INFINITY);
    let mut rng = Rng::new(9, 0);
    let (mut sum_t, mut sum_err, mut sum_chord) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..4000 {
        // Points over the sheet's middle, through its thickness.
        let u = DVec3::new(rng.next_f64() * 20.0 - 10.0, rng.next_f64() * 20.0 - 10.0, rng.next_f64() * 8.0 - 4.0);
        let x = transform.to_world(u);
        if v.sample_world(x) <= 0.0 {
            continue;
        }
        let want = (-shadow_ray(medium, x, sun, 0.0005)).exp();
        sum_t += want;
        sum_err += (table.transmittance(x) - want).abs();
        // The chord: the same eight nodes, interpolated trilinearly.
        sum_chord += (table.transmittance.sample_world(x) as f64 - want).abs();
    }
    let (mean, chord) = (sum_err / sum_t, sum_chord / sum_t);
    eprintln!("sheet: mean |dT| / mean T {mean:.5} (the chord's {chord:.5})");
    assert!(sum_t > 50.0, "enough lit points inside the sheet");
    assert!(mean < 2e-3 && mean < 0.5 * chord, "mean |dT| / mean T = {mean} (chord {chord})");
}
