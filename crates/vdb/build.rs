//! Compiles the C++ bridge (ffi/*.cpp: files, grids, points, metadata) and generates Rust
//! bindings from its plain C header. Links OpenVDB 10 and what its headers pull in (TBB;
//! Imath for half floats).

use std::env;
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
    let ffi = manifest.join("../../ffi").canonicalize().expect("ffi/ beside crates/");
    let header = ffi.join("nimbus_vdb.h");
    let sources = ["nimbus_vdb.cpp", "grids.cpp", "points.cpp", "metadata.cpp"].map(|f| ffi.join(f));
    println!("cargo:rerun-if-changed={}", header.display());
    println!("cargo:rerun-if-changed={}", ffi.join("nimbus_vdb_internal.h").display());
    for source in &sources {
        println!("cargo:rerun-if-changed={}", source.display());
    }
    println!("cargo:rerun-if-env-changed=NIMBUS_VDB_INCLUDE");

    // Debian installs OpenVDB under /usr/include; NIMBUS_VDB_INCLUDE adds another prefix.
    let include = env::var("NIMBUS_VDB_INCLUDE").unwrap_or_else(|_| "/usr/include".into());
    cc::Build::new()
        .cpp(true)
        .std("c++17")
        .opt_level(2)
        .include(&include)
        .include(&ffi)
        .files(&sources)
        // OpenVDB's headers are noisy under -Wall; the bridge is checked with -Wall by hand.
        .warnings(false)
        .flag_if_supported("-w")
        .compile("nimbus_vdb_bridge");

    for lib in ["openvdb", "tbb", "Imath-3_1", "pthread"] {
        println!("cargo:rustc-link-lib={lib}");
    }

    let bindings = bindgen::Builder::default()
        .header(header.to_str().unwrap())
        .allowlist_function("nimbus_.*")
        .allowlist_type("nimbus_.*")
        .allowlist_var("NIMBUS_.*")
        .newtype_enum("nimbus_.*")
        .prepend_enum_name(false)
        .layout_tests(false)
        .generate()
        .expect("bindgen could not read ffi/nimbus_vdb.h");
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("bindings.rs");
    bindings.write_to_file(&out).expect("cannot write bindings.rs");
}
