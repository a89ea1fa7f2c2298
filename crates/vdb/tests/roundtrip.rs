//! Round trips through files and byte streams: volumes, points, metadata, transforms,
//! compression and half floats all come back as written.

mod common;

use common::*;
use glam::{DAffine3, DVec3, IVec3, Vec3};
use nimbus_vdb::{
    has_blosc, testing, Compression, GridClass, GridKind, MetaValue, PointSet, VdbFile, WriteOptions,
};
use nimbus_volume::{Transform, Volume};

fn compressions() -> Vec<Compression> {
    let mut c = vec![Compression::Zip, Compression::None];
    if has_blosc() {
        c.push(Compression::Blosc);
    }
    c
}

/// Writes `file` to a path and to bytes with `options`, and reads both back.
fn both_ways(file: &VdbFile, options: &WriteOptions, dir: &TempDir) -> [VdbFile; 2] {
    let path = dir.path("roundtrip.vdb");
    file.write(&path, options).unwrap();
    let from_path = VdbFile::open(&path).unwrap();
    let from_bytes = VdbFile::from_bytes(&file.to_bytes(options).unwrap(), "<bytes>").unwrap();
    [from_path, from_bytes]
}

#[test]
fn float_and_vec3_volumes_round_trip_exactly() {
    let dir = TempDir::new("volumes");
    for transform in [awkward_transform(), Transform::uniform(0.05, DVec3::new(1e5, 2.0, -3.0))] {
        let density = sample_float_volume(transform);
        let light = sample_vec3_volume(transform);
        let mut file = VdbFile::new();
        file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
        file.insert_volume("Li_single", &light, GridClass::Unknown).unwrap();
        for compression in compressions() {
            let options = WriteOptions { compression, half: false };
            for back in both_ways(&file, &options, &dir) {
                assert_volumes_equal(&density, &back.read_float("density").unwrap());
                assert_volumes_equal(&light, &back.read_vec3("Li_single").unwrap());
                let info = back.grid("density").unwrap();
                assert_eq!((info.kind, info.class, info.value_type.as_str()), (GridKind::Float, GridClass::FogVolume, "float"));
                assert_eq!(info.active_voxel_count, density.active_voxel_count());
                assert_eq!(info.index_bbox, density.active_index_bbox());
                let info = back.grid("Li_single").unwrap();
                assert_eq!((info.kind, info.class, info.value_type.as_str()), (GridKind::Vec3, GridClass::Unknown, "vec3s"));
            }
        }
    }
}

#[test]
fn transforms_of_every_linear_kind_round_trip_exactly() {
    let dir = TempDir::new("transforms");
    let cases = [
        ("uniform", DAffine3::from_scale(DVec3::splat(0.1)), "UniformScaleMap"),
        ("uniform_far", DAffine3::from_scale(DVec3::splat(0.1)) * DAffine3::from_translation(DVec3::splat(1e6)), "UniformScaleTranslateMap"),
        ("scale", DAffine3::from_translation(DVec3::new(1e5, -1e5, 7.5)) * DAffine3::from_scale(DVec3::new(0.1, 0.2, 0.3)), "ScaleTranslateMap"),
        ("rotated", awkward_transform().index_to_world(), "AffineMap"),
        ("sheared", DAffine3::from_cols_array(&[0.1, 0.0, 0.0, 0.05, 0.1, 0.0, 0.0, 0.02, 0.1, -3.0, 4.0, 5.0]), "AffineMap"),
    ];
    let mut file = VdbFile::new();
    for (name, m, _) in &cases {
        let mut vol = Volume::new(Transform::new(*m).unwrap(), 0.0f32);
        vol.set(IVec3::new(1, 2, 3), 1.0);
        file.insert_volume(name, &vol, GridClass::FogVolume).unwrap();
    }
    for back in both_ways(&file, &WriteOptions::default(), &dir) {
        for (name, m, map_type) in &cases {
            let info = back.grid(name).unwrap();
            assert_eq!(info.map_type, *map_type, "{name}");
            assert_eq!(info.transform.unwrap().index_to_world(), *m, "{name}");
            // World positions agree with what OpenVDB's map computes (checked by BoxSampler
            // in world space: the voxel at (1,2,3) has value 1 at its world position).
            let world = m.transform_point3(DVec3::new(1.0, 2.0, 3.0));
            let v: Vec<f32> = back.sample_box(name, &[world], nimbus_vdb::Space::World).unwrap();
            assert!((v[0] - 1.0).abs() < 1e-4, "{name}: {v:?}");
        }
    }
}

#[test]
fn points_with_attributes_round_trip() {
    let dir = TempDir::new("points");
    let mut rng = Rng::new(3);
    let n = 5000;
    let offset = DVec3::new(1e5, -2e5, 50.0);
    let positions: Vec<DVec3> =
        (0..n).map(|_| offset + DVec3::new(rng.f64() * 4.0, rng.f64() * 2.0, rng.f64() * 0.5)).collect();
    // Each point carries its own index so matches survive OpenVDB's reordering.
    let id: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let power: Vec<Vec3> = (0..n).map(|_| Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 1e-3).collect();
    let dir3: Vec<Vec3> = (0..n).map(|_| Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, 1.0).normalize()).collect();
    let points = PointSet::new(positions.clone()).with_float("id", id).with_vec3("power", power.clone()).with_vec3("dir", dir3.clone());

    let mut file = VdbFile::new();
    file.insert_points("photons", &points, None).unwrap();
    file.insert_points("empty", &PointSet::default(), Some(0.5)).unwrap();
    for back in both_ways(&file, &WriteOptions::default(), &dir) {
        let info = back.grid("photons").unwrap();
        assert_eq!((info.kind, info.point_count), (GridKind::Points, n as u64));
        let voxel = info.transform.unwrap().voxel_size().x;
        let got = back.read_points("photons").unwrap();
        assert_eq!(got.len(), n);
        assert_eq!(got.attributes.keys().collect::<Vec<_>>(), ["dir", "id", "power"]);
        let ids = got.float("id").unwrap();
        let mut seen = vec![false; n];
        for (k, &idf) in ids.iter().enumerate() {
            let i = idf as usize;
            assert!(!seen[i], "point {i} twice");
            seen[i] = true;
            let err = (got.positions[k] - positions[i]).abs().max_element();
            assert!(err <= 1e-6 * voxel, "point {i}: {} vs {} (voxel {voxel})", got.positions[k], positions[i]);
            assert_eq!(got.vec3("power").unwrap()[k], power[i]);
            assert_eq!(got.vec3("dir").unwrap()[k], dir3[i]);
        }
        let empty = back.read_points("empty").unwrap();
        assert!(empty.is_empty() && empty.attributes.is_empty());
    }
}

#[test]
fn points_reject_mismatched_attributes_and_non_finite_positions() {
    let mut file = VdbFile::new();
    let bad = PointSet::new(vec![DVec3::ZERO; 3]).with_float("mass", vec![1.0; 2]);
    let err = file.insert_points("particles", &bad, None).unwrap_err().to_string();
    assert!(err.contains("particles") && err.contains("mass") && err.contains("2 values for 3 points"), "{err}");
    let nan = PointSet::new(vec![DVec3::new(0.0, f64::NAN, 0.0)]);
    let err = file.insert_points("particles", &nan, None).unwrap_err().to_string();
    assert!(err.contains("non-finite"), "{err}");
    assert!(!file.has_grid("particles"));
}

#[test]
fn metadata_of_every_type_round_trips() {
    let dir = TempDir::new("meta");
    let values = [
        ("nimbus:string", MetaValue::from("sun dir=0,0,-1 \u{00e9}")),
        ("nimbus:empty", MetaValue::from("")),
        ("nimbus:bool", MetaValue::Bool(true)),
        ("nimbus:i32", MetaValue::I32(-123_456)),
        ("nimbus:i64", MetaValue::I64(1 << 40)),
        ("nimbus:f32", MetaValue::F32(0.1)),
        ("nimbus:f64", MetaValue::F64(0.1)),
        ("nimbus:vec3i", MetaValue::Vec3I(IVec3::new(-1, 2, 3))),
        ("nimbus:vec3f", MetaValue::Vec3F(Vec3::new(0.1, -0.2, 3e10))),
        ("nimbus:vec3d", MetaValue::Vec3D(DVec3::new(0.1, -0.2, 3e100))),
    ];
    let mut file = VdbFile::new();
    file.insert_volume("density", &sample_float_volume(Transform::uniform(1.0, DVec3::ZERO)), GridClass::FogVolume).unwrap();
    for (k, v) in &values {
        file.set_metadata(k, v.clone()).unwrap();
        file.set_grid_metadata("density", k, v.clone()).unwrap();
    }
    // Replacing changes the type too.
    file.set_metadata("nimbus:retyped", 1i32).unwrap();
    file.set_metadata("nimbus:retyped", "now a string").unwrap();
    file.set_metadata("nimbus:gone", 1.5f64).unwrap();
    file.remove_metadata("nimbus:gone").unwrap();
    for back in both_ways(&file, &WriteOptions::default(), &dir) {
        let meta = back.metadata();
        let grid_meta = back.grid("density").unwrap().metadata;
        for (k, v) in &values {
            assert_eq!(meta.get(*k), Some(v), "file {k}");
            assert_eq!(grid_meta.get(*k), Some(v), "grid {k}");
        }
        assert_eq!(meta.get("nimbus:retyped"), Some(&MetaValue::from("now a string")));
        assert!(!meta.contains_key("nimbus:gone"));
        // OpenVDB's own grid metadata is there too.
        assert_eq!(grid_meta.get("class"), Some(&MetaValue::from("fog volume")));
        assert_eq!(grid_meta.get("name"), Some(&MetaValue::from("density")));
    }
}

#[test]
fn half_output_and_grid_class_options() {
    let dir = TempDir::new("half");
    let mut vol = Volume::new(Transform::uniform(0.5, DVec3::ZERO), 0.0f32);
    vol.set(IVec3::new(0, 0, 0), 0.5); // exact in binary16
    vol.set(IVec3::new(1, 0, 0), 1.25); // exact
    vol.set(IVec3::new(2, 0, 0), 0.1); // not exact: 0.0999755859375
    let mut file = VdbFile::new();
    file.insert_volume("density", &vol, GridClass::FogVolume).unwrap();
    file.set_grid_class("density", GridClass::LevelSet).unwrap();
    // Enough active voxels that halving them shows in the size.
    file.insert_volume("bulk", &sample_float_volume(Transform::uniform(1.0, DVec3::ZERO)), GridClass::FogVolume).unwrap();
    let full_size = file.to_bytes(&WriteOptions { compression: Compression::None, half: false }).unwrap().len();
    let half = WriteOptions { compression: Compression::None, half: true };
    let half_size = file.to_bytes(&half).unwrap().len();
    assert!(half_size < full_size, "half {half_size} bytes, full {full_size} bytes");
    for back in both_ways(&file, &half, &dir) {
        let info = back.grid("density").unwrap();
        assert!(info.saved_as_half);
        assert_eq!(info.class, GridClass::LevelSet);
        let v = back.read_float("density").unwrap();
        assert_eq!(v.get(IVec3::new(0, 0, 0)), 0.5);
        assert_eq!(v.get(IVec3::new(1, 0, 0)), 1.25);
        assert_eq!(v.get(IVec3::new(2, 0, 0)), 0.099_975_586);
        // Rewriting without `half` stores float32 again.
        let again = VdbFile::from_bytes(&back.to_bytes(&WriteOptions::default()).unwrap(), "again").unwrap();
        assert!(!again.grid("density").unwrap().saved_as_half);
    }
}

#[test]
fn double_grids_read_as_float() {
    let transform = awkward_transform();
    let density = sample_float_volume(transform);
    let light = sample_vec3_volume(transform);
    let mut file = VdbFile::new();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume("light", &light, GridClass::Unknown).unwrap();
    testing::widen_grid(&mut file, "density").unwrap();
    testing::widen_grid(&mut file, "light").unwrap();
    let back = VdbFile::from_bytes(&file.to_bytes(&WriteOptions::default()).unwrap(), "<bytes>").unwrap();
    assert_eq!(back.grid("density").unwrap().value_type, "double");
    assert_eq!(back.grid("light").unwrap().value_type, "vec3d");
    assert_volumes_equal(&density, &back.read_float("density").unwrap());
    assert_volumes_equal(&light, &back.read_vec3("light").unwrap());
}

#[test]
fn grids_pass_through_and_replace_by_name() {
    let transform = Transform::uniform(1.0, DVec3::ZERO);
    let a = sample_float_volume(transform);
    let mut b = Volume::new(transform, 0.0f32);
    b.set(IVec3::ONE, 9.0);
    let mut input = VdbFile::new();
    input.insert_volume("density", &a, GridClass::FogVolume).unwrap();
    input.insert_volume("other", &b, GridClass::FogVolume).unwrap();
    testing::insert_frustum_grid(&mut input, "frustum").unwrap();

    let mut output = VdbFile::new();
    output.copy_grid_from(&input, "frustum").unwrap(); // any grid, even one nimbus cannot read
    output.copy_grid_from(&input, "density").unwrap();
    output.insert_volume("density", &b, GridClass::FogVolume).unwrap(); // replaces in place
    assert_eq!(output.grid_names(), ["frustum", "density"]);
    let back = VdbFile::from_bytes(&output.to_bytes(&WriteOptions::default()).unwrap(), "<bytes>").unwrap();
    assert_volumes_equal(&b, &back.read_float("density").unwrap());
    assert_eq!(back.grid("frustum").unwrap().map_type, "NonlinearFrustumMap");
    assert!(output.remove_grid("frustum") && !output.remove_grid("frustum"));
    assert_eq!(output.grid_names(), ["density"]);
    // The input is untouched.
    assert_volumes_equal(&a, &input.read_float("density").unwrap());
}

#[test]
fn write_replaces_atomically_and_leaves_no_temporary() {
    let dir = TempDir::new("atomic");
    let path = dir.path("out.vdb");
    std::fs::write(&path, b"old contents").unwrap();
    let mut file = VdbFile::new();
    file.insert_volume("density", &sample_float_volume(awkward_transform()), GridClass::FogVolume).unwrap();
    file.write(&path, &WriteOptions::default()).unwrap();
    assert!(VdbFile::open(&path).unwrap().has_grid("density"));
    let names: Vec<_> = std::fs::read_dir(dir.dir()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, ["out.vdb"]);
    // A failing write (no such directory) leaves nothing behind.
    let err = file.write(dir.path("missing/out.vdb"), &WriteOptions::default()).unwrap_err().to_string();
    assert!(err.contains("missing/out.vdb"), "{err}");
    // Reading a file and writing over it works (the input is fully in memory).
    let again = VdbFile::open(&path).unwrap();
    again.write(&path, &WriteOptions::default()).unwrap();
    assert!(VdbFile::open(&path).unwrap().has_grid("density"));
}

#[test]
fn blosc_matches_what_the_build_supports() {
    let file = VdbFile::new();
    let result = file.to_bytes(&WriteOptions { compression: Compression::Blosc, half: false });
    assert_eq!(result.is_ok(), has_blosc(), "{result:?}");
}

/// OpenVDB never ZIP-compresses fog volumes, yet OpenVDB 10 deflates every leaf of one to
/// fill its delayed-load metadata when the archive asks for ZIP (half a second for a
/// 4M-voxel density grid). A file of fog volumes only is therefore written as with `None`:
/// same size, same values; a file with another class of grid still gets ZIP.
#[test]
fn zip_is_not_asked_for_where_it_cannot_apply() {
    let density = sample_float_volume(awkward_transform());
    let mut fog = VdbFile::new();
    fog.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    let size = |f: &VdbFile, c| f.to_bytes(&WriteOptions { compression: c, half: false }).unwrap().len();
    assert_eq!(size(&fog, Compression::Zip), size(&fog, Compression::None));
    let back = VdbFile::from_bytes(&fog.to_bytes(&WriteOptions::default()).unwrap(), "<fog>").unwrap();
    assert_volumes_equal(&back.read_float("density").unwrap(), &density);

    let mut mixed = VdbFile::new();
    mixed.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    mixed.insert_volume("Li_single", &sample_vec3_volume(Transform::uniform(0.05, DVec3::ZERO)), GridClass::Unknown).unwrap();
    assert!(size(&mixed, Compression::Zip) < size(&mixed, Compression::None), "ZIP still applies to the vec3 grid");
}
