//! What the end-to-end test files share: the tools' paths, a scratch directory, a tool run
//! as a pipe, and an EXR read independently of vdbmarch.
#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

/// A sun for the small scenes.
pub const SUN: &str = "dir=0.3,0.2,-1,irradiance=3";

/// nimbus-render's flags for small and quick frames, 32x24 drafts of a ball on a 16-voxel
/// grid: the shared flags once (the first 12 words), particles2vdb's through its own flag.
pub const RENDER: &[&str] = &[
    "--sun",
    SUN,
    "--eye",
    "0,-6,1",
    "--look-at",
    "0,0,0",
    "--width",
    "32",
    "--height",
    "24",
    "--quality",
    "draft",
    "--particles2vdb",
    "--resolution 16 --neighbours 16",
];

/// The built binary of one of the four tools, or of nimbus-render.
pub fn bin(name: &str) -> PathBuf {
    match name {
        "particles2vdb" => env!("CARGO_BIN_EXE_particles2vdb"),
        "vdbphoton" => env!("CARGO_BIN_EXE_vdbphoton"),
        "vdbcache" => env!("CARGO_BIN_EXE_vdbcache"),
        "vdbmarch" => env!("CARGO_BIN_EXE_vdbmarch"),
        "nimbus-render" => env!("CARGO_BIN_EXE_nimbus-render"),
        _ => unreachable!(),
    }
    .into()
}

/// The tools, as their binaries are named.
pub const TOOLS: [&str; 5] = ["particles2vdb", "vdbphoton", "vdbcache", "vdbmarch", "nimbus-render"];

/// Runs the shell command line `command` (one tool and its flags, quoted as in a shell) with
/// the built tools first on `PATH` and `NIMBUS_PARSE_ONLY` set, so the tool exits 0 once its
/// flags parsed and runs nothing (crates/cli `parse_args`): whether the tool accepts them.
pub fn parse_only(command: &str) -> Output {
    let dir = bin("vdbmarch").parent().unwrap().to_path_buf();
    let path = format!("{}:{}", dir.display(), std::env::var("PATH").unwrap_or_default());
    Command::new("sh").arg("-c").arg(command).env("PATH", &path).env("NIMBUS_PARSE_ONLY", "1").output().unwrap()
}

/// A fresh directory per test process and `name` (`suite` keeps the test files apart).
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nimbus-{suite}-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs `tool args - -o -` with `input` on its stdin, as a shell pipe does; its status is
/// the caller's to check (a tool that refuses its flags exits before reading: the broken
/// pipe is then the writer's, as in a shell, and not an error here).
pub fn pipe_output(tool: &str, args: &[&str], input: &[u8]) -> Output {
    let mut child = Command::new(bin(tool)).args(args).args(["-", "-o", "-"]).stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let input = input.to_vec();
    let writer = std::thread::spawn(move || stdin.write_all(&input));
    let out = child.wait_with_output().unwrap();
    match writer.join().unwrap() {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
        other => other.unwrap(),
    }
    out
}

/// An EXR's RGBA pixels, read with the exr crate (independent of how vdbmarch wrote them).
pub fn read_rgba(path: &Path) -> Vec<[f32; 4]> {
    use exr::prelude::read_first_rgba_layer_from_file;
    let image = read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), vec![[0.0f32; 4]; size.width() * size.height()]),
        |(width, pixels): &mut (usize, Vec<[f32; 4]>), pos, (r, g, b, a): (f32, f32, f32, f32)| {
            pixels[pos.y() * *width + pos.x()] = [r, g, b, a];
        },
    )
    .expect("a readable EXR");
    image.layer_data.channel_data.pixels.1
}

/// Runs `cmd` to its end and asserts it succeeded (its stderr in the message).
pub fn run(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(out.status.success(), "{cmd:?} failed: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// [`pipe_output`], asserting the tool succeeded.
pub fn pipe_ok(tool: &str, args: &[&str], input: &[u8]) -> Output {
    let out = pipe_output(tool, args, input);
    assert!(out.status.success(), "{tool} {args:?} failed ({}): {}", out.status, String::from_utf8_lossy(&out.stderr));
    out
}

/// The RGBA pixels of an EXR's bytes (a tool's stdout), through [`read_rgba`] from a scratch
/// file of their own.
pub fn rgba_of(exr: &[u8]) -> Vec<[f32; 4]> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static N: AtomicUsize = AtomicUsize::new(0);
    let path = scratch("exr", "images").join(format!("{}.exr", N.fetch_add(1, Ordering::Relaxed)));
    std::fs::write(&path, exr).unwrap();
    read_rgba(&path)
}

/// A text attribute of an EXR's header, read with the exr crate.
pub fn exr_attribute(exr: &[u8], key: &str) -> Option<String> {
    use exr::meta::attribute::{AttributeValue, Text};
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(exr), false).expect("an EXR header");
    match meta.headers[0].own_attributes.other.get(&Text::from(key))? {
        AttributeValue::Text(t) => Some(t.to_string()),
        _ => None,
    }
}

/// A fixed 64-bit LCG (Knuth's MMIX constants): every run of a test sees the same particles.
pub struct Lcg(u64);

impl Lcg {
    pub fn new(seed: u64) -> Lcg {
        Lcg(seed)
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in the ball of radius 1 about the origin, by rejection.
    pub fn in_unit_ball(&mut self) -> [f64; 3] {
        loop {
            let p = [self.next_f64() * 2.0 - 1.0, self.next_f64() * 2.0 - 1.0, self.next_f64() * 2.0 - 1.0];
            if p.iter().map(|v| v * v).sum::<f64>() <= 1.0 {
                return p;
            }
        }
    }
}

/// An ASCII PLY of `points` (x y z only).
pub fn write_points_ply(path: &Path, points: impl ExactSizeIterator<Item = [f64; 3]>) {
    let mut text = format!("ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n", points.len());
    for p in points {
        text += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    std::fs::write(path, text).unwrap();
}

/// A ball of `n` particles of radius 1 moved along +X by `shift`, as ASCII PLY: the same
/// particles for every shift, so a sequence of shifts is a ball in motion.
pub fn write_ball(path: &Path, n: usize, shift: f64) {
    let mut rng = Lcg::new(11);
    write_points_ply(path, (0..n).map(|_| rng.in_unit_ball()).map(|p| [p[0] + shift, p[1], p[2]]));
}

/// Whether the root-only tests may run: as root yes; otherwise they fail, unless
/// NIMBUS_SKIP_ROOT_TESTS=1 says to skip them.
pub fn root_or_skip(what: &str) -> bool {
    let uid = String::from_utf8(Command::new("id").arg("-u").output().unwrap().stdout).unwrap();
    if uid.trim() == "0" {
        return true;
    }
    if std::env::var("NIMBUS_SKIP_ROOT_TESTS").as_deref() == Ok("1") {
        eprintln!("SKIPPED {what}: not root and NIMBUS_SKIP_ROOT_TESTS=1");
        return false;
    }
    panic!("{what} needs root (make test runs as root on CI); set NIMBUS_SKIP_ROOT_TESTS=1 to skip it");
}
