//! # nimbus-vdb: OpenVDB files for nimbus
//!
//! Every nimbus tool reads and writes OpenVDB `.vdb` files through this crate. It wraps
//! OpenVDB 10 (Debian's `libopenvdb-dev`) behind a small C bridge and converts grids to and
//! from the in-memory [`nimbus_volume::Volume`] that the stages compute on.
//!
//! ## Structure
//!
//! - `ffi/nimbus_vdb.h` — a plain C header: opaque handles (`nimbus_file`, `nimbus_grid`,
//!   `nimbus_leaf_iter`, `nimbus_meta`), int status codes, plain structs.
//! - `ffi/nimbus_vdb.cpp` (errors, files), `grids.cpp`, `points.cpp`, `metadata.cpp` — the
//!   C++17 implementation, sharing `nimbus_vdb_internal.h`. Every entry point runs inside
//!   `guarded()`, which catches every exception (OpenVDB's, the standard library's, and
//!   anything else) and turns it into `NIMBUS_ERR` plus a thread-local message read with
//!   `nimbus_last_error()`: no exception ever unwinds into Rust. `openvdb::initialize()` runs
//!   once, on the first call.
//! - `build.rs` — `cc` compiles the bridge, `bindgen` turns the header into `sys` (private).
//!   Links `openvdb`, `tbb`, `Imath-3_1`.
//! - This crate — the safe API: [`VdbFile`], [`GridInfo`], [`PointSet`], [`MetaValue`],
//!   [`VdbError`].
//!
//! ## Conventions
//!
//! - **Whole files in memory.** Reading loads every grid (no delayed loading), so a tool
//!   can write its output over its input. Reading from stdin takes the bytes
//!   ([`VdbFile::from_reader`]) and parses them through `io::Stream`.
//! - **One file format.** [`VdbFile::write`] and [`VdbFile::to_bytes`] produce the same
//!   bytes: OpenVDB's file format with grid offsets (what `io::File` writes), so output
//!   piped to stdout and redirected to a file is a regular `.vdb` for Blender, Houdini,
//!   `vdb_print`, and streams read back through `io::Stream` as well.
//! - **Atomic writes.** [`VdbFile::write`] writes a hidden temporary file beside the target,
//!   syncs it and renames it into place; a failure removes it (design.md section 6).
//! - **Compression** ZIP by default, blosc or none on request ([`WriteOptions`]); `half`
//!   stores float grids as 16-bit halves.
//! - **Leaf by leaf.** Grids convert to volumes one 8^3 leaf at a time (origin, 512 values in
//!   `LeafNode::coordToOffset` order, 8 mask words), never through a dense array. Active
//!   tiles are voxelized on a copy first so every active value arrives in a leaf; double
//!   grids read as f32; half-saved grids are float grids in OpenVDB and read as such. The
//!   background carries over both ways. Inactive *tiles* are not kept (a volume is the
//!   background outside its bricks).
//! - **Transforms.** Any linear OpenVDB map (Affine, Scale, UniformScaleTranslate, ...)
//!   converts to [`nimbus_volume::Transform`]; OpenVDB's row-vector matrices (world =
//!   index * M) are transposed at the bridge, which passes glam's `DAffine3` column order.
//!   A frustum (or any non-affine) map is refused with [`VdbError::Grid`] naming the grid.
//!   Writing stores the simplest equal map (UniformScale[Translate], Scale[Translate] or
//!   Affine), built directly so the coefficients stay bit-exact.
//! - **Points** ([`PointSet`]): f64 world positions, float/vec3 attributes; see there for
//!   precision and ordering.
//! - **Metadata** ([`MetaValue`]): string, bool, i32, i64, f32, f64, vec3i, vec3f, vec3d;
//!   other types are skipped when reading. nimbus's run parameters live in file metadata
//!   under `nimbus:` keys.
//! - **Errors** ([`VdbError`]) name the file (path or `<stdin>`) and the grid; a corrupt,
//!   truncated or non-VDB input is an `Err`, never a panic or abort.
//! - **Pass-through.** Grids of types nimbus does not convert stay in the [`VdbFile`] and are
//!   written back unchanged; [`VdbFile::copy_grid_from`] moves any grid between files.
//!
//! ```no_run
//! use nimbus_vdb::{GridClass, VdbFile, WriteOptions};
//! let mut file = VdbFile::open("smoke.vdb")?;
//! let density = file.read_float("density")?;
//! let doubled = density.map(0.0, |d| 2.0 * d);
//! file.insert_volume("density2", &doubled, GridClass::FogVolume)?;
//! file.set_metadata("nimbus:note", "doubled")?;
//! file.write("out.vdb", &WriteOptions::default())?;
//! # Ok::<(), nimbus_vdb::VdbError>(())
//! ```

mod error;
mod file;
mod meta;
mod points;
mod sys;

pub use error::{Result, VdbError};
pub use file::{has_blosc, Compression, GridClass, GridInfo, GridKind, GridValue, Space, VdbFile, VectorType, WriteOptions, MAX_READ_VOXELS};
pub use meta::{MetaValue, Metadata};
pub use points::{PointAttribute, PointSet};

/// Fixtures for tests elsewhere in the workspace; not part of the API.
#[doc(hidden)]
pub mod testing {
    use crate::file::OwnedGrid;
    use crate::{sys, Result, VdbFile};

    /// Adds a float fog grid `name` with an OpenVDB NonlinearFrustumMap transform and one
    /// active voxel, to check that non-affine transforms are refused.
    pub fn insert_frustum_grid(file: &mut VdbFile, name: &str) -> Result<()> {
        let cname = std::ffi::CString::new(name).expect("grid name without NUL");
        let mut out = std::ptr::null_mut();
        // SAFETY: valid C string and out-pointer.
        let status = unsafe { sys::nimbus_test_frustum_grid(cname.as_ptr(), &mut out) };
        let grid = OwnedGrid::from_status(status, out).map_err(|m| file.error_for(name, m))?;
        file.insert_owned(grid, name)
    }

    /// Adds a points grid `name` as Houdini writes it by default: 16-bit fixed-point
    /// positions ("ufxpt16"), a half-float vec3 `v`, a float `temperature` and a point group
    /// `group` of the points whose `in_group` is true (see `nimbus_test_houdini_points`).
    pub fn insert_houdini_points(
        file: &mut VdbFile,
        name: &str,
        positions: &[glam::DVec3],
        v: &[glam::Vec3],
        temperature: &[f32],
        in_group: &[bool],
        voxel_size: f64,
        group: &str,
    ) -> Result<()> {
        let n = positions.len();
        assert!(v.len() == n && temperature.len() == n && in_group.len() == n, "one value per point");
        let cname = std::ffi::CString::new(name).expect("grid name without NUL");
        let cgroup = std::ffi::CString::new(group).expect("group name without NUL");
        let member: Vec<u8> = in_group.iter().map(|&b| b as u8).collect();
        let mut out = std::ptr::null_mut();
        // SAFETY: n positions (3 doubles), n v (3 floats), n temperatures and n flags.
        let status = unsafe {
            sys::nimbus_test_houdini_points(
                cname.as_ptr(),
                bytemuck::cast_slice::<glam::DVec3, f64>(positions).as_ptr(),
                bytemuck::cast_slice::<glam::Vec3, f32>(v).as_ptr(),
                temperature.as_ptr(),
                member.as_ptr(),
                n,
                voxel_size,
                cgroup.as_ptr(),
                &mut out,
            )
        };
        let grid = OwnedGrid::from_status(status, out).map_err(|m| file.error_for(name, m))?;
        file.insert_owned(grid, name)
    }

    /// Replaces float grid `name` by a double grid (vec3s by vec3d) with the same values.
    pub fn widen_grid(file: &mut VdbFile, name: &str) -> Result<()> {
        let (grid, _) = file.grid_ptr_by_name(name)?;
        let mut out = std::ptr::null_mut();
        // SAFETY: a valid grid and out-pointer.
        let status = unsafe { sys::nimbus_test_widen_grid(grid, &mut out) };
        let grid = OwnedGrid::from_status(status, out).map_err(|m| file.error_for(name, m))?;
        file.insert_owned(grid, name)
    }
}
