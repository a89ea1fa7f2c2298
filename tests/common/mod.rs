//! What the end-to-end test files share: the tools' paths and a scratch directory.

use std::path::PathBuf;

/// The built binary of one of the four tools.
pub fn bin(name: &str) -> PathBuf {
    match name {
        "particles2vdb" => env!("CARGO_BIN_EXE_particles2vdb"),
        "vdbphoton" => env!("CARGO_BIN_EXE_vdbphoton"),
        "vdbcache" => env!("CARGO_BIN_EXE_vdbcache"),
        "vdbmarch" => env!("CARGO_BIN_EXE_vdbmarch"),
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
