//! What the end-to-end test files share: the tools' paths, a scratch directory, a tool run
//! as a pipe, and an EXR read independently of vdbmarch.
#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

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
