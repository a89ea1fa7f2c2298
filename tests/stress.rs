//! Stress: every tool against degenerate and extreme inputs (issue #7). Each run must end,
//! within a deadline, either with finite output or with a clear error (design.md section 7:
//! one `error: ` line, exit code 2 for bad input or usage, 1 for a failure while running) and
//! no file at the output path. A panic (exit code 101, or the `internal error` line the tools'
//! panic guard prints), a hang or a partial file fails the test.
//!
//! Scenes are tiny (a few voxels, a few hundred photons, small images) so the whole file fits
//! in CI's budget on two cores.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use glam::{DVec3, IVec3};
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};
use nimbus_volume::{Transform, Volume};

mod common;

use common::bin;

fn scratch(name: &str) -> PathBuf {
    common::scratch("stress", name)
}

/// How long any one tool run may take before it counts as a hang. Generous against a loaded
/// CI machine; every case here takes well under a second or two when healthy.
const DEADLINE: Duration = Duration::from_secs(60);

struct Run {
    label: String,
    code: Option<i32>,
    stderr: String,
    output: PathBuf,
}

impl Run {
    fn ok(&self) -> bool {
        self.code == Some(0)
    }

    /// Success, else panics with what the tool said.
    fn expect_ok(&self) -> &Run {
        assert!(self.ok(), "{} failed ({:?}): {}", self.label, self.code, self.stderr);
        assert!(self.output.exists(), "{} succeeded without writing {}", self.label, self.output.display());
        self
    }

    /// A clear error with exit code `code` whose message mentions `needle`.
    fn expect_error(&self, code: i32, needle: &str) {
        assert_eq!(self.code, Some(code), "{}: expected exit code {code}: {}", self.label, self.stderr);
        assert!(self.stderr.contains(needle), "{}: the error should mention '{needle}': {}", self.label, self.stderr);
    }
}

/// Runs `tool args... -o output` with `stdin` fed in, killing it at the deadline, and checks
/// what holds for every run: no panic, and either success or one clear error with no file
/// left behind.
fn run(tool: &str, args: &[&str], output: &Path, stdin: Option<Vec<u8>>) -> Run {
    let label = format!("{tool} {}", args.join(" "));
    // A file from an earlier case must not pass for this run's output.
    std::fs::remove_file(output).ok();
    let mut child = Command::new(bin(tool))
        .args(args)
        .arg("-o")
        .arg(output)
        .stdin(if stdin.is_some() { Stdio::piped() } else { Stdio::null() })
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("tool starts");
    let writer = stdin.map(|bytes| {
        let mut pipe = child.stdin.take().unwrap();
        // A tool that refuses its input early closes the pipe: a broken pipe here is fine.
        std::thread::spawn(move || drop(pipe.write_all(&bytes)))
    });
    // Drain stderr on a thread so a chatty tool cannot block on a full pipe.
    let mut err_pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        err_pipe.read_to_string(&mut s).ok();
        s
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > DEADLINE {
            child.kill().ok();
            child.wait().ok();
            panic!("{label}: still running after {DEADLINE:?} (a hang)");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    if let Some(w) = writer {
        w.join().unwrap();
    }
    let stderr = reader.join().unwrap();
    let code = status.code();
    assert_ne!(code, Some(101), "{label} panicked: {stderr}");
    assert!(code.is_some(), "{label} died from a signal ({status:?}): {stderr}");
    assert!(!stderr.contains("panicked") && !stderr.contains("internal error"), "{label} panicked: {stderr}");
    if code != Some(0) {
        assert!(matches!(code, Some(1 | 2)), "{label}: exit code {code:?} is neither 1 nor 2: {stderr}");
        // The error line comes last from the tools, first from clap (which adds usage after).
        assert!(stderr.lines().any(|l| l.starts_with("error: ")), "{label}: no 'error: ' line on stderr: {stderr}");
        assert!(!output.exists(), "{label} failed but left {} behind", output.display());
        let dir = output.parent().unwrap();
        let stem = output.file_name().unwrap().to_string_lossy().to_string();
        let leftovers: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().to_string())
            .filter(|n| n != &stem && n.contains(&stem))
            .collect();
        assert!(leftovers.is_empty(), "{label} failed but left temporaries behind: {leftovers:?}");
    }
    Run { label, code, stderr, output: output.to_path_buf() }
}

fn run_file(tool: &str, input: &Path, args: &[&str], output: &Path) -> Run {
    let mut all = vec![input.to_str().unwrap()];
    all.extend_from_slice(args);
    run(tool, &all, output, None)
}

/// A float density grid holding `value` on every voxel of the box [0, n)^3, `voxel` wide,
/// its index origin at world `offset`. n = 0 writes a grid with no active voxels.
fn density_vdb(path: &Path, n: i32, value: impl Fn(IVec3) -> f32, voxel: f64, offset: DVec3) {
    let mut volume = Volume::new(Transform::uniform(voxel, offset), 0.0f32);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let ijk = IVec3::new(i, j, k);
                volume.set(ijk, value(ijk));
            }
        }
    }
    let mut file = VdbFile::new();
    file.insert_volume("density", &volume, GridClass::FogVolume).unwrap();
    file.write(path, &WriteOptions::default()).unwrap();
}

/// Every float and vec3 grid in the file holds finite values; a photons grid holds finite
/// positions, powers and directions.
fn assert_vdb_finite(path: &Path) {
    let file = VdbFile::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    for info in file.grids().unwrap() {
        match info.kind {
            nimbus_vdb::GridKind::Float => {
                let v = file.read_float(&info.name).unwrap();
                assert!(v.bricks().all(|b| b.values.iter().all(|x| x.is_finite())), "{}: grid {} not finite", path.display(), info.name);
            }
            nimbus_vdb::GridKind::Vec3 => {
                let v = file.read_vec3(&info.name).unwrap();
                assert!(v.bricks().all(|b| b.values.iter().all(|x| x.is_finite())), "{}: grid {} not finite", path.display(), info.name);
                assert!(v.bricks().all(|b| b.values.iter().all(|x| x.min_element() >= 0.0)), "{}: grid {} negative", path.display(), info.name);
            }
            nimbus_vdb::GridKind::Points => {
                let p = file.read_points(&info.name).unwrap();
                assert!(p.positions.iter().all(|x| x.is_finite()), "{}: points {} not finite", path.display(), info.name);
                for attr in ["power", "dir"] {
                    if let Some(values) = p.vec3(attr) {
                        assert!(values.iter().all(|x| x.is_finite()), "{}: {attr} not finite", path.display());
                    }
                }
            }
            _ => {}
        }
    }
}

/// The EXR's RGBA pixels, read with the exr crate (independent of how vdbmarch wrote them).
fn read_rgba(path: &Path) -> (usize, usize, Vec<[f32; 4]>) {
    use exr::prelude::read_first_rgba_layer_from_file;
    let image = read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), size.height(), vec![[0.0f32; 4]; size.width() * size.height()]),
        |(width, _, pixels): &mut (usize, usize, Vec<[f32; 4]>), pos, (r, g, b, a): (f32, f32, f32, f32)| {
            pixels[pos.y() * *width + pos.x()] = [r, g, b, a];
        },
    )
    .expect("a readable EXR");
    image.layer_data.channel_data.pixels
}

/// Finite, non-negative colour and alpha in [0,1]; returns the mean of R.
fn assert_exr_finite(path: &Path) -> f64 {
    let (w, h, pixels) = read_rgba(path);
    assert_eq!(pixels.len(), w * h);
    for p in &pixels {
        assert!(p.iter().all(|v| v.is_finite()), "{}: non-finite pixel {p:?}", path.display());
        assert!(p[..3].iter().all(|v| *v >= 0.0), "{}: negative pixel {p:?}", path.display());
        assert!((0.0..=1.0 + 1e-5).contains(&p[3]), "{}: alpha out of range {p:?}", path.display());
    }
    pixels.iter().map(|p| p[0] as f64).sum::<f64>() / pixels.len() as f64
}

const FEW_PHOTONS: &[&str] = &["--photons", "300", "--max-emitted", "20000", "--seed", "3", "-q"];
const SMALL_CACHE: &[&str] = &["--width", "16", "--height", "12", "--gather-neighbours", "8", "-q"];
const SMALL_IMAGE: &[&str] = &["--width", "24", "--height", "16", "-q"];

/// density -> photons -> cache -> image with extra flags per stage; every stage must succeed
/// with finite output. Returns the image's mean red.
fn chain(dir: &Path, tag: &str, density: &Path, photon: &[&str], cache: &[&str], march: &[&str]) -> f64 {
    chain_with(dir, tag, density, &[FEW_PHOTONS, photon].concat(), cache, march)
}

/// [`chain`] with all of vdbphoton's arguments given.
fn chain_with(dir: &Path, tag: &str, density: &Path, photon: &[&str], cache: &[&str], march: &[&str]) -> f64 {
    let (p, c, e) = (dir.join(format!("{tag}-p.vdb")), dir.join(format!("{tag}-c.vdb")), dir.join(format!("{tag}.exr")));
    run_file("vdbphoton", density, photon, &p).expect_ok();
    assert_vdb_finite(&p);
    run_file("vdbcache", &p, &[SMALL_CACHE, cache].concat(), &c).expect_ok();
    assert_vdb_finite(&c);
    run_file("vdbmarch", &c, &[SMALL_IMAGE, march].concat(), &e).expect_ok();
    assert_exr_finite(&e)
}

fn uniform(v: f32) -> impl Fn(IVec3) -> f32 {
    move |_| v
}

#[test]
fn empty_grid_and_one_voxel() {
    let dir = scratch("empty");
    // A density grid with no active voxels: nothing to trace or bake, a black image.
    let empty = dir.join("empty.vdb");
    density_vdb(&empty, 0, uniform(1.0), 0.1, DVec3::ZERO);
    let (p, c, e) = (dir.join("e-p.vdb"), dir.join("e-c.vdb"), dir.join("e.exr"));
    run_file("vdbphoton", &empty, FEW_PHOTONS, &p).expect_ok();
    run_file("vdbcache", &p, SMALL_CACHE, &c).expect_ok();
    run_file("vdbmarch", &c, SMALL_IMAGE, &e).expect_ok();
    assert_eq!(assert_exr_finite(&e), 0.0);

    // One voxel, with the default camera framing it.
    let one = dir.join("one.vdb");
    density_vdb(&one, 1, uniform(5.0), 0.1, DVec3::ZERO);
    chain(&dir, "one", &one, &[], &[], &[]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn extreme_densities() {
    let dir = scratch("dens");
    // Almost vacuum: photons mostly escape, the image is (nearly) black but finite.
    let thin = dir.join("thin.vdb");
    density_vdb(&thin, 6, uniform(1e-9), 0.1, DVec3::ZERO);
    chain(&dir, "thin", &thin, &[], &[], &[]);
    // Opaque: every photon interacts at the surface, shadow rays cut off at once.
    let thick = dir.join("thick.vdb");
    density_vdb(&thick, 6, uniform(1e9), 0.1, DVec3::ZERO);
    for distance in ["simpson", "exponential"] {
        chain(&dir, &format!("thick-{distance}"), &thick, &["--distance", distance], &[], &[]);
    }
    // Delta tracking costs majorant x distance in null collisions. With brick-sized majorant
    // cells a photon crossing the empty part of the cube's brick took ~1e8 of them at density
    // 1e9 (10 photons still running after 5 minutes), so this was held to 1e4. The cells now
    // bound just the voxels each reads and the space around the cube is skipped; what remains
    // is the one-voxel ramp at the cube's faces, where the interpolated density rises from 0 to
    // 1e9 under a constant majorant of 1e9: ~1e4-1e5 null collisions per entry, a few ms per
    // photon. One batch of 1024 photons (not the 16384 of --max-emitted 20000) keeps it to
    // seconds.
    let start = Instant::now();
    let delta = ["--photons", "300", "--max-emitted", "1024", "--seed", "3", "-q", "--distance", "delta"];
    chain_with(&dir, "thick-delta", &thick, &delta, &[], &[]);
    eprintln!("delta tracking at density 1e9: chain in {:?}", start.elapsed());
    // A density jump of 18 orders of magnitude between neighbouring voxels, through Simpson
    // (named: the default is delta tracking, which takes the one-batch limit above here).
    let mixed = dir.join("mixed.vdb");
    density_vdb(&mixed, 6, |ijk| if (ijk.x + ijk.y + ijk.z) % 2 == 0 { 1e9 } else { 1e-9 }, 0.1, DVec3::ZERO);
    chain(&dir, "mixed", &mixed, &["--distance", "simpson"], &[], &[]);
    chain_with(&dir, "mixed-delta", &mixed, &delta, &[], &[]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn extreme_media() {
    let dir = scratch("media");
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 6, uniform(20.0), 0.1, DVec3::ZERO);
    // Albedo 0: nothing scatters (no photons stored, a black image with alpha).
    let black = chain(&dir, "a0", &cube, &["--albedo", "0"], &[], &[]);
    assert_eq!(black, 0.0, "albedo 0 scatters nothing");
    // Albedo 1: photons only leave by escaping or the interaction cap.
    chain(&dir, "a1", &cube, &["--albedo", "1", "--max-interactions", "200"], &[], &[]);
    for g in ["0.999", "-0.999"] {
        chain(&dir, &format!("g{g}"), &cube, &["--g", g], &[], &[]);
    }
    // |g| = 1 and albedo > 1 are outside the model: refused as usage errors.
    let out = dir.join("bad.vdb");
    run_file("vdbphoton", &cube, &["--g", "1"], &out).expect_error(2, "g");
    run_file("vdbphoton", &cube, &["--albedo", "1.5"], &out).expect_error(2, "albedo");
    run_file("vdbphoton", &cube, &["--extinction", "-1"], &out).expect_error(2, "extinction");
    run_file("vdbphoton", &cube, &["--albedo", "NaN"], &out).expect_error(2, "albedo");
    std::fs::remove_dir_all(&dir).ok();
}

/// Step sizes from 1e-4 to 100 voxels. 1e-4 is accepted (a step is a quality knob, not an
/// input error): the scene is 4^3 voxels and the images tiny so it still ends quickly.
#[test]
fn step_sizes_from_tiny_to_huge() {
    let dir = scratch("steps");
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 4, uniform(10.0), 0.1, DVec3::ZERO);
    let voxel = 0.1;
    for step in [1e-4, 0.01, 1.0, 100.0] {
        let world = format!("{}", step * voxel);
        let s = format!("{step}");
        // The tracer emits a first batch of thousands of photons whatever --photons says;
        // --max-emitted caps it for the tiny step.
        let photons: &[&str] = if step < 1e-3 { &["--photons", "50", "--max-emitted", "60"] } else { &["--photons", "300"] };
        let (p, c, e) = (dir.join(format!("{s}-p.vdb")), dir.join(format!("{s}-c.vdb")), dir.join(format!("{s}.exr")));
        run_file("vdbphoton", &cube, &[photons, &["--seed", "3", "-q", "--step", &s]].concat(), &p).expect_ok();
        assert_vdb_finite(&p);
        run_file("vdbcache", &p, &["--gather-neighbours", "8", "-q", "--step", &s, "--width", "8", "--height", "6"], &c).expect_ok();
        assert_vdb_finite(&c);
        // One sample a pixel: the default's 25 (pixels 0.6 voxels wide) times 40000 steps a
        // ray, each with its shadow rays, took 26 CPU s at the tiny step, past the hang
        // deadline on a loaded machine; the samples are not what this test stresses.
        run_file("vdbmarch", &c, &["-q", "--step", &world, "--spp", "1", "--width", "8", "--height", "6"], &e).expect_ok();
        assert_exr_finite(&e);
    }
    // Zero, negative and non-finite steps are usage errors.
    let out = dir.join("bad.vdb");
    for bad in ["0", "-1", "inf", "NaN"] {
        let flag = format!("--step={bad}");
        run_file("vdbphoton", &cube, &[&flag], &out).expect_error(2, "step");
        run_file("vdbcache", &cube, &[&flag], &out).expect_error(2, "step");
        run_file("vdbmarch", &cube, &[&flag], &dir.join("bad.exr")).expect_error(2, "step");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn cameras_rays_and_far_offsets() {
    let dir = scratch("cams");
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 8, uniform(10.0), 0.1, DVec3::ZERO);
    let p = dir.join("p.vdb");
    run_file("vdbphoton", &cube, FEW_PHOTONS, &p).expect_ok();
    // Inside the volume, far outside it, exactly axis-aligned, and grazing along a face.
    let cameras: &[(&str, &[&str])] = &[
        ("inside", &["--eye", "0.4,0.4,0.4", "--look-at", "0.7,0.4,0.4"]),
        ("far", &["--eye", "0.4,-1e6,0.4", "--look-at", "0.4,0.4,0.4", "--fov", "0.001"]),
        ("axis", &["--eye", "0.35,-5,0.35", "--look-at", "0.35,0.35,0.35", "--fov", "1"]),
        ("grazing", &["--eye", "-5,0,0.7", "--look-at", "5,0,0.7", "--fov", "0.5"]),
        ("up-parallel-free", &["--eye", "0.35,0.35,5", "--look-at", "0.35,0.35,0.35", "--up", "0,1,0"]),
    ];
    for (tag, cam) in cameras {
        let (c, e) = (dir.join(format!("{tag}-c.vdb")), dir.join(format!("{tag}.exr")));
        run_file("vdbcache", &p, &[SMALL_CACHE, cam].concat(), &c).expect_ok();
        assert_vdb_finite(&c);
        run_file("vdbmarch", &c, &[SMALL_IMAGE, cam].concat(), &e).expect_ok();
        assert_exr_finite(&e);
    }
    // A camera looking along its up vector has no image plane: a usage error.
    let e = dir.join("degenerate.exr");
    run_file("vdbmarch", &p, &["--eye", "0,0,5", "--look-at", "0,0,0", "--up", "0,0,1"], &e).expect_error(2, "camera");
    // Grazing suns: along a face of the cube, and exactly along an axis.
    for sun in ["dir=1,0,0,irradiance=1", "dir=1,0,1e-7,irradiance=1"] {
        let tag = if sun.contains("1e-7") { "graze" } else { "axis" };
        chain(&dir, &format!("sun-{tag}"), &cube, &["--sun", sun], &[], &[]);
    }

    // The same cube a million units from the origin: positions lose precision in f32.
    let far = dir.join("far.vdb");
    density_vdb(&far, 8, uniform(10.0), 0.1, DVec3::splat(1e6));
    chain(&dir, "offset", &far, &[], &[], &[]);
    std::fs::remove_dir_all(&dir).ok();
}

/// An 8K frame (7680x4320): CPU only, no AOVs, a 2^3-voxel volume seen from afar, covering
/// a few dozen pixels (the camera stood back because rays through the volume's 8^3 majorant
/// brick marched its empty part sample by sample; the cells are now one voxel); the frame is
/// mostly per-pixel set-up and EXR encoding (about 10 s on two loaded cores, 1.6 GB peak).
#[test]
fn eight_k_image() {
    let dir = scratch("8k");
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 2, uniform(10.0), 0.1, DVec3::ZERO);
    let (p, c, e) = (dir.join("p.vdb"), dir.join("c.vdb"), dir.join("8k.exr"));
    run_file("vdbphoton", &cube, FEW_PHOTONS, &p).expect_ok();
    run_file("vdbcache", &p, SMALL_CACHE, &c).expect_ok();
    let start = Instant::now();
    run_file("vdbmarch", &c, &["--width", "7680", "--height", "4320", "--device", "cpu", "--eye", "0.05,-30,0.05", "--look-at", "0.05,0.05,0.05", "-q"], &e).expect_ok();
    let took = start.elapsed();
    let (w, h, pixels) = read_rgba(&e);
    assert_eq!((w, h), (7680, 4320));
    assert!(pixels.iter().all(|p| p.iter().all(|v| v.is_finite())));
    assert!(pixels.iter().any(|p| p[3] > 0.0), "the cube shows up in the frame");
    eprintln!("8K frame in {took:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Images too large to hold are refused up front rather than failing an allocation.
#[test]
fn absurd_image_sizes() {
    let dir = scratch("sizes");
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 2, uniform(1.0), 0.1, DVec3::ZERO);
    let e = dir.join("big.exr");
    let r = run_file("vdbmarch", &cube, &["--width", "4000000000", "--height", "4000000000", "--device", "cpu"], &e);
    r.expect_error(2, "larger than");
    let r = run_file("vdbmarch", &cube, &["--width", "0", "--height", "10"], &e);
    r.expect_error(2, "size");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn non_finite_inputs() {
    let dir = scratch("nan");
    // Density with NaN or inf is bad input for every tool that reads it.
    for (tag, bad) in [("nan", f32::NAN), ("inf", f32::INFINITY), ("neg-inf", f32::NEG_INFINITY)] {
        let path = dir.join(format!("{tag}.vdb"));
        density_vdb(&path, 4, |ijk| if ijk == IVec3::new(1, 2, 3) { bad } else { 1.0 }, 0.1, DVec3::ZERO);
        for tool in ["vdbphoton", "vdbcache", "vdbmarch"] {
            let out = dir.join(if tool == "vdbmarch" { "out.exr" } else { "out.vdb" });
            run_file(tool, &path, &["-q"], &out).expect_error(2, "non-finite");
        }
    }

    // Particles with NaN and inf rows are skipped and counted; the rest make a finite grid.
    let csv = dir.join("p.csv");
    let mut text = String::from("x,y,z\n");
    for i in 0..200 {
        let t = i as f64 * 0.1;
        text += &format!("{},{},{}\n", t.sin(), t.cos(), (t * 0.7).sin());
    }
    text += "nan,0,0\n0,inf,0\n0,0,-inf\nNaN,NaN,NaN\n";
    std::fs::write(&csv, &text).unwrap();
    let d = dir.join("d.vdb");
    let r = run_file("particles2vdb", &csv, &["--resolution", "16"], &d);
    r.expect_ok();
    assert!(r.stderr.contains("skipped 4"), "{}", r.stderr);
    assert_vdb_finite(&d);
    // The same through a PLY, binary little-endian, and a mass column with NaN.
    let ply = dir.join("p.ply");
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nproperty float mass\nend_header\n".to_vec();
    for row in [[0.0f32, 0.0, 0.0, 1.0], [0.1, 0.0, 0.0, f32::NAN], [f32::INFINITY, 0.0, 0.0, 1.0], [0.0, 0.1, 0.0, 1.0], [0.0, 0.0, 0.1, 1.0]] {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(&ply, &bytes).unwrap();
    let r = run_file("particles2vdb", &ply, &["--resolution", "8"], &d);
    r.expect_ok();
    assert!(r.stderr.contains("skipped 2"), "{}", r.stderr);
    assert_vdb_finite(&d);
    // Only non-finite rows: nothing left, a clear error.
    std::fs::write(&csv, "x,y,z\nnan,0,0\ninf,inf,inf\n").unwrap();
    let out = dir.join("none.vdb");
    run_file("particles2vdb", &csv, &[], &out).expect_error(2, "particles");
    // An empty file, a header only, and garbage.
    for (tag, content) in [("empty.csv", ""), ("header.csv", "x,y,z\n"), ("junk.ply", "ply\nformat ascii 1.0\nelement vertex 99999999999999999999\nend_header\n")] {
        let path = dir.join(tag);
        std::fs::write(&path, content).unwrap();
        let r = run_file("particles2vdb", &path, &[], &out);
        assert!(!r.ok(), "{tag} made a grid");
        assert_eq!(r.code, Some(2), "{tag}: {}", r.stderr);
    }
    // Through stdin too.
    let r = run("particles2vdb", &["-", "--format", "csv"], &out, Some(b"x,y,z\n1,2\n".to_vec()));
    assert_eq!(r.code, Some(2), "{}", r.stderr);
    // Non-finite flags are refused.
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 2, uniform(1.0), 0.1, DVec3::ZERO);
    let e = dir.join("o.exr");
    run_file("vdbmarch", &cube, &["--eye", "nan,0,0"], &e).expect_error(2, "finite");
    run_file("vdbmarch", &cube, &["--background", "inf"], &e).expect_error(2, "background");
    run_file("vdbphoton", &cube, &["--sun", "dir=0,0,-1,irradiance=inf"], &out).expect_error(2, "irradiance");
    run_file("vdbphoton", &cube, &["--sun", "dir=0,0,0,irradiance=1"], &out).expect_error(2, "dir");
    std::fs::remove_dir_all(&dir).ok();
}

/// particles2vdb against degenerate particle sets: one particle, all in one spot, and a set
/// spread over 1e6 units (the auto grid would be enormous: refused by --max-voxels).
#[test]
fn degenerate_particle_sets() {
    let dir = scratch("parts");
    let out = dir.join("d.vdb");
    let csv = dir.join("p.csv");
    std::fs::write(&csv, "x,y,z\n0,0,0\n").unwrap();
    for method in ["usl", "asl2", "asl3", "knn", "ici"] {
        run_file("particles2vdb", &csv, &["--method", method, "--resolution", "8", "--h0", "0.5"], &out).expect_ok();
        assert_vdb_finite(&out);
    }
    // And ici on the GPU backend (lavapipe here).
    run_file("particles2vdb", &csv, &["--method", "ici", "--device", "gpu", "--resolution", "8", "--h0", "0.5"], &out).expect_ok();
    assert_vdb_finite(&out);
    // One particle with h0 auto: nothing to measure spacing against.
    let r = run_file("particles2vdb", &csv, &["--resolution", "8"], &out);
    if r.ok() {
        assert_vdb_finite(&out);
    }
    std::fs::write(&csv, "x,y,z\n1e6,1e6,1e6\n1e6,1e6,1e6\n1e6,1e6,1e6\n").unwrap();
    run_file("particles2vdb", &csv, &["--resolution", "8", "--h0", "0.5"], &out).expect_ok();
    assert_vdb_finite(&out);
    let r = run_file("particles2vdb", &csv, &["--resolution", "8"], &out);
    if r.ok() {
        assert_vdb_finite(&out);
    }
    std::fs::write(&csv, "x,y,z\n0,0,0\n1e6,1e6,1e6\n").unwrap();
    // Bounds given with negative coordinates (a list starting with '-') leave the far one out.
    run_file("particles2vdb", &csv, &["--bounds", "-1,-1,-1,1,1,1", "--resolution", "8", "--h0", "0.5"], &out).expect_ok();
    let r = run_file("particles2vdb", &csv, &["--voxel-size", "0.01", "--h0", "0.5"], &out);
    r.expect_error(2, "voxels");
    let mut text = String::from("x,y,z,mass\n");
    for i in 0..100 {
        text += &format!("{},{},{},{}\n", 1e6 + (i % 5) as f64 * 0.1, 1e6 + (i / 5 % 5) as f64 * 0.1, 1e6 + (i / 25) as f64 * 0.1, if i % 2 == 0 { 1e-9 } else { 1e9 });
    }
    std::fs::write(&csv, text).unwrap();
    run_file("particles2vdb", &csv, &["--resolution", "16"], &out).expect_ok();
    assert_vdb_finite(&out);
    // Negative mass: bad input or a finite grid, never a panic (checked by run).
    std::fs::write(&csv, "x,y,z,mass\n0,0,0,-1\n0.1,0,0,1\n").unwrap();
    let r = run_file("particles2vdb", &csv, &["--resolution", "8", "--h0", "0.5"], &out);
    if r.ok() {
        assert_vdb_finite(&out);
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `vdbcache --paths` straight from the density, under the extreme media and densities the
/// photon chain is held to above: each finishes with finite grids and image.
#[test]
fn path_traced_multiple_scattering_under_extremes() {
    let dir = scratch("paths");
    let paths = |tag: &str, density: &Path, cache: &[&str]| -> f64 {
        let (c, e) = (dir.join(format!("{tag}-c.vdb")), dir.join(format!("{tag}.exr")));
        let start = Instant::now();
        run_file("vdbcache", density, &[&["--width", "16", "--height", "12", "--paths", "4", "-q"], cache].concat(), &c).expect_ok();
        eprintln!("--paths, {tag}: {:?}", start.elapsed());
        assert_vdb_finite(&c);
        run_file("vdbmarch", &c, SMALL_IMAGE, &e).expect_ok();
        assert_exr_finite(&e)
    };
    let cube = dir.join("cube.vdb");
    density_vdb(&cube, 6, uniform(20.0), 0.1, DVec3::ZERO);
    assert!(paths("plain", &cube, &[]) > 0.0, "the cube is lit");
    assert_eq!(paths("a0", &cube, &["--albedo", "0"]), 0.0, "albedo 0 scatters nothing");
    // Albedo 1: the throughput never falls, so roulette never ends a path; the depth cap does.
    paths("a1", &cube, &["--albedo", "1"]);
    for g in ["0.999", "-0.999"] {
        paths(&format!("g{g}"), &cube, &["--g", g]);
    }
    let thin = dir.join("thin.vdb");
    density_vdb(&thin, 6, uniform(1e-9), 0.1, DVec3::ZERO);
    paths("thin", &thin, &[]);
    let thick = dir.join("thick.vdb");
    density_vdb(&thick, 6, uniform(1e9), 0.1, DVec3::ZERO);
    paths("thick", &thick, &[]);
    let mixed = dir.join("mixed.vdb");
    density_vdb(&mixed, 6, |ijk| if (ijk.x + ijk.y + ijk.z) % 2 == 0 { 1e9 } else { 1e-9 }, 0.1, DVec3::ZERO);
    paths("mixed", &mixed, &["--multiple-scale", "3"]);
    run_file("vdbcache", &cube, &["--paths", "4", "--multiple-scale", "0"], &dir.join("bad.vdb")).expect_error(2, "multiple-scale");
    std::fs::remove_dir_all(&dir).ok();
}

/// A tool that fails in a pipe writes nothing; the next tool says once that its input was
/// empty because of that (exit 2), and the tools after it say nothing more (issue #31).
#[test]
fn a_failure_in_a_pipe_is_reported_once_downstream() {
    let dir = scratch("pipe-failure");
    let image = dir.join("out.exr");
    let mut first = Command::new(bin("particles2vdb")).arg(dir.join("missing.ply")).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let mut second = Command::new(bin("vdbcache")).stdin(first.stdout.take().unwrap()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let third = Command::new(bin("vdbmarch")).arg("-o").arg(&image).stdin(second.stdout.take().unwrap()).stderr(Stdio::piped()).spawn().unwrap();
    let outs = [first.wait_with_output().unwrap(), second.wait_with_output().unwrap(), third.wait_with_output().unwrap()];
    let err: Vec<String> = outs.iter().map(|o| String::from_utf8_lossy(&o.stderr).into_owned()).collect();
    assert_eq!(outs.iter().map(|o| o.status.code()).collect::<Vec<_>>(), [Some(2); 3], "{err:?}");
    assert!(err[0].contains("missing.ply"), "{}", err[0]);
    assert_eq!(err[1].lines().count(), 1, "{}", err[1]);
    assert!(err[1].starts_with("error: empty input: the tool before this one in the pipe wrote nothing"), "{}", err[1]);
    assert!(err[2].is_empty(), "the third tool adds nothing: {}", err[2]);
    assert!(!image.exists());
    // An empty input from any other program is said as plainly.
    let out = Command::new(bin("vdbmarch")).arg("-").arg("-o").arg(&image).stdin(Stdio::null()).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("empty input"), "{}", String::from_utf8_lossy(&out.stderr));
    std::fs::remove_dir_all(&dir).ok();
}

/// A negative number reaches the tool's own check ("must be positive") instead of clap's tip
/// to write `-- -1` (issue #31).
#[test]
fn negative_numbers_reach_the_tools_checks() {
    let dir = scratch("negative");
    let csv = dir.join("p.csv");
    std::fs::write(&csv, "x,y,z\n0,0,0\n1,1,1\n0.5,0.2,0.7\n").unwrap();
    let out = dir.join("d.vdb");
    let r = run_file("particles2vdb", &csv, &["--voxel-size", "-1"], &out);
    r.expect_error(2, "must be positive");
    assert!(!r.stderr.contains("-- -1"), "{}", r.stderr);
    density_vdb(&dir.join("cube.vdb"), 4, uniform(1.0), 1.0, DVec3::ZERO);
    for (flag, value) in [("--fov", "-10"), ("--cache-scale", "-2"), ("--step", "-1")] {
        let r = run_file("vdbcache", &dir.join("cube.vdb"), &[flag, value], &out);
        assert_eq!(r.code, Some(2), "{flag} {value}: {}", r.stderr);
        assert!(!r.stderr.contains("-- -"), "{flag} {value}: {}", r.stderr);
    }
    std::fs::remove_dir_all(&dir).ok();
}
