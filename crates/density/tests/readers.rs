//! PLY and delimited-text readers: round trips through files written here, and the errors.

use std::io::Write;
use std::path::PathBuf;

use glam::DVec3;
use nimbus_density::*;

fn temp_path(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nimbus-density-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn sample() -> (Vec<DVec3>, Vec<f32>) {
    let positions = (0..50)
        .map(|i| DVec3::new(i as f64 * 0.5 - 3.0, (i * 7 % 11) as f64 + 0.25, 1e6 + i as f64 * 0.125))
        .collect();
    let masses = (0..50).map(|i| 0.5 + i as f32 * 0.25).collect();
    (positions, masses)
}

/// Writes a PLY with an element before the vertices, extra vertex properties (a list among
/// them) and a face element after, in the given encoding.
fn write_test_ply(encoding: &str, positions: &[DVec3], masses: &[f32]) -> Vec<u8> {
    let mut out = Vec::new();
    writeln!(out, "ply\nformat {encoding} 1.0\ncomment written by the nimbus tests").unwrap();
    writeln!(out, "element camera 1\nproperty float view_px\nproperty uchar id").unwrap();
    writeln!(out, "element vertex {}", positions.len()).unwrap();
    writeln!(out, "property uchar flag\nproperty double x\nproperty double y\nproperty double z").unwrap();
    writeln!(out, "property list uchar int tags\nproperty float mass\nproperty short temperature").unwrap();
    writeln!(out, "element face 2\nproperty list uchar int vertex_indices\nend_header").unwrap();
    let big = encoding == "binary_big_endian";
    macro_rules! put {
        ($v:expr) => {
            if big {
                out.extend_from_slice(&$v.to_be_bytes())
            } else {
                out.extend_from_slice(&$v.to_le_bytes())
            }
        };
    }
    if encoding == "ascii" {
        writeln!(out, "1.5 7").unwrap();
        for (i, (p, m)) in positions.iter().zip(masses).enumerate() {
            writeln!(out, "{} {} {} {} 2 {} {} {} -{}", i % 3, p.x, p.y, p.z, i, i + 1, m, i).unwrap();
        }
        writeln!(out, "3 0 1 2\n3 1 2 3").unwrap();
    } else {
        put!(1.5f32);
        out.push(7u8);
        for (i, (p, m)) in positions.iter().zip(masses).enumerate() {
            out.push((i % 3) as u8);
            put!(p.x);
            put!(p.y);
            put!(p.z);
            out.push(2u8);
            put!(i as i32);
            put!(i as i32 + 1);
            put!(*m);
            put!(-(i as i16));
        }
        for f in [[0i32, 1, 2], [1, 2, 3]] {
            out.push(3u8);
            for v in f {
                put!(v);
            }
        }
    }
    out
}

#[test]
fn ply_round_trips_in_every_encoding() {
    let (positions, masses) = sample();
    for encoding in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let path = temp_path(&format!("round-{encoding}.ply"));
        std::fs::write(&path, write_test_ply(encoding, &positions, &masses)).unwrap();
        let (set, report) = read_path(&path, None).unwrap();
        assert_eq!(report.rows, 50, "{encoding}");
        assert_eq!(report.skipped_nonfinite, 0);
        assert_eq!(set.positions, positions, "{encoding}: positions (f64, 1e6 offset kept exactly)");
        assert_eq!(set.masses.as_deref(), Some(&masses[..]), "{encoding}");
    }
}

#[test]
fn ply_integer_and_float_coordinates_without_mass() {
    let mut out = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty int x\nproperty uchar y\nproperty float z\nend_header\n".to_vec();
    for (x, y, z) in [(-5i32, 200u8, 0.5f32), (7, 0, -1.25), (1 << 20, 255, 3.0)] {
        out.extend_from_slice(&x.to_le_bytes());
        out.push(y);
        out.extend_from_slice(&z.to_le_bytes());
    }
    let (set, _) = read_particles(&out[..], Format::Ply).unwrap();
    assert_eq!(set.masses, None);
    assert_eq!(set.positions[0], DVec3::new(-5.0, 200.0, 0.5));
    assert_eq!(set.positions[2], DVec3::new((1 << 20) as f64, 255.0, 3.0));
}

#[test]
fn ply_truncated_body_names_the_counts() {
    let (positions, masses) = sample();
    for encoding in ["ascii", "binary_little_endian"] {
        let mut bytes = write_test_ply(encoding, &positions[..10], &masses[..10]);
        // Promise 12 vertices, hold 10 (the face element lines then read as broken vertices
        // in ascii, so drop them too).
        let text_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let header = String::from_utf8(bytes[..text_end].to_vec()).unwrap().replace("element vertex 10", "element vertex 12");
        let mut body = bytes.split_off(text_end);
        body.truncate(if encoding == "ascii" { body.len() - "3 0 1 2\n3 1 2 3\n".len() } else { body.len() - 2 * 13 });
        let mut file = header.into_bytes();
        file.extend(body);
        let err = read_particles(&file[..], Format::Ply).unwrap_err();
        assert!(matches!(err, ReadError::Truncated { expected: 12, found: 10 }), "{encoding}: {err}");
        assert!(err.to_string().contains("12") && err.to_string().contains("10"));
    }
}

#[test]
fn ply_not_a_ply_and_missing_coordinate() {
    assert!(matches!(read_particles(&b"x,y,z\n1,2,3\n"[..], Format::Ply), Err(ReadError::NotPly(_))));
    let no_z = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
    assert!(matches!(read_particles(&no_z[..], Format::Ply), Err(ReadError::MissingCoordinate("z"))));
    let bad_type = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n";
    let err = read_particles(&bad_type[..], Format::Ply).unwrap_err();
    assert!(err.to_string().contains("line 4"), "{err}");
}

#[test]
fn csv_round_trip_and_delimiters() {
    let (positions, masses) = sample();
    for (name, sep, header) in [
        ("comma.csv", ",", "id, x, y, z, mass, name"),
        ("semicolon.csv", ";", "id;X;Y;Z;m;name"),
        ("tabs.tsv", "\t", "id\tx\ty\tz\tmass\tname"),
        ("spaces.txt", "   ", "id x y z mass name"),
    ] {
        let mut text = format!("# a comment\n{header}\n");
        for (i, (p, m)) in positions.iter().zip(&masses).enumerate() {
            let row = [i.to_string(), format!("{:?}", p.x), format!("{:?}", p.y), format!("{:?}", p.z), m.to_string(), format!("p{i}")];
            text += &format!(" {} \r\n", row.join(sep));
            if i == 10 {
                text += "\n"; // blank lines are skipped
            }
        }
        let path = temp_path(name);
        std::fs::write(&path, text).unwrap();
        let (set, report) = read_path(&path, None).unwrap();
        assert_eq!(report.rows, 50, "{name}");
        assert_eq!(set.positions, positions, "{name}");
        assert_eq!(set.masses.as_deref(), Some(&masses[..]), "{name}");
    }
}

#[test]
fn nan_rows_are_skipped_and_counted() {
    let text = "x,y,z,mass\n1,2,3,1\nnan,2,3,1\n4,inf,6,1\n7,8,9,NaN\n10,11,12,2\n";
    let (set, report) = read_particles(text.as_bytes(), Format::Csv).unwrap();
    assert_eq!(report.rows, 5);
    assert_eq!(report.skipped_nonfinite, 3);
    assert_eq!(set.positions, vec![DVec3::new(1.0, 2.0, 3.0), DVec3::new(10.0, 11.0, 12.0)]);
    assert_eq!(set.masses, Some(vec![1.0, 2.0]));
    let ply = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\nnan 0 0\n1 2 3\n";
    let (set, report) = read_particles(&ply[..], Format::Ply).unwrap();
    assert_eq!((set.len(), report.skipped_nonfinite), (1, 1));
}

/// Found by fuzzing (fuzz target `ply`): an element with no properties and a count near
/// 2^64 before the vertices. Its records take no bytes; skipping them one by one never ended.
#[test]
fn ply_element_without_properties_is_skipped_whatever_its_count() {
    for format in ["binary_little_endian", "ascii"] {
        let mut bytes = format!("ply\nformat {format} 1.0\nelement face 18446744073709551615\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n").into_bytes();
        if format == "ascii" {
            bytes.extend_from_slice(b"1 2 3\n");
        } else {
            for v in [1.0f32, 2.0, 3.0] {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        let (set, _) = read_particles(&bytes[..], Format::Ply).unwrap();
        assert_eq!(set.positions, vec![DVec3::new(1.0, 2.0, 3.0)], "{format}");
    }
}

/// Found by fuzzing (fuzz target `delimited`): a mass finite as f64 but past f32's range was
/// stored as an infinite f32 mass. It is non-finite as kept, so it is skipped and counted.
#[test]
fn masses_beyond_f32_range_are_skipped_as_non_finite() {
    let text = "x,y,z,mass\n0,0,0,1\n1,1,1,1e39\n2,2,2,-1e300\n3,3,3,3e38\n";
    let (set, report) = read_particles(text.as_bytes(), Format::Csv).unwrap();
    assert_eq!(report.skipped_nonfinite, 2);
    assert_eq!(set.masses, Some(vec![1.0, 3e38]));
    assert!(set.masses.iter().flatten().all(|m| m.is_finite()));
}

#[test]
fn csv_errors_say_where() {
    let negative = "x,y,z,mass\n1,2,3,1\n1,2,3,-0.5\n";
    let err = read_particles(negative.as_bytes(), Format::Csv).unwrap_err();
    assert!(matches!(err, ReadError::NegativeMass { .. }) && err.to_string().contains("line 3"), "{err}");

    let garbage = "x,y,z\n1,2,3\n1,two,3\n";
    let err = read_particles(garbage.as_bytes(), Format::Csv).unwrap_err();
    assert!(err.to_string().contains("line 3") && err.to_string().contains("`y`"), "{err}");

    let short = "x,y,z\n1,2\n";
    assert!(matches!(read_particles(short.as_bytes(), Format::Csv), Err(ReadError::FieldCount { .. })));

    let missing = "x,y,mass\n1,2,3\n";
    assert!(matches!(read_particles(missing.as_bytes(), Format::Csv), Err(ReadError::MissingCoordinate("z"))));

    assert!(matches!(read_particles(&b""[..], Format::Csv), Err(ReadError::NoHeader)));
    assert!(matches!(read_path(&temp_path("particles.bin"), None), Err(ReadError::UnknownFormat(_))));
    assert_eq!(Format::from_name("PLY"), Some(Format::Ply));
    assert_eq!(Format::from_name("vdb"), None);
}

#[test]
fn binary_negative_mass_names_the_vertex() {
    let mut out = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float m\nend_header\n".to_vec();
    for m in [1.0f32, -2.0] {
        for v in [0.0f32, 0.0, 0.0, m] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    let err = read_particles(&out[..], Format::Ply).unwrap_err();
    assert!(err.to_string().contains("vertex 1"), "{err}");
}

#[test]
fn write_ply_round_trips() {
    let (positions, masses) = sample();
    for set in [ParticleSet { positions: positions.clone(), masses: Some(masses.clone()), ..Default::default() }, ParticleSet::new(positions.clone())] {
        let mut bytes = Vec::new();
        write_ply(&mut bytes, &set).unwrap();
        let (back, report) = read_particles(&bytes[..], Format::Ply).unwrap();
        assert_eq!(back, set);
        assert_eq!(report.rows, 50);
    }
}
