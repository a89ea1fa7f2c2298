//! The release (issue #49): scripts/dist.sh packs the ci profile's tools as `make dist` packs
//! the release profile's; unpacked into an empty folder, every library its binaries load
//! outside glibc's and GCC's runtime resolves into its own lib/ (ldd with a clean
//! environment), and the chain runs from its bin/ with a clean environment and, where a mount
//! namespace is allowed (root on CI), with the system's copies of those libraries replaced by
//! empty files, so a release that still leaned on the system's OpenVDB would fail to start.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use common::{bin, run, scratch, SUN};

/// What the release leaves to the system (scripts/dist.sh's SYSTEM).
const SYSTEM: &[&str] = &[
    "linux-vdso.so.1",
    "ld-linux-x86-64.so.2",
    "libc.so.6",
    "libm.so.6",
    "libpthread.so.0",
    "libdl.so.2",
    "librt.so.1",
    "libutil.so.1",
    "libresolv.so.2",
    "libanl.so.1",
    "libmvec.so.1",
    "libgcc_s.so.1",
    "libstdc++.so.6",
];
const CLEAN_PATH: &str = "/usr/bin:/bin";
/// Where Debian's copies of the bundled libraries live (/lib is a link to /usr/lib on Debian 12).
const SYSTEM_LIBS: &str = "/usr/lib/x86_64-linux-gnu";

fn dist_sh() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/dist.sh")
}

/// The ci profile's directory, where cargo put the tools this test runs.
fn profile() -> PathBuf {
    bin("vdbmarch").parent().unwrap().to_path_buf()
}

/// scripts/dist.sh PROFILE OUT at xz's fastest level: the tarball.
fn pack(out: &Path) -> PathBuf {
    let packed = run(Command::new(dist_sh()).arg(profile()).arg(out).env("NIMBUS_DIST_XZ", "0"));
    PathBuf::from(String::from_utf8(packed.stdout).unwrap().trim())
}

#[test]
fn the_release_runs_unpacked_in_an_empty_folder() {
    let work = scratch("dist", "release");
    let start = Instant::now();
    let tarball = pack(&work.join("out"));
    let version = env!("CARGO_PKG_VERSION");
    assert_eq!(tarball.file_name().unwrap().to_str().unwrap(), format!("nimbus-{version}-linux-x86_64.tar.xz"));
    let size = std::fs::metadata(&tarball).unwrap().len();
    assert!(size < 64 << 20, "{}: {size} bytes, over 64 MiB", tarball.display());
    eprintln!("packed in {:.1} s: {:.1} MiB at xz -0", start.elapsed().as_secs_f64(), size as f64 / (1 << 20) as f64);

    let unpacked = work.join("unpacked");
    std::fs::create_dir(&unpacked).unwrap();
    run(Command::new("tar").arg("-C").arg(&unpacked).arg("-xJf").arg(&tarball));
    let entries: Vec<_> = std::fs::read_dir(&unpacked).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(entries.len(), 1, "the tarball holds one folder: {entries:?}");
    let release = entries[0].clone();
    for path in ["bin/particles2vdb", "bin/vdbphoton", "bin/vdbcache", "bin/vdbmarch", "bin/nimbus-render", "bin/nimbus-scene", "lib/libvulkan.so.1", "README.md", "LICENSE", "INSTALL", "data/plume.ply", "scripts/demo.sh"] {
        assert!(release.join(path).exists(), "the release lacks {path}");
    }

    // The hard check: what ldd resolves, with nothing in the environment to help it.
    let lib = release.join("lib").canonicalize().unwrap();
    let bins: Vec<PathBuf> = std::fs::read_dir(release.join("bin")).unwrap().map(|e| e.unwrap().path()).collect();
    for binary in &bins {
        let out = run(Command::new("ldd").arg(binary).env_clear().env("PATH", CLEAN_PATH));
        let report = String::from_utf8(out.stdout).unwrap();
        assert!(!report.contains("not found"), "{}: {report}", binary.display());
        let mut bundled = Vec::new();
        for line in report.lines() {
            let words: Vec<&str> = line.split_whitespace().collect();
            let [soname, "=>", path, ..] = words[..] else { continue };
            if SYSTEM.contains(&soname) {
                continue;
            }
            let real = Path::new(path).canonicalize().unwrap();
            assert!(real.starts_with(&lib), "{} loads {soname} from {path}, outside the release's lib/:\n{report}", binary.display());
            bundled.push(soname);
        }
        let chain_tool = ["particles2vdb", "vdbphoton", "vdbcache", "vdbmarch", "nimbus-render"].iter().any(|t| binary.ends_with(t));
        assert!(!chain_tool || bundled.iter().any(|s| s.starts_with("libopenvdb.so")), "{} loads no OpenVDB:\n{report}", binary.display());
    }
    let sonames: Vec<String> = std::fs::read_dir(&lib).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert!(sonames.iter().any(|s| s.starts_with("libopenvdb.so")), "no OpenVDB in lib/: {sonames:?}");

    // The chain, from bin/, in a clean environment: the bundled generator's particles, CPU
    // stages, then a march on the GPU (lavapipe) through the bundled Vulkan loader.
    let scene = work.join("scene");
    std::fs::create_dir(&scene).unwrap();
    let chain = format!(
        "set -eu\n\
         cd '{scene}'\n\
         B='{bin}'\n\
         \"$B/gen_particles\" plume particles.ply 4000 2>/dev/null\n\
         \"$B/particles2vdb\" particles.ply --resolution 16 --neighbours 16 --device cpu -q -o density.vdb\n\
         \"$B/vdbcache\" density.vdb --sun {SUN} --width 32 --height 24 --quality draft --device cpu -q -o cache.vdb\n\
         \"$B/vdbmarch\" cache.vdb --device cpu -q -o image.exr\n\
         \"$B/vdbmarch\" cache.vdb --device gpu -q -o image-gpu.exr\n\
         \"$B/nimbus-compare\" image.exr image-gpu.exr\n",
        scene = scene.display(),
        bin = release.join("bin").display(),
    );
    std::fs::write(work.join("chain.sh"), &chain).unwrap();
    // The system's copies of what lib/ holds, each replaced by an empty file in a mount
    // namespace of its own (mount --bind follows the soname's link to the real file).
    let hidden: Vec<PathBuf> = sonames.iter().map(|s| Path::new(SYSTEM_LIBS).join(s)).filter(|p| p.exists()).map(|p| p.canonicalize().unwrap()).collect();
    let empty = work.join("empty");
    std::fs::write(&empty, b"").unwrap();
    let mut hide = String::from("set -eu\n");
    for path in &hidden {
        hide.push_str(&format!("mount --bind '{}' '{}'\n", empty.display(), path.display()));
    }
    // Proof that the hiding holds: the same tool built against the system's libraries no longer starts.
    hide.push_str(&format!("if '{}' --help >/dev/null 2>&1; then echo 'the system libraries are still visible' >&2; exit 3; fi\n", bin("vdbmarch").display()));
    hide.push_str(&format!("exec env -i PATH={CLEAN_PATH} sh '{}'\n", work.join("chain.sh").display()));
    std::fs::write(work.join("hide.sh"), &hide).unwrap();
    let start = Instant::now();
    let unshare = Command::new("unshare").args(["--mount", "true"]).output();
    let out = match unshare {
        Ok(o) if o.status.success() && !hidden.is_empty() => {
            run(Command::new("unshare").args(["--mount", "--propagation", "private", "sh"]).arg(work.join("hide.sh")))
        }
        other => {
            let why = match other {
                Ok(o) if o.status.success() => "no system copy of the bundled libraries to hide".to_string(),
                Ok(o) => format!("unshare --mount is not permitted here: {}", String::from_utf8_lossy(&o.stderr).trim()),
                Err(e) => format!("no unshare: {e}"),
            };
            eprintln!("SKIPPED hiding the system's libraries ({why}); the chain runs with a clean environment only");
            run(Command::new("env").args(["-i", &format!("PATH={CLEAN_PATH}"), "sh"]).arg(work.join("chain.sh")))
        }
    };
    eprintln!("chain in {:.1} s ({} system libraries hidden)", start.elapsed().as_secs_f64(), hidden.len());
    // nimbus-compare: the GPU's march against the CPU's, both of the same cache.
    let compared = String::from_utf8(out.stdout).unwrap();
    let rmse: f64 = compared.split("relative RMSE ").nth(1).and_then(|s| s.split(',').next()).and_then(|s| s.trim().parse().ok()).unwrap_or_else(|| panic!("nimbus-compare said: {compared}"));
    assert!(rmse < 0.02, "the GPU's march differs from the CPU's by {rmse}: {compared}");

    // The image, read by OpenEXR's own exrheader.
    let header = run(Command::new("exrheader").arg(scene.join("image.exr")));
    let header = String::from_utf8_lossy(&header.stdout);
    assert!(header.contains("dataWindow (type box2i): (0 0) - (31 23)"), "{header}");
    for channel in ["R", "G", "B", "A"] {
        assert!(header.contains(&format!("    {channel}, 32-bit floating-point")), "no {channel} channel: {header}");
    }
    std::fs::remove_dir_all(&work).unwrap();
}

/// A profile directory without the tools is refused with a reason, and leaves no tarball.
#[test]
fn packing_what_was_not_built_fails_and_leaves_nothing() {
    let work = scratch("dist", "unbuilt");
    let empty = work.join("profile");
    std::fs::create_dir_all(&empty).unwrap();
    let out_dir = work.join("out");
    let out = Command::new(dist_sh()).arg(&empty).arg(&out_dir).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("particles2vdb is missing"), "{stderr}");
    assert!(!out_dir.exists() || std::fs::read_dir(&out_dir).unwrap().next().is_none(), "a failed pack left files in {}", out_dir.display());
    let out = Command::new(dist_sh()).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("usage: scripts/dist.sh PROFILE_DIR [OUT_DIR]"));
    std::fs::remove_dir_all(&work).unwrap();
}
