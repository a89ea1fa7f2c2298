//! End-to-end: frame sequences in every tool and through nimbus-render (issue #20): the frame
//! patterns, a missing frame in the middle, reruns with --skip-existing, usage errors, the
//! chain in one command against the tools chained by hand, identical frames of a static
//! volume, and a full disk that does not cost an already written frame.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;

use common::{bin, read_rgba, root_or_skip, run, write_ball, RENDER, SUN};

fn scratch(name: &str) -> PathBuf {
    common::scratch("seq", name)
}


const P2V: &[&str] = &["--resolution", "16", "--neighbours", "16"];
const CACHE: &[&str] = &["--width", "32", "--height", "24", "--quality", "draft", "--sun", SUN, "--eye", "0,-6,1", "--look-at", "0,0,0"];
const MARCH: &[&str] = &["--quality", "draft"];

fn output(cmd: &mut Command) -> Output {
    cmd.output().expect("the tool runs")
}


fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn tool(name: &str, dir: &Path) -> Command {
    let mut c = Command::new(bin(name));
    c.current_dir(dir);
    c
}

/// A baked cache of a ball, for the march tests.
fn cache(dir: &Path, name: &str) -> PathBuf {
    let ply = dir.join(format!("{name}.ply"));
    write_ball(&ply, 1500, 0.0);
    let d = dir.join(format!("{name}.density.vdb"));
    run(tool("particles2vdb", dir).arg(&ply).args(P2V).arg("-o").arg(&d));
    let c = dir.join(format!("{name}.vdb"));
    run(tool("vdbcache", dir).arg(&d).args(CACHE).arg("-o").arg(&c));
    c
}

#[test]
fn every_tool_runs_a_sequence_and_reports_a_missing_frame() {
    let dir = scratch("tools");
    for f in [1, 2, 4] {
        write_ball(&dir.join(format!("p.{f:04}.ply")), 1200, 0.2 * f as f64);
    }
    // Frame 3 is missing: reported by number, the others done, exit 1 at the end.
    let out = output(tool("particles2vdb", &dir).args(["p.####.ply", "--frames", "1-4", "-o", "d.$F4.vdb"]).args(P2V));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("error: frame 3: cannot open"), "{err}");
    assert!(err.contains("p.0003.ply"), "{err}");
    assert!(err.lines().last().unwrap().contains("1 of 4 frames failed: 3"), "{err}");
    for f in [1, 2, 4] {
        assert!(dir.join(format!("d.{f:04}.vdb")).is_file(), "frame {f} was written");
    }
    assert!(!dir.join("d.0003.vdb").exists());
    // The per-frame progress line: frame, time, stage times.
    assert!(err.contains("particles2vdb: frame 2: ") && err.contains("estimate "), "{err}");

    run(tool("vdbphoton", &dir).args(["d.%04d.vdb", "--frame", "2", "-o", "ph.%04d.vdb", "--photons", "2000", "-q"]));
    assert!(dir.join("ph.0002.vdb").is_file());
    run(tool("vdbcache", &dir).args(["d.%04d.vdb", "--frames", "1-2,4", "-o", "c.%d.vdb"]).args(CACHE));
    let out = run(tool("vdbmarch", &dir).args(["c.%d.vdb", "--frames", "1,2,4", "-o", "i.$F.exr", "--preview", "i.##.png"]).args(MARCH));
    assert!(stderr(&out).contains("vdbmarch: frame 4: "), "{}", stderr(&out));
    for f in [1, 2, 4] {
        assert!(dir.join(format!("i.{f:02}.png")).is_file());
    }
    let (one, two) = (read_rgba(&dir.join("i.1.exr")), read_rgba(&dir.join("i.2.exr")));
    assert!(one.iter().any(|p| p[3] > 0.05), "the ball is in the picture");
    assert_ne!(one, two, "the ball moved between frames");
    // -q: nothing on stderr, not even the frame lines.
    let out = run(tool("vdbmarch", &dir).args(["c.%d.vdb", "--frame", "1", "-q", "-o", "q.####.exr"]).args(MARCH));
    assert!(out.stderr.is_empty(), "{}", stderr(&out));
    assert_eq!(std::fs::read(dir.join("q.0001.exr")).unwrap(), std::fs::read(dir.join("i.1.exr")).unwrap());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn skip_existing_finishes_only_the_missing_frames() {
    let dir = scratch("skip");
    let c = cache(&dir, "ball");
    for f in 1..=3 {
        std::fs::copy(&c, dir.join(format!("c.{f:04}.vdb"))).unwrap();
    }
    run(tool("vdbmarch", &dir).args(["c.####.vdb", "--frames", "1-3", "-o", "i.####.exr"]).args(MARCH));
    let first = std::fs::read(dir.join("i.0001.exr")).unwrap();
    std::fs::write(dir.join("i.0002.exr"), b"stands for a finished frame").unwrap();
    std::fs::remove_file(dir.join("i.0003.exr")).unwrap();
    let out = run(tool("vdbmarch", &dir).args(["c.####.vdb", "--frames", "1-3", "--skip-existing", "-o", "i.####.exr"]).args(MARCH));
    let err = stderr(&out);
    assert!(err.contains("frame 1: skipped") && err.contains("frame 2: skipped"), "{err}");
    assert_eq!(std::fs::read(dir.join("i.0002.exr")).unwrap(), b"stands for a finished frame", "an existing frame is not redone");
    assert_eq!(std::fs::read(dir.join("i.0003.exr")).unwrap(), first, "the missing frame is rendered (a static volume: as frame 1)");
    // Without a sequence too: the output exists, nothing runs.
    run(tool("vdbmarch", &dir).args(["c.0001.vdb", "--skip-existing", "-o", "i.0002.exr"]));
    assert_eq!(std::fs::read(dir.join("i.0002.exr")).unwrap(), b"stands for a finished frame");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn sequence_usage_errors_exit_2_and_write_nothing() {
    let dir = scratch("usage");
    let c = cache(&dir, "ball");
    std::fs::copy(&c, dir.join("c.0001.vdb")).unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["ball.vdb", "--frames", "1-3", "-o", "i.####.exr"], "has no frame pattern"),
        (&["c.####.vdb", "--frames", "1-3", "-o", "i.exr"], "every frame would overwrite"),
        (&["ball.vdb", "--frames", "1-3", "-o", "i.exr"], "has no frame pattern"),
        (&["c.####.vdb", "-o", "i.####.exr"], "give --frames SET or --frame N"),
        (&["c.####.vdb", "--frames", "5-1", "-o", "i.####.exr"], "backwards"),
        (&["c.####.vdb", "--frames", "1-9x0", "-o", "i.####.exr"], "step 0"),
        (&["c.####.vdb", "--frames", "1-3", "--frame", "2", "-o", "i.####.exr"], "cannot be used with"),
        (&["-", "--frames", "1", "-o", "i.####.exr"], "stdin cannot be a sequence"),
        (&["c.####.vdb", "--frames", "1", "-o", "-"], "stdout cannot be a sequence"),
        (&["c.####.vdb", "--frames", "1", "-o", "i.####.exr", "--preview", "i.png"], "'i.png' has no frame pattern"),
        (&["c.%4d.vdb", "--frames", "1", "-o", "i.%04d.exr"], "%04d"),
    ];
    for (args, want) in cases {
        let out = output(tool("vdbmarch", &dir).args(*args).stdin(std::process::Stdio::null()));
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?} should say '{want}': {err}");
        assert!(err.trim_end().lines().count() <= 6, "a short message: {err}");
    }
    let written: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().filter(|e| e.path().extension().is_some_and(|x| x == "exr" || x == "png")).collect();
    assert!(written.is_empty(), "no output after a usage error: {written:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Frame `f`'s image through the three tools by hand, through files.
fn by_hand(dir: &Path, ply: &Path, name: &str) -> Vec<u8> {
    let (d, c, e) = (dir.join(format!("{name}.d.vdb")), dir.join(format!("{name}.c.vdb")), dir.join(format!("{name}.exr")));
    run(tool("particles2vdb", dir).arg(ply).args(P2V).arg("-o").arg(&d));
    run(tool("vdbcache", dir).arg(&d).args(CACHE).arg("-o").arg(&c));
    run(tool("vdbmarch", dir).arg(&c).args(MARCH).arg("-o").arg(&e));
    std::fs::read(e).unwrap()
}


#[test]
fn nimbus_render_runs_the_chain_over_a_sequence() {
    let dir = scratch("render");
    for f in [1, 3] {
        write_ball(&dir.join(format!("p.{f:04}.ply")), 1200, 0.2 * f as f64);
    }
    let out = output(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "r/i.$F4.exr", "--frames", "1-3", "--keep-intermediates", "k"]).args(RENDER));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "frame 2 is missing: {err}");
    assert!(err.contains("error: frame 2: no such file (p.0002.ply)"), "{err}");
    assert!(err.trim_end().ends_with("1 of 3 frames failed: 2 (nimbus-render)"), "{err}");
    assert!(err.contains("nimbus-render: frame 3: ") && err.contains("vdbcache "), "{err}");
    assert!(!dir.join("r/i.0002.exr").exists());
    for name in ["i.0001.density.vdb", "i.0001.cache.vdb", "i.0003.density.vdb", "i.0003.cache.vdb"] {
        assert!(dir.join("k").join(name).is_file(), "kept {name}");
    }
    // The same image as the tools chained by hand with each flag where it belongs.
    let hand = by_hand(&dir, &dir.join("p.0001.ply"), "hand");
    assert_eq!(std::fs::read(dir.join("r/i.0001.exr")).unwrap(), hand, "nimbus-render passes the shared flags on as a user would");

    // Piped (no --keep-intermediates): the same image, and no intermediate file anywhere.
    run(tool("nimbus-render", &dir).args(["p.####.ply", "-o", "piped/i.####.exr", "--frame", "1", "-q"]).args(RENDER));
    assert_eq!(std::fs::read(dir.join("piped/i.0001.exr")).unwrap(), hand);
    let files: Vec<_> = std::fs::read_dir(dir.join("piped")).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(files, ["i.0001.exr"]);

    // A density VDB skips particles2vdb.
    run(tool("nimbus-render", &dir).args(["k/i.####.density.vdb", "-o", "v/i.####.exr", "--frame", "3"]).args(&RENDER[..12]));
    assert_eq!(std::fs::read(dir.join("v/i.0003.exr")).unwrap(), std::fs::read(dir.join("r/i.0003.exr")).unwrap());

    // The photon chain.
    let out = run(tool("nimbus-render", &dir)
        .args(["p.####.ply", "-o", "ph/i.####.exr", "--frame", "1", "--photons", "--keep-intermediates", "ph", "--vdbphoton", "--photons 3000", "--vdbcache", "--gather-neighbours 16"])
        .args(RENDER));
    assert!(dir.join("ph/i.0001.photons.vdb").is_file(), "{}", stderr(&out));
    assert!(read_rgba(&dir.join("ph/i.0001.exr")).iter().any(|p| p[3] > 0.05));

    // A rerun with --skip-existing does only what is missing.
    write_ball(&dir.join("p.0002.ply"), 1200, 0.4);
    let before = std::fs::metadata(dir.join("r/i.0001.exr")).unwrap().modified().unwrap();
    let out = run(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "r/i.$F4.exr", "--frames", "1-3", "--skip-existing"]).args(RENDER));
    assert!(stderr(&out).contains("frame 3: skipped"), "{}", stderr(&out));
    assert!(dir.join("r/i.0002.exr").is_file());
    assert_eq!(std::fs::metadata(dir.join("r/i.0001.exr")).unwrap().modified().unwrap(), before);
    std::fs::remove_dir_all(&dir).ok();
}

/// `--preview PATTERN` (expanded as the output) and a pattern passed through `--vdbmarch`
/// (expanded per frame too) both write a PNG per frame (issue #31).
#[test]
fn nimbus_render_writes_previews() {
    let dir = scratch("preview");
    for f in [1, 2] {
        write_ball(&dir.join(format!("p.{f:04}.ply")), 1200, 0.2 * f as f64);
    }
    run(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "a/i.$F4.exr", "--preview", "a/p.$F4.png", "--frames", "1-2", "-q"]).args(RENDER));
    run(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "b/i.$F4.exr", "--frames", "1-2", "-q", "--vdbmarch", "--preview b/q.$F4.png"]).args(RENDER));
    for f in [1, 2] {
        for png in [format!("a/p.{f:04}.png"), format!("b/q.{f:04}.png")] {
            let bytes = std::fs::read(dir.join(&png)).unwrap_or_else(|e| panic!("{png}: {e}"));
            assert!(bytes.starts_with(b"\x89PNG"), "{png} is a PNG");
        }
        assert_eq!(std::fs::read(dir.join(format!("a/p.{f:04}.png"))).unwrap(), std::fs::read(dir.join(format!("b/q.{f:04}.png"))).unwrap());
    }
    // Both at once, or a preview without a pattern in a sequence, are usage errors.
    let out = output(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "c/i.$F4.exr", "--preview", "c/p.$F4.png", "--frames", "1", "--vdbmarch", "--preview c/q.$F4.png"]).args(RENDER));
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let out = output(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "c/i.$F4.exr", "--preview", "c/p.png", "--frames", "1-2"]).args(RENDER));
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("c/p.png"), "{}", stderr(&out));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn nimbus_render_usage_errors_exit_2() {
    let dir = scratch("render-usage");
    write_ball(&dir.join("p.0001.ply"), 200, 0.0);
    let cases: &[(&[&str], &str)] = &[
        (&["p.####.ply", "-o", "i.####.exr", "--frames", "3-1"], "backwards"),
        (&["p.####.ply", "-o", "i.####.exr"], "give --frames"),
        (&["p.0001.ply", "-o", "i.####.exr", "--frames", "1"], "no frame pattern"),
        (&["p.####.ply", "-o", "i.####.exr", "--frames", "1", "--vdbphoton", "--photons 10"], "add --photons"),
        (&["p.####.ply", "-o", "i.####.exr", "--frames", "1", "--sun", "dir=0,0"], "--sun"),
        (&["p.####.ply", "-o", "i.####.exr", "--frames", "1", "--vdbmarch", "--spp '4"], "unterminated"),
        (&["p.####.ply", "-o", "i.####.png", "--frames", "1"], "does not end in .exr"),
        (&["p.####.ply", "-o", "i.####.exr", "--print-chunks", "2"], "--frames"),
    ];
    for (args, want) in cases {
        let out = output(tool("nimbus-render", &dir).args(*args));
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?} should say '{want}': {err}");
    }
    assert!(!dir.join("i.0001.exr").exists());
    // The farm scripts' chunks.
    let out = run(tool("nimbus-render", &dir).args(["p.$F4.ply", "-o", "i.$F4.exr", "--frames", "1-7,10", "--print-chunks", "3"]));
    assert_eq!(String::from_utf8_lossy(&out.stdout), "1-3\n4-6\n7,10\n");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_static_volume_gives_identical_frames_and_reruns_are_bit_identical() {
    let dir = scratch("static");
    write_ball(&dir.join("p.0001.ply"), 1500, 0.0);
    for f in 2..=3 {
        std::fs::copy(dir.join("p.0001.ply"), dir.join(format!("p.{f:04}.ply"))).unwrap();
    }
    // The Perlin offset noise on: anchored in world space and seeded by the same seed every
    // frame, it does not crawl; the cache's paths are keyed by (seed, voxel) alike.
    let noise = ["--vdbmarch", "--offset-noise 0.05 --noise-scale 0.3 --spp 2", "--vdbcache", "--paths 8"];
    run(tool("nimbus-render", &dir).args(["p.####.ply", "-o", "s/i.####.exr", "--frames", "1-3", "-q"]).args(RENDER).args(noise));
    let frames: Vec<Vec<u8>> = (1..=3).map(|f| std::fs::read(dir.join(format!("s/i.{f:04}.exr"))).unwrap()).collect();
    assert_eq!(frames[0], frames[1], "frames 1 and 2 of a static volume are identical");
    assert_eq!(frames[1], frames[2], "frames 2 and 3 of a static volume are identical");
    // The same frame rendered again, in another process: bit-identical.
    run(tool("nimbus-render", &dir).args(["p.####.ply", "-o", "again/i.####.exr", "--frame", "2", "-q"]).args(RENDER).args(noise));
    assert_eq!(std::fs::read(dir.join("again/i.0002.exr")).unwrap(), frames[1]);
    // The noise is there (so the identity above is about it): without it the image differs.
    run(tool("nimbus-render", &dir).args(["p.####.ply", "-o", "plain/i.####.exr", "--frame", "1", "-q", "--vdbcache", "--paths 8", "--vdbmarch", "--spp 2"]).args(RENDER));
    assert_ne!(read_rgba(&dir.join("plain/i.0001.exr")), read_rgba(&dir.join("s/i.0001.exr")));
    std::fs::remove_dir_all(&dir).ok();
}

/// Unmounts the test's tmpfs however the test ends.
struct Mount(PathBuf);

impl Drop for Mount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

fn available_bytes(dir: &Path) -> u64 {
    let out = Command::new("df").args(["--output=avail", "-B1"]).arg(dir).output().unwrap();
    String::from_utf8_lossy(&out.stdout).lines().nth(1).unwrap().trim().parse().unwrap()
}

#[test]
fn a_full_disk_keeps_the_previous_frame_and_reports_it() {
    if !root_or_skip("the full-disk test (mounts a tmpfs)") {
        return;
    }
    let dir = scratch("full");
    let c = cache(&dir, "ball");
    for f in 1..=2 {
        std::fs::copy(&c, dir.join(format!("c.{f:04}.vdb"))).unwrap();
    }
    let disk = dir.join("disk");
    std::fs::create_dir_all(&disk).unwrap();
    let status = Command::new("mount").args(["-t", "tmpfs", "-o", "size=1m", "tmpfs"]).arg(&disk).status().unwrap();
    assert!(status.success(), "mount a 1 MB tmpfs at {}", disk.display());
    let _mount = Mount(disk.clone());
    let march = |extra: &[&str]| output(tool("vdbmarch", &dir).args(["c.####.vdb", "--frames", "1-2", "-o"]).arg(disk.join("i.####.exr")).args(["--width", "96", "--height", "72", "--spp", "1"]).args(extra));
    let out = march(&[]);
    assert!(out.status.success(), "{}", stderr(&out));
    let previous: Vec<Vec<u8>> = (1..=2).map(|f| std::fs::read(disk.join(format!("i.{f:04}.exr"))).unwrap()).collect();
    let size = previous[0].len() as u64;
    assert!(size > 16 << 10, "an EXR large enough to fail mid-way ({size} bytes)");
    // Fill the disk to leave a third of a frame: the next write fails part-way through.
    let filler = disk.join("filler");
    let room = available_bytes(&disk);
    std::fs::write(&filler, vec![1u8; (room - size / 3) as usize]).unwrap();
    let out = march(&["--background", "0.1"]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("error: frame 1: cannot write: No space left on device"), "{err}");
    assert!(err.contains("error: frame 2: "), "{err}");
    assert!(err.trim_end().ends_with("2 of 2 frames failed: 1-2 (vdbmarch)"), "{err}");
    for f in 1..=2 {
        assert_eq!(std::fs::read(disk.join(format!("i.{f:04}.exr"))).unwrap(), previous[f - 1], "frame {f} as it was before");
    }
    let mut left: Vec<String> = std::fs::read_dir(&disk).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    left.sort();
    assert_eq!(left, ["filler", "i.0001.exr", "i.0002.exr"], "no temporary file left behind");
    // With room again the same run succeeds (the new background shows).
    std::fs::remove_file(&filler).unwrap();
    let out = march(&["--background", "0.1"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_ne!(std::fs::read(disk.join("i.0001.exr")).unwrap(), previous[0]);
    drop(_mount);
    std::fs::remove_dir_all(&dir).ok();
}
