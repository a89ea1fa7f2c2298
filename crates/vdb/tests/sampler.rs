//! The BoxSampler reference entry: OpenVDB's own trilinear sampling, for checking
//! nimbus_volume's sampler against.

mod common;

use common::*;
use glam::{DVec3, IVec3, Vec3};
use nimbus_vdb::{GridClass, Space, VdbFile};
use nimbus_volume::{Transform, Volume};

#[test]
fn box_sampler_reproduces_linear_fields_and_background() {
    // Trilinear interpolation is exact for a linear field inside fully active data.
    let transform = Transform::uniform(0.5, DVec3::new(10.0, 20.0, 30.0));
    let mut vol = Volume::new(transform, 0.0f32);
    let f = |p: DVec3| 1.0 + 0.5 * p.x - 0.25 * p.y + 0.125 * p.z;
    for i in -8..16 {
        for j in -8..16 {
            for k in -8..16 {
                vol.set(IVec3::new(i, j, k), f(IVec3::new(i, j, k).as_dvec3()) as f32);
            }
        }
    }
    let mut file = VdbFile::new();
    file.insert_volume("density", &vol, GridClass::FogVolume).unwrap();
    let points = [DVec3::new(0.25, 0.5, 0.75), DVec3::new(-3.3, 7.9, 1.01), DVec3::new(14.5, -7.5, 3.0)];
    let got: Vec<f32> = file.sample_box("density", &points, Space::Index).unwrap();
    for (p, v) in points.iter().zip(&got) {
        assert!((*v as f64 - f(*p)).abs() < 1e-5, "{p}: {v} vs {}", f(*p));
    }
    // World space goes through the transform.
    let world: Vec<DVec3> = points.iter().map(|p| transform.to_world(*p)).collect();
    let got_world: Vec<f32> = file.sample_box("density", &world, Space::World).unwrap();
    assert_eq!(got, got_world);
    // Far outside: the background. Half a voxel beyond the edge: half the edge value.
    let out: Vec<f32> = file.sample_box("density", &[DVec3::splat(1000.0), DVec3::new(15.5, 0.0, 0.0)], Space::Index).unwrap();
    assert_eq!(out[0], 0.0);
    assert!((out[1] as f64 - 0.5 * f(DVec3::new(15.0, 0.0, 0.0))).abs() < 1e-5);
}

#[test]
fn volume_sampler_equals_box_sampler() {
    let mut rng = Rng::new(5);
    let density = sample_float_volume(awkward_transform());
    let light = sample_vec3_volume(Transform::uniform(0.1, DVec3::ZERO));
    let mut file = VdbFile::new();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume("light", &light, GridClass::Unknown).unwrap();
    // Points in and around every brick, including the inactive voxels and the gaps.
    let points: Vec<DVec3> = density
        .bricks()
        .flat_map(|b| {
            let o = b.origin.as_dvec3();
            (0..200).map(|_| o - DVec3::splat(1.0) + DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 10.0).collect::<Vec<_>>()
        })
        .collect();
    let reference: Vec<f32> = file.sample_box("density", &points, Space::Index).unwrap();
    for (p, want) in points.iter().zip(&reference) {
        let got = density.sample_index(*p);
        assert!((got - want).abs() <= 1e-6 * want.abs().max(1.0), "{p}: volume {got} vs BoxSampler {want}");
    }
    let world: Vec<DVec3> = points.iter().map(|p| light.transform().to_world(*p)).collect();
    let reference: Vec<Vec3> = file.sample_box("light", &world, Space::World).unwrap();
    for (p, want) in world.iter().zip(&reference) {
        let got = light.sample_world(*p);
        assert!((got - *want).abs().max_element() <= 1e-4 * want.abs().max_element().max(1.0), "{p}: {got} vs {want}");
    }
}
