//! Files written by nimbus-vdb, checked by readers that share none of its code:
//! `vdb_print -l -m` (OpenVDB's own tool) and pyopenvdb (tests/pyvdb.py); and
//! third-party-style files written by pyopenvdb, read by nimbus-vdb.

mod common;

use std::collections::HashMap;
use std::process::Command;

use common::*;
use glam::{DVec3, IVec3, Vec3};
use nimbus_vdb::{Compression, GridClass, PointSet, VdbFile, WriteOptions};
use nimbus_volume::{Transform, Volume, Voxel};

/// pyvdb.py's JSON, parsed by a tiny reader (no serde in this crate): we only need
/// numbers, strings, lists and objects.
mod json {
    #[derive(Debug, Clone, PartialEq)]
    pub enum Value {
        Null,
        Bool(bool),
        Num(f64),
        Str(String),
        List(Vec<Value>),
        Obj(Vec<(String, Value)>),
    }
    impl Value {
        pub fn get(&self, key: &str) -> &Value {
            match self {
                Value::Obj(kv) => &kv.iter().find(|(k, _)| k == key).unwrap_or_else(|| panic!("no key {key}")).1,
                _ => panic!("not an object"),
            }
        }
        pub fn list(&self) -> &[Value] {
            match self {
                Value::List(v) => v,
                _ => panic!("not a list: {self:?}"),
            }
        }
        pub fn num(&self) -> f64 {
            match self {
                Value::Num(n) => *n,
                Value::Bool(b) => f64::from(u8::from(*b)),
                _ => panic!("not a number: {self:?}"),
            }
        }
        pub fn str(&self) -> &str {
            match self {
                Value::Str(s) => s,
                _ => panic!("not a string: {self:?}"),
            }
        }
        pub fn nums(&self) -> Vec<f64> {
            self.list().iter().map(Value::num).collect()
        }
    }
    pub fn parse(s: &str) -> Value {
        let mut p = Parser { s: s.as_bytes(), i: 0 };
        p.value()
    }
    struct Parser<'a> {
        s: &'a [u8],
        i: usize,
    }
    impl Parser<'_> {
        fn ws(&mut self) {
            while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
                self.i += 1;
            }
        }
        fn eat(&mut self, c: u8) -> bool {
            self.ws();
            let hit = self.s.get(self.i) == Some(&c);
            if hit {
                self.i += 1;
            }
            hit
        }
        fn value(&mut self) -> Value {
            self.ws();
            match self.s[self.i] {
                b'{' => {
                    self.i += 1;
                    let mut kv = Vec::new();
                    while !self.eat(b'}') {
                        self.eat(b',');
                        let Value::Str(k) = self.value() else { panic!("key") };
                        assert!(self.eat(b':'));
                        kv.push((k, self.value()));
                    }
                    Value::Obj(kv)
                }
                b'[' => {
                    self.i += 1;
                    let mut v = Vec::new();
                    while !self.eat(b']') {
                        self.eat(b',');
                        v.push(self.value());
                    }
                    Value::List(v)
                }
                b'"' => {
                    self.i += 1;
                    let mut out = String::new();
                    loop {
                        let c = self.s[self.i];
                        self.i += 1;
                        match c {
                            b'"' => break,
                            b'\\' => {
                                let e = self.s[self.i];
                                self.i += 1;
                                match e {
                                    b'u' => {
                                        let hex = std::str::from_utf8(&self.s[self.i..self.i + 4]).unwrap();
                                        out.push(char::from_u32(u32::from_str_radix(hex, 16).unwrap()).unwrap_or('?'));
                                        self.i += 4;
                                    }
                                    b'n' => out.push('\n'),
                                    b't' => out.push('\t'),
                                    other => out.push(other as char),
                                }
                            }
                            _ => {
                                // Re-assemble UTF-8 sequences byte by byte.
                                let start = self.i - 1;
                                let len = match c {
                                    0..=0x7f => 1,
                                    0xc0..=0xdf => 2,
                                    0xe0..=0xef => 3,
                                    _ => 4,
                                };
                                out.push_str(std::str::from_utf8(&self.s[start..start + len]).unwrap());
                                self.i = start + len;
                            }
                        }
                    }
                    Value::Str(out)
                }
                b't' => {
                    self.i += 4;
                    Value::Bool(true)
                }
                b'f' => {
                    self.i += 5;
                    Value::Bool(false)
                }
                b'n' => {
                    self.i += 4;
                    Value::Null
                }
                _ => {
                    let start = self.i;
                    while self.i < self.s.len() && b"+-0123456789.eE".contains(&self.s[self.i]) {
                        self.i += 1;
                    }
                    Value::Num(std::str::from_utf8(&self.s[start..self.i]).unwrap().parse().unwrap())
                }
            }
        }
    }
}

fn fixture_file() -> (VdbFile, Volume<f32>, Volume<Vec3>) {
    let density = sample_float_volume(awkward_transform());
    let light = sample_vec3_volume(Transform::uniform(0.05, DVec3::new(1e5, -2.0, 3.5)));
    let mut file = VdbFile::new();
    file.insert_volume("density", &density, GridClass::FogVolume).unwrap();
    file.insert_volume("Li_single", &light, GridClass::Unknown).unwrap();
    file.set_metadata("nimbus:method", "asl3").unwrap();
    file.set_metadata("nimbus:seed", 42i64).unwrap();
    file.set_metadata("nimbus:albedo", Vec3::new(0.9, 0.8, 0.7)).unwrap();
    file.set_grid_metadata("density", "nimbus:h0", 0.25f64).unwrap();
    (file, density, light)
}

/// Every active voxel of `vol` as ijk -> value.
fn active_values<T: Voxel>(vol: &Volume<T>) -> HashMap<IVec3, T> {
    let mut out = HashMap::new();
    for b in vol.bricks() {
        for (n, v) in b.values.iter().enumerate() {
            if b.is_active(n) {
                out.insert(b.origin + nimbus_volume::brick_local(n), *v);
            }
        }
    }
    out
}

fn check_python_view(grid: &json::Value, name: &str, class: &str, vtype: &str, transform: &Transform, expected: &[(IVec3, Vec<f64>)], count: u64) {
    assert_eq!(grid.get("name").str(), name);
    assert_eq!(grid.get("value_type").str(), vtype);
    assert_eq!(grid.get("class").str(), class);
    let m = transform.index_to_world();
    let axes = grid.get("index_axes").list();
    for (axis, want) in axes.iter().zip([m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis]) {
        let got = axis.nums();
        // pyopenvdb computes differences of mapped points near 1e5: compare relatively.
        for c in 0..3 {
            assert!((got[c] - want[c]).abs() < 1e-9 * (1.0 + m.translation.abs().max_element()), "{name} axis {got:?} vs {want}");
        }
    }
    assert_eq!(grid.get("translation").nums(), m.translation.to_array().to_vec(), "{name}");
    assert_eq!(grid.get("active_voxel_count").num() as u64, count, "{name}");
    let values: HashMap<IVec3, Vec<f64>> = grid
        .get("values")
        .list()
        .iter()
        .map(|e| {
            let e = e.list();
            let ijk = e[0].nums();
            let v = match &e[1] {
                json::Value::List(_) => e[1].nums(),
                x => vec![x.num()],
            };
            (IVec3::new(ijk[0] as i32, ijk[1] as i32, ijk[2] as i32), v)
        })
        .collect();
    assert_eq!(values.len() as u64, count);
    for (ijk, want) in expected {
        assert_eq!(values.get(ijk), Some(want), "{name} at {ijk}");
    }
}

#[test]
fn pyopenvdb_reads_what_we_write() {
    let Some(py) = python_with_pyopenvdb() else { return };
    let dir = TempDir::new("pyread");
    let (file, density, light) = fixture_file();
    for (i, compression) in [Compression::Zip, Compression::None].into_iter().enumerate() {
        let path = dir.path(&format!("out{i}.vdb"));
        // The stream bytes are a regular .vdb: write them like a shell redirect would.
        std::fs::write(&path, file.to_bytes(&WriteOptions { compression, half: false }).unwrap()).unwrap();
        let out = run(Command::new(py).arg(pyvdb_script()).arg("describe").arg(&path));
        let doc = json::parse(&out);
        let meta = doc.get("metadata");
        assert_eq!(meta.get("nimbus:method").str(), "asl3");
        assert_eq!(meta.get("nimbus:seed").num(), 42.0);
        assert_eq!(meta.get("nimbus:albedo").nums(), [0.9f32 as f64, 0.8f32 as f64, 0.7f32 as f64]);
        let grids = doc.get("grids").list();
        let by_name = |n: &str| grids.iter().find(|g| g.get("name").str() == n).unwrap_or_else(|| panic!("{n}"));

        let d = by_name("density");
        let expected: Vec<_> = active_values(&density).into_iter().map(|(k, v)| (k, vec![v as f64])).collect();
        check_python_view(d, "density", "fog volume", "float", density.transform(), &expected, density.active_voxel_count());
        assert_eq!(d.get("metadata").get("nimbus:h0").num(), 0.25);
        let (lo, hi) = density.active_index_bbox().unwrap();
        assert_eq!(d.get("bbox").list()[0].nums(), lo.as_dvec3().to_array().to_vec());
        assert_eq!(d.get("bbox").list()[1].nums(), hi.as_dvec3().to_array().to_vec());

        let l = by_name("Li_single");
        let expected: Vec<_> = active_values(&light).into_iter().map(|(k, v)| (k, v.as_dvec3().to_array().to_vec())).collect();
        check_python_view(l, "Li_single", "unknown", "vec3s", light.transform(), &expected, light.active_voxel_count());
        assert_eq!(l.get("background").nums(), light.background().as_dvec3().to_array().to_vec());
    }
}

/// vdb_print's report, one text block per grid name.
fn vdb_print_sections(out: &str) -> HashMap<String, String> {
    let grids: HashMap<String, String> = out
        .split("\nName: ")
        .skip(1)
        .map(|block| (block.lines().next().unwrap().trim().to_string(), block.to_string()))
        .collect();
    assert!(!grids.is_empty(), "vdb_print printed no grids:\n{out}");
    grids
}

#[test]
fn vdb_print_reads_what_we_write() {
    let Some(tool) = vdb_print() else { return };
    let dir = TempDir::new("vdbprint");
    let (mut file, density, _) = fixture_file();
    let photons = PointSet::new(vec![DVec3::new(1e5, 0.0, 0.0), DVec3::new(1e5 + 1.0, 0.5, 0.25), DVec3::new(1e5, 1.0, 2.0)])
        .with_vec3("power", vec![Vec3::ONE; 3])
        .with_vec3("dir", vec![Vec3::Z; 3]);
    file.insert_points("photons", &photons, None).unwrap();
    let path = dir.path("out.vdb");
    file.write(&path, &WriteOptions::default()).unwrap();
    let out = run(Command::new(tool).args(["-l", "-m"]).arg(&path));
    assert!(out.contains("nimbus:method: asl3"), "{out}");
    assert!(out.contains("nimbus:seed: 42"), "{out}");
    let grids = vdb_print_sections(&out);

    let d = &grids["density"];
    assert!(d.contains("Type: Tree_float_5_4_3"), "{d}");
    assert!(d.contains("class: fog volume"), "{d}");
    // OpenVDB never applies ZIP to fog volumes and level sets (Archive::setGridCompression);
    // blosc it does. Grids of other classes get ZIP.
    assert!(d.contains("file_compression: active values"), "{d}");
    assert!(d.contains(&format!("Number of active voxels:       {}", density.active_voxel_count())), "{d}");
    let (lo, hi) = density.active_index_bbox().unwrap();
    let bbox = format!("Bounding box of active voxels: [{}, {}, {}] -> [{}, {}, {}]", lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
    assert!(d.contains(&bbox), "{bbox}\n{d}");
    assert!(d.contains("nimbus:h0: 0.25"), "{d}");
    // Per-axis voxel sizes are the lengths of the index axes (rows in OpenVDB): a transposed
    // rotation would give other lengths.
    assert!(d.contains("voxel dimensions: [0.1, 0.25, 0.05]"), "{d}");
    assert!(d.contains("[1e+05, -2.5e+05, 3, 1]"), "{d}");

    let l = &grids["Li_single"];
    assert!(l.contains("Type: Tree_vec3s_5_4_3"), "{l}");
    assert!(l.contains("file_compression: zip + active values"), "{l}");
    assert!(l.contains("voxel size: 0.05"), "{l}");
    // The translation is the last row of OpenVDB's row-vector matrix.
    assert!(l.contains("[1e+05, -2, 3.5, 1]"), "{l}");

    let p = &grids["photons"];
    assert!(p.contains("Type: Tree_ptdataidx32_5_4_3"), "{p}");
}

#[test]
fn third_party_tiles_half_and_frustum_inputs() {
    let Some(py) = python_with_pyopenvdb() else { return };
    let dir = TempDir::new("pywrite");
    let path = dir.path("fixtures.vdb");
    run(Command::new(py).arg(pyvdb_script()).arg("fixtures").arg(&path));
    let file = VdbFile::open(&path).unwrap();
    assert_eq!(file.metadata().get("made_by").and_then(|m| m.as_str()), Some("pyvdb.py"));

    // Active tiles arrive voxelized as bricks.
    let tiles = file.read_float("tiles").unwrap();
    assert_eq!(tiles.active_voxel_count(), 64 * 64 * 64 + 1);
    assert_eq!(tiles.get(IVec3::new(63, 0, 31)), 0.5);
    assert_eq!(tiles.get(IVec3::new(100, 3, 4)), 2.0);
    assert_eq!(tiles.get(IVec3::new(64, 0, 0)), 0.0);
    assert_eq!(tiles.transform().voxel_size(), DVec3::splat(0.25));
    let vtiles = file.read_vec3("vtiles").unwrap();
    assert_eq!(vtiles.active_voxel_count(), 16 * 16 * 16);
    assert_eq!(vtiles.get(IVec3::new(-16, -1, -9)), Vec3::new(1.0, 2.0, 3.0));

    // Half floats read back as the halves they were stored as.
    let info = file.grid("half").unwrap();
    assert!(info.saved_as_half);
    let half = file.read_float("half").unwrap();
    assert_eq!(half.get(IVec3::new(1, 2, 3)), 0.5);
    assert_eq!(half.get(IVec3::new(4, 5, 6)), 1.25);
    assert_eq!(half.get(IVec3::new(7, 8, 9)), 0.099_975_586);

    // A frustum transform is refused, by name.
    let err = file.read_float("frustum").unwrap_err().to_string();
    assert!(err.contains("'frustum'") && err.contains("NonlinearFrustumMap") && err.contains("fixtures.vdb"), "{err}");

    // And reading through a stream gives the same.
    let streamed = VdbFile::from_bytes(&std::fs::read(&path).unwrap(), "<stdin>").unwrap();
    assert_volumes_equal(&tiles, &streamed.read_float("tiles").unwrap());
}
