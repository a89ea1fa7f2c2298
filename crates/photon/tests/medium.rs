//! Photons from the medium's own emission (issue #19), with no lights at all.

use glam::{DVec3, IVec3, Vec3};
use nimbus_optics::{Emission, Medium};
use nimbus_photon::{emitted_power_emitting, trace_cpu, trace_cpu_emitting, PhotonParams};
use nimbus_tracking::EmissionField;
use nimbus_volume::{Transform, Volume};

const VOXEL: f64 = 0.1;

/// Value `d` on the index box lo..=hi.
fn block(lo: IVec3, hi: IVec3, d: f32) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(VOXEL, DVec3::ZERO), 0.0);
    for x in lo.x..=hi.x {
        for y in lo.y..=hi.y {
            for z in lo.z..=hi.z {
                v.set(IVec3::new(x, y, z), d);
            }
        }
    }
    v
}

/// A dense cube of 20^3 voxels whose lower half in z glows with e = (2, 1, 0.5): the medium
/// emits 4 pi integral e dV, the trilinear glow's integral being its voxel sum (8 x 20 x 20 x 10
/// voxels of 0.1^3 at unit value, times e). Nearly every photon meets the medium within a
/// hundredth of a voxel (optical depth 1000 a voxel), so the photons stored at their first
/// interaction (at most one each) carry albedo x that power, and lie where the glow is.
#[test]
fn photons_from_an_emitting_medium_carry_its_power_from_where_it_glows() {
    let density = block(IVec3::ZERO, IVec3::splat(19), 1.0);
    let glow_grid = block(IVec3::ZERO, IVec3::new(19, 19, 9), 1.0);
    let emission = Emission { grid: Some("glow".into()), strength: 2.0, color: Vec3::new(1.0, 0.5, 0.25), ..Emission::default() };
    let field = EmissionField { grid: Some(&glow_grid), temperature: None, params: &emission };
    let params = PhotonParams {
        medium: Medium { extinction: 10_000.0, albedo: Vec3::splat(0.5), g: 0.0 },
        lights: vec![],
        photons: 40_000,
        max_interactions: 1,
        ..PhotonParams::default()
    };
    let expected = Vec3::new(2.0, 1.0, 0.5) * (4.0 * std::f32::consts::PI * (20 * 20 * 10) as f32 * (VOXEL * VOXEL * VOXEL) as f32);
    let power = emitted_power_emitting(&density, &params, Some(&field)).unwrap().expect("the medium emits");
    assert!((power - expected).abs().max_element() < 1e-4 * expected.max_element(), "emitted {power}, expected {expected}");

    let (map, stats) = trace_cpu_emitting(&density, &params, Some(&field)).unwrap();
    assert_eq!(stats.stored, params.photons, "{stats:?}");
    // Each photon's share of the power is unbiased: the stored total is albedo x power, to
    // the noise of the per-photon weights and the photons that escape from the surface.
    let stored = map.total_power() * (stats.emitted as f32 / stats.stored as f32);
    for k in 0..3 {
        let rel = (stored[k] / (0.5 * expected[k]) - 1.0).abs();
        assert!(rel < 0.01, "channel {k}: stored {stored} against half of {expected} ({rel:.4} off)");
    }
    // Where the glow is: voxels z = 0..=9 and the trilinear ramps a voxel beyond (z index -1
    // to 10), whose integral is 10 voxels, 5.5 of them below z index 5.
    let top = map.positions.iter().map(|p| p.z).fold(f64::MIN, f64::max);
    assert!(top <= 10.0 * VOXEL + 1e-3, "a photon stored at z = {top}, above the glow");
    let lower = map.positions.iter().filter(|p| p.z < 5.0 * VOXEL).count() as f64 / map.len() as f64;
    assert!((lower - 0.55).abs() < 0.02, "{lower} of the photons below z index 5, expected 0.55");

    // Without the emission nothing lights the medium: no photons.
    let (none, stats) = trace_cpu(&density, &params).unwrap();
    assert!(none.is_empty() && stats.skipped.is_some(), "{stats:?}");
}
