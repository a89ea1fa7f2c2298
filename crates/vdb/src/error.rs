//! The crate's error type. Every message names the file (or stream) and, where one is
//! involved, the grid, so a tool can print it as is.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum VdbError {
    /// The source could not be opened (missing file, directory, permissions).
    #[error("cannot open {}: {source}", path.display())]
    Open { path: PathBuf, source: std::io::Error },

    /// The bytes are not a readable VDB: not a VDB at all, truncated or corrupt.
    #[error("cannot read VDB {file}: {message}")]
    Read { file: String, message: String },

    /// Writing failed; no partial output file is left behind.
    #[error("cannot write VDB {target}: {message}")]
    Write { target: String, message: String },

    #[error("no grid named '{grid}' in {file} (it has: {available})")]
    MissingGrid { file: String, grid: String, available: String },

    /// A grid exists but cannot be used as asked: wrong value type, non-affine transform,
    /// mismatched attribute length, ...
    #[error("grid '{grid}' in {file}: {message}")]
    Grid { file: String, grid: String, message: String },
}

pub type Result<T, E = VdbError> = std::result::Result<T, E>;
