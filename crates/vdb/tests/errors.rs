//! Bad input gives a clear Err naming the file or grid, never a panic or abort.

mod common;

use common::*;
use glam::{DVec3, Vec3};
use nimbus_vdb::{testing, GridClass, Space, VdbError, VdbFile, WriteOptions};
use nimbus_volume::Transform;

fn good_bytes() -> Vec<u8> {
    let mut file = VdbFile::new();
    file.insert_volume("density", &sample_float_volume(awkward_transform()), GridClass::FogVolume).unwrap();
    file.set_metadata("nimbus:seed", 7i64).unwrap();
    file.to_bytes(&WriteOptions::default()).unwrap()
}

/// Reading from bytes and from a file both fail, with messages naming the source.
fn assert_unreadable(bytes: &[u8], dir: &TempDir, file_name: &str) -> String {
    let err = VdbFile::from_bytes(bytes, "<stdin>").unwrap_err();
    assert!(matches!(err, VdbError::Read { .. }), "{err:?}");
    assert!(err.to_string().contains("<stdin>"), "{err}");
    let path = dir.path(file_name);
    std::fs::write(&path, bytes).unwrap();
    let err = VdbFile::open(&path).unwrap_err();
    assert!(matches!(err, VdbError::Read { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(file_name), "{msg}");
    msg
}

#[test]
fn missing_file() {
    let err = VdbFile::open("/nonexistent/smoke.vdb").unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, VdbError::Open { .. }), "{err:?}");
    assert!(msg.contains("/nonexistent/smoke.vdb") && msg.contains("No such file"), "{msg}");
    let dir = TempDir::new("dir-as-file");
    let err = VdbFile::open(dir.dir()).unwrap_err().to_string();
    assert!(err.contains("directory"), "{err}");
}

#[test]
fn text_and_empty_files() {
    let dir = TempDir::new("text");
    let msg = assert_unreadable(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n", &dir, "particles.ply");
    assert!(msg.contains("not a VDB file"), "{msg}");
    assert_unreadable(b"", &dir, "empty.vdb");
}

#[test]
fn truncated_files() {
    let dir = TempDir::new("truncated");
    let bytes = good_bytes();
    // Cut inside the header, the metadata, the grid descriptor and the compressed tree.
    for len in [4, 16, 40, 200, bytes.len() / 2, bytes.len() - 1] {
        assert_unreadable(&bytes[..len], &dir, &format!("cut{len}.vdb"));
    }
}

#[test]
fn corrupt_files() {
    let dir = TempDir::new("corrupt");
    let bytes = good_bytes();
    let mut rng = Rng::new(11);
    // Overwrite a run of bytes at several places after the magic number. Every read must
    // return (Ok or Err) without crashing; where OpenVDB notices, it is an Err.
    let mut errors = 0;
    for trial in 0..40 {
        let mut bad = bytes.clone();
        let start = 8 + (rng.next_u64() as usize) % (bad.len() - 40);
        for b in &mut bad[start..start + 32] {
            *b = rng.next_u64() as u8;
        }
        let path = dir.path(&format!("corrupt{trial}.vdb"));
        std::fs::write(&path, &bad).unwrap();
        match VdbFile::open(&path).and_then(|f| f.read_float("density")) {
            Ok(_) => {}
            Err(e) => {
                errors += 1;
                assert!(e.to_string().contains(&format!("corrupt{trial}.vdb")), "{e}");
            }
        }
    }
    assert!(errors > 0, "no corruption was noticed at all");
    // Garbage where the grid count and descriptors are is always an error.
    let mut bad = bytes.clone();
    bad[8..bytes.len()].iter_mut().for_each(|b| *b = 0xAB);
    assert_unreadable(&bad, &dir, "garbage.vdb");
}

#[test]
fn missing_grid_lists_what_is_there() {
    let file = VdbFile::from_bytes(&good_bytes(), "smoke.vdb").unwrap();
    let err = file.read_float("densty").unwrap_err();
    assert!(matches!(err, VdbError::MissingGrid { .. }), "{err:?}");
    assert_eq!(err.to_string(), "no grid named 'densty' in smoke.vdb (it has: density)");
    assert!(file.read_points("photons").is_err());
    let empty = VdbFile::new();
    assert!(empty.grid("density").unwrap_err().to_string().contains("no grids"));
}

#[test]
fn wrong_grid_type() {
    let file = VdbFile::from_bytes(&good_bytes(), "smoke.vdb").unwrap();
    let err = file.read_vec3("density").unwrap_err().to_string();
    assert_eq!(err, "grid 'density' in smoke.vdb: has value type float, expected a vec3 grid");
    let err = file.read_points("density").unwrap_err().to_string();
    assert!(err.contains("expected an OpenVDB points grid"), "{err}");
    let err = file.sample_box::<Vec3>("density", &[DVec3::ZERO], Space::Index).unwrap_err().to_string();
    assert!(err.contains("density"), "{err}");
}

#[test]
fn frustum_transform_is_refused() {
    let mut file = VdbFile::new();
    testing::insert_frustum_grid(&mut file, "density").unwrap();
    let back = VdbFile::from_bytes(&file.to_bytes(&WriteOptions::default()).unwrap(), "frustum.vdb").unwrap();
    let info = back.grid("density").unwrap();
    assert_eq!(info.map_type, "NonlinearFrustumMap");
    assert!(info.transform.is_none());
    let err = back.read_float("density").unwrap_err();
    assert!(matches!(err, VdbError::Grid { .. }));
    assert_eq!(
        err.to_string(),
        "grid 'density' in frustum.vdb: its transform (NonlinearFrustumMap) is not an invertible affine map; \
         nimbus needs an affine index-to-world map"
    );
}

#[test]
fn bad_names_are_errors_not_panics() {
    let mut file = VdbFile::new();
    let vol = sample_float_volume(Transform::uniform(1.0, DVec3::ZERO));
    assert!(file.insert_volume("bad\0name", &vol, GridClass::FogVolume).is_err());
    assert!(file.set_metadata("bad\0key", 1i32).is_err());
    assert!(file.set_grid_metadata("nothing", "key", 1i32).is_err());
    let err = file.write("", &WriteOptions::default()).unwrap_err().to_string();
    assert!(err.contains("cannot write"), "{err}");
}

/// Found by fuzzing (fuzz target `vdb`): active tiles are voxelized on read, so a small file
/// can stand for more voxels than memory holds. A 4096^3 active tile (70 KB of file at most)
/// is refused with the count instead of being allocated.
#[test]
fn huge_active_tiles_are_refused_before_allocating() {
    let Some(py) = common::python_with_pyopenvdb() else { return };
    let dir = TempDir::new("tiles");
    let path = dir.path("tile.vdb");
    let script = format!(
        "import pyopenvdb as v; g = v.FloatGrid(); g.name = 'density'; g.fill((0, 0, 0), (4095, 4095, 4095), 1.0, True); v.write({:?}, [g])",
        path.display().to_string()
    );
    common::run(std::process::Command::new(py).args(["-c", &script]));
    let file = VdbFile::open(&path).unwrap();
    assert_eq!(file.grid("density").unwrap().active_voxel_count, 4096u64.pow(3));
    let err = file.read_float("density").unwrap_err().to_string();
    assert!(err.contains("68719476736 active voxels") && err.contains(&nimbus_vdb::MAX_READ_VOXELS.to_string()), "{err}");
}
