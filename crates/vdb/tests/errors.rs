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

/// Peak resident set size of this process so far, in KiB (VmHWM, as getrusage's ru_maxrss).
fn peak_rss_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).expect("VmHWM in /proc/self/status");
    line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim().parse().unwrap()
}

/// Set in the child process that `corrupt_metadata_lengths_are_refused_before_allocating`
/// starts to run itself alone.
const CHILD_ENV: &str = "NIMBUS_VDB_TEST_ALONE";

/// Found by fuzzing (fuzz target `vdb`, fuzz/regressions/vdb-metadata-string-*): a file
/// metadata name length of 2.6 or 4 GiB in a 10-20 KB file made OpenVDB allocate and
/// zero-fill a string that size before the short read failed. The bridge now checks the
/// stated lengths against the data before OpenVDB parses it. Peak memory is a property of
/// the whole process, and other tests run beside this one, so it measures itself in a child
/// process running only this test.
#[test]
fn corrupt_metadata_lengths_are_refused_before_allocating() {
    const NAME: &str = "corrupt_metadata_lengths_are_refused_before_allocating";
    const MARK: &str = "peak RSS growth KiB: ";
    if std::env::var_os(CHILD_ENV).is_none() {
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([NAME, "--exact", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, "1")
            .output()
            .unwrap();
        let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        // The child ran this test (not zero tests) and measured; memory is checked first.
        let growth: u64 = stdout
            .lines()
            .find_map(|l| l.split_once(MARK).map(|(_, n)| n.trim()))
            .unwrap_or_else(|| panic!("no measurement from the child:\n{stdout}\n{stderr}"))
            .parse()
            .unwrap();
        assert!(growth < 256 * 1024, "reading grew peak RSS by {growth} KiB:\n{stdout}\n{stderr}");
        assert!(out.status.success(), "child failed:\n{stdout}\n{stderr}");
        return;
    }

    let dir = TempDir::new("regressions");
    let regressions = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/regressions");
    let before = peak_rss_kib();
    let mut messages = Vec::new();
    for (name, stated) in [("vdb-metadata-string-2.6gib", 2643056797u64), ("vdb-metadata-string-4gib", 4294967267)] {
        let bytes = std::fs::read(regressions.join(name)).unwrap();
        messages.push((assert_unreadable(&bytes, &dir, name), stated));
    }
    println!("{MARK}{}", peak_rss_kib() - before);
    for (msg, stated) in messages {
        let want = format!("file metadata item 3 of 4 name at byte 369 needs {stated} bytes but only");
        assert!(msg.contains(&want) && msg.contains("truncated or corrupt"), "{msg}");
    }
}

/// Overwrites the u32 length in front of the first `len`-prefixed occurrence of `text`.
fn patch_length(bytes: &mut [u8], text: &[u8], len: u32) {
    let mut prefixed = (text.len() as u32).to_le_bytes().to_vec();
    prefixed.extend_from_slice(text);
    let at = bytes.windows(prefixed.len()).position(|w| w == prefixed).expect("length-prefixed text");
    bytes[at..at + 4].copy_from_slice(&len.to_le_bytes());
}

/// Every stated length and offset the bridge checks before OpenVDB parses: in the file
/// metadata, the grid count, each grid's descriptor, metadata and transform type, found by
/// hopping from grid to grid with the grid offsets. Each is refused with what and where.
#[test]
fn stated_lengths_past_the_end_are_refused() {
    let dir = TempDir::new("lengths");
    let mut file = VdbFile::new();
    let vol = sample_float_volume(awkward_transform());
    file.insert_volume("density", &vol, GridClass::FogVolume).unwrap();
    file.insert_volume("temperature", &vol, GridClass::FogVolume).unwrap();
    file.set_metadata("nimbus:seed", 7i64).unwrap();
    file.set_metadata("nimbus:note", "hello").unwrap();
    let bytes = file.to_bytes(&WriteOptions::default()).unwrap();
    assert!(VdbFile::from_bytes(&bytes, "two.vdb").is_ok());
    let huge = u32::MAX - 8;

    let cases: [(&[u8], &str); 7] = [
        (b"nimbus:note", "file metadata item 1 of 2 name at byte"),
        (b"hello", "file metadata item 1 of 2 value (string) at byte"),
        (b"density", "grid 1 of 2 name at byte"),
        (b"temperature", "grid 2 of 2 name at byte"),
        (b"fog volume", "grid 1 of 2 metadata item 1 of"),
        (b"AffineMap", "grid 1 of 2 transform type at byte"),
        (b"Tree_float_5_4_3", "grid 1 of 2 type at byte"),
    ];
    for (n, (text, want)) in cases.iter().enumerate() {
        let mut bad = bytes.clone();
        patch_length(&mut bad, text, huge);
        let msg = assert_unreadable(&bad, &dir, &format!("len{n}.vdb"));
        assert!(msg.contains(want) && msg.contains(&format!("needs {huge} bytes")), "{msg}");
    }

    // OpenVDB refuses an empty metadata name; so does the check, before walking on.
    let mut bad = bytes.clone();
    patch_length(&mut bad, b"nimbus:note", 0);
    let msg = assert_unreadable(&bad, &dir, "empty-name.vdb");
    assert!(msg.contains("file metadata item 1 of 2 has an empty name"), "{msg}");

    // The grid count follows the file metadata: the int64 "nimbus:seed" value ends it.
    let mut bad = bytes.clone();
    let seed = bad.windows(20).position(|w| w == b"nimbus:seed\x05\0\0\0int64").unwrap();
    let count_at = seed + 20 + 4 + 8;
    assert_eq!(bad[count_at..count_at + 4], 2i32.to_le_bytes());
    bad[count_at..count_at + 4].copy_from_slice(&i32::MAX.to_le_bytes());
    let msg = assert_unreadable(&bad, &dir, "count.vdb");
    assert!(msg.contains("grid count 2147483647 at byte") && msg.contains("does not fit"), "{msg}");

    // The end offset of grid 1 (after its name, type and empty instance parent name).
    let mut bad = bytes.clone();
    let desc = bad.windows(20).position(|w| w == b"Tree_float_5_4_3\0\0\0\0").unwrap();
    let end_at = desc + 20 + 16;
    bad[end_at..end_at + 8].copy_from_slice(&(bytes.len() as i64 + 1).to_le_bytes());
    let msg = assert_unreadable(&bad, &dir, "offset.vdb");
    assert!(msg.contains("grid 1 of 2 offsets") && msg.contains("lie outside"), "{msg}");

    // A truncated file fails at the first length that runs past the new end.
    let msg = assert_unreadable(&bytes[..100], &dir, "cut.vdb");
    assert!(msg.contains("truncated or corrupt"), "{msg}");
}
