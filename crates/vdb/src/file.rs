//! [`VdbFile`]: a set of OpenVDB grids plus file metadata, read from and written to paths
//! or bytes, with conversions between grids and [`nimbus_volume::Volume`].

use std::ffi::CString;
use std::io::Write;
use std::os::unix::ffi::OsStrExt;
use std::path::Path;
use std::ptr::{self, NonNull};
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{DAffine3, DVec3, IVec3, Vec3};
use nimbus_volume::{Transform, Volume, Voxel, BRICK_VOXELS};

use crate::error::{Result, VdbError};
use crate::meta::{self, MetaValue, Metadata};
use crate::sys;

/// OpenVDB's grid class (the `class` grid metadata).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum GridClass {
    Unknown,
    LevelSet,
    /// Density-like: non-negative values, background 0. nimbus's default.
    #[default]
    FogVolume,
    Staggered,
}

/// OpenVDB's vector type of a vec3 grid (the `vector_type` grid metadata): how a change of
/// transform acts on its values. Velocity is [`VectorType::ContravariantRelative`], as
/// Houdini and Blender write it; colour is [`VectorType::Invariant`] (OpenVDB's default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum VectorType {
    #[default]
    Invariant,
    Covariant,
    CovariantNormalize,
    ContravariantRelative,
    ContravariantAbsolute,
}

/// What a grid can be read as.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GridKind {
    /// float grids (including ones saved as half) and double grids: [`VdbFile::read_float`].
    Float,
    /// vec3s and vec3d grids: [`VdbFile::read_vec3`].
    Vec3,
    /// OpenVDB points: [`VdbFile::read_points`].
    Points,
    /// Any other type (int, bool, mask, ...): listed, and kept when the file is rewritten.
    Other,
}

/// VDB compression. ZIP is the default because every OpenVDB build reads it.
///
/// OpenVDB itself never ZIP-compresses the voxel data of fog volumes and level sets
/// (`io::Archive::setGridCompression`): such grids get only active-mask compression under
/// `Zip`. OpenVDB 10 nevertheless deflates each of their leaves to record compressed sizes
/// in its delayed-load metadata, which cost 0.45 s of a 4.2M-voxel density write (0.53 s
/// against 0.08 s). So when every grid of a file is a fog volume or level set, the bridge
/// does not ask for ZIP: the voxel data written is the same. Blosc does apply to them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Compression {
    #[default]
    Zip,
    /// Faster, but only readable by OpenVDB builds with blosc; see [`has_blosc`].
    Blosc,
    None,
}

/// Options for writing a file or bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    pub compression: Compression,
    /// Store float and vec3 grids as 16-bit halves (OpenVDB's saveFloatAsHalf). Off means
    /// float32, also for grids that were read from a half-float file.
    pub half: bool,
}

/// Whether this OpenVDB build can write blosc compression.
pub fn has_blosc() -> bool {
    // SAFETY: no arguments; cannot fail.
    unsafe { sys::nimbus_has_blosc() != 0 }
}

/// Index space or world space, for [`VdbFile::sample_box`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Space {
    Index,
    World,
}

/// The most active voxels [`VdbFile::read_volume`] converts (2^30: 4 GiB of floats).
pub const MAX_READ_VOXELS: u64 = 1 << 30;

/// A description of one grid, as listed by [`VdbFile::grids`].
#[derive(Clone, Debug, PartialEq)]
pub struct GridInfo {
    pub name: String,
    /// OpenVDB's value type name, e.g. `float`, `vec3s`, `ptdataidx32`.
    pub value_type: String,
    /// OpenVDB's grid type name, e.g. `Tree_float_5_4_3`.
    pub grid_type: String,
    pub kind: GridKind,
    pub class: GridClass,
    /// OpenVDB's map type, e.g. `UniformScaleTranslateMap`, `AffineMap`, `NonlinearFrustumMap`.
    pub map_type: String,
    /// The index-to-world map, or `None` when it is not affine (frustum) or is singular.
    pub transform: Option<Transform>,
    pub active_voxel_count: u64,
    /// Inclusive index-space bounds of the active voxels (`None` when there are none).
    pub index_bbox: Option<(IVec3, IVec3)>,
    /// Number of points (points grids only, else 0).
    pub point_count: u64,
    /// The grid asks to be saved as half floats (set when it was read from such a file).
    pub saved_as_half: bool,
    /// All convertible grid metadata, including OpenVDB's own (`class`, `name`,
    /// `file_bbox_min`, `file_voxel_count`, ... after reading a file).
    pub metadata: Metadata,
}

/// Value types that convert between OpenVDB grids and [`Volume`]s: `f32` and `glam::Vec3`.
pub trait GridValue: Voxel + sealed::Sealed {
    #[doc(hidden)]
    const KIND: GridKind;
    #[doc(hidden)]
    const CHANNELS: usize;
}
impl GridValue for f32 {
    const KIND: GridKind = GridKind::Float;
    const CHANNELS: usize = 1;
}
impl GridValue for Vec3 {
    const KIND: GridKind = GridKind::Vec3;
    const CHANNELS: usize = 3;
}
mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for glam::Vec3 {}
}

fn value_kind(kind: GridKind) -> sys::nimbus_value_kind {
    match kind {
        GridKind::Float => sys::nimbus_value_kind::NIMBUS_VALUE_FLOAT,
        GridKind::Vec3 => sys::nimbus_value_kind::NIMBUS_VALUE_VEC3F,
        GridKind::Points => sys::nimbus_value_kind::NIMBUS_VALUE_POINTS,
        GridKind::Other => sys::nimbus_value_kind::NIMBUS_VALUE_OTHER,
    }
}

fn grid_kind(kind: sys::nimbus_value_kind) -> GridKind {
    match kind {
        sys::nimbus_value_kind::NIMBUS_VALUE_FLOAT => GridKind::Float,
        sys::nimbus_value_kind::NIMBUS_VALUE_VEC3F => GridKind::Vec3,
        sys::nimbus_value_kind::NIMBUS_VALUE_POINTS => GridKind::Points,
        _ => GridKind::Other,
    }
}

fn class_to_sys(class: GridClass) -> sys::nimbus_grid_class {
    match class {
        GridClass::Unknown => sys::nimbus_grid_class::NIMBUS_CLASS_UNKNOWN,
        GridClass::LevelSet => sys::nimbus_grid_class::NIMBUS_CLASS_LEVEL_SET,
        GridClass::FogVolume => sys::nimbus_grid_class::NIMBUS_CLASS_FOG_VOLUME,
        GridClass::Staggered => sys::nimbus_grid_class::NIMBUS_CLASS_STAGGERED,
    }
}

fn class_from_sys(class: sys::nimbus_grid_class) -> GridClass {
    match class {
        sys::nimbus_grid_class::NIMBUS_CLASS_LEVEL_SET => GridClass::LevelSet,
        sys::nimbus_grid_class::NIMBUS_CLASS_FOG_VOLUME => GridClass::FogVolume,
        sys::nimbus_grid_class::NIMBUS_CLASS_STAGGERED => GridClass::Staggered,
        _ => GridClass::Unknown,
    }
}

fn compression_to_sys(c: Compression) -> sys::nimbus_compression {
    match c {
        Compression::Zip => sys::nimbus_compression::NIMBUS_COMPRESS_ZIP,
        Compression::Blosc => sys::nimbus_compression::NIMBUS_COMPRESS_BLOSC,
        Compression::None => sys::nimbus_compression::NIMBUS_COMPRESS_NONE,
    }
}

/// A grid handle the caller owns until it is inserted into a file.
pub(crate) struct OwnedGrid(NonNull<sys::nimbus_grid>);

impl OwnedGrid {
    /// Wraps what a bridge constructor returned through `out`.
    pub(crate) fn from_status(status: std::os::raw::c_int, out: *mut sys::nimbus_grid) -> Result<Self, String> {
        sys::check(status)?;
        NonNull::new(out).map(OwnedGrid).ok_or_else(|| "the bridge returned no grid".to_string())
    }
    pub(crate) fn as_ptr(&self) -> *mut sys::nimbus_grid {
        self.0.as_ptr()
    }
    fn into_raw(self) -> *mut sys::nimbus_grid {
        let p = self.0.as_ptr();
        std::mem::forget(self);
        p
    }
}

impl Drop for OwnedGrid {
    fn drop(&mut self) {
        // SAFETY: we own the handle and nothing else frees it.
        unsafe { sys::nimbus_grid_free(self.0.as_ptr()) }
    }
}

pub(crate) fn c_string(s: &str, what: &str) -> Result<CString, String> {
    CString::new(s).map_err(|_| format!("{what} {s:?} contains a NUL byte"))
}

/// A VDB file in memory: grids of any type OpenVDB reads plus file metadata.
///
/// Grids that nimbus does not convert (int grids, masks, level sets, ...) are kept as they
/// are, so a tool that reads a file, adds grids and writes it passes everything through.
pub struct VdbFile {
    raw: NonNull<sys::nimbus_file>,
    /// Where the grids came from, for error messages: a path, `<stdin>`, `<bytes>`, ...
    label: String,
}

// SAFETY: the bridge owns its grids exclusively per file, loads them fully on read (no
// delayed loading) and only reads them through `&self` (samplers use their own accessors).
unsafe impl Send for VdbFile {}
unsafe impl Sync for VdbFile {}

impl Drop for VdbFile {
    fn drop(&mut self) {
        // SAFETY: we own the file handle.
        unsafe { sys::nimbus_file_free(self.raw.as_ptr()) }
    }
}

impl std::fmt::Debug for VdbFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VdbFile").field("label", &self.label).field("grids", &self.grid_names()).finish()
    }
}

impl Default for VdbFile {
    fn default() -> Self {
        Self::new()
    }
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl VdbFile {
    /// An empty file: no grids, no metadata.
    pub fn new() -> VdbFile {
        let mut raw = ptr::null_mut();
        // SAFETY: out-pointer to a local.
        let status = unsafe { sys::nimbus_file_new(&mut raw) };
        sys::check(status).expect("allocating an empty VDB file");
        VdbFile { raw: NonNull::new(raw).expect("the bridge returned no file"), label: "<new>".into() }
    }

    fn from_raw(status: std::os::raw::c_int, raw: *mut sys::nimbus_file, label: String) -> Result<VdbFile> {
        match sys::check(status).and_then(|()| NonNull::new(raw).ok_or_else(|| "no file returned".into())) {
            Ok(raw) => Ok(VdbFile { raw, label }),
            Err(message) => Err(VdbError::Read { file: label, message }),
        }
    }

    /// Reads every grid of the `.vdb` file at `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<VdbFile> {
        let path = path.as_ref();
        let label = path.display().to_string();
        // Checked here for a clear OS error; the bridge would only say it cannot open it.
        let md = std::fs::metadata(path).map_err(|source| VdbError::Open { path: path.into(), source })?;
        if md.is_dir() {
            let source = std::io::Error::new(std::io::ErrorKind::InvalidInput, "is a directory");
            return Err(VdbError::Open { path: path.into(), source });
        }
        let cpath = CString::new(path.as_os_str().as_bytes())
            .map_err(|_| VdbError::Read { file: label.clone(), message: "path contains a NUL byte".into() })?;
        let mut raw = ptr::null_mut();
        // SAFETY: valid C string and out-pointer.
        let status = unsafe { sys::nimbus_file_read_path(cpath.as_ptr(), &mut raw) };
        Self::from_raw(status, raw, label)
    }

    /// Reads a `.vdb` held in memory (e.g. all of stdin). `label` names the source in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<VdbFile> {
        let mut raw = ptr::null_mut();
        // SAFETY: the slice is valid for the call; the bridge copies what it keeps.
        let status = unsafe { sys::nimbus_file_read_bytes(bytes.as_ptr(), bytes.len(), &mut raw) };
        Self::from_raw(status, raw, label.to_string())
    }

    /// Reads all of `reader` and parses it as a `.vdb` (stdin: `label` = `"<stdin>"`).
    pub fn from_reader(mut reader: impl std::io::Read, label: &str) -> Result<VdbFile> {
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .map_err(|e| VdbError::Read { file: label.to_string(), message: e.to_string() })?;
        Self::from_bytes(&bytes, label)
    }

    /// What errors call this file: its path, `<stdin>`, ...
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Writes to `path` atomically: the bytes go to a temporary file beside it, which is
    /// synced and renamed over `path` only once complete. On error no file is left behind.
    pub fn write(&self, path: impl AsRef<Path>, options: &WriteOptions) -> Result<()> {
        let path = path.as_ref();
        let werr = |message: String| VdbError::Write { target: path.display().to_string(), message };
        let name = path.file_name().ok_or_else(|| werr("not a file path".into()))?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".tmp-{}-{}", std::process::id(), TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)));
        let tmp = dir.join(tmp_name);

        let result = (|| {
            let ctmp = CString::new(tmp.as_os_str().as_bytes()).map_err(|_| "path contains a NUL byte".to_string())?;
            // SAFETY: valid handle and C string.
            sys::check(unsafe {
                sys::nimbus_file_write_path(
                    self.raw.as_ptr(),
                    ctmp.as_ptr(),
                    compression_to_sys(options.compression),
                    i32::from(options.half),
                )
            })?;
            // Durable before it becomes visible under the real name.
            std::fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(|e| e.to_string())?;
            std::fs::rename(&tmp, path).map_err(|e| e.to_string())
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        result.map_err(werr)
    }

    /// The bytes of a `.vdb` file (the same format as [`VdbFile::write`], so they can be
    /// piped to another tool or saved by a shell redirect and read by any OpenVDB reader).
    pub fn to_bytes(&self, options: &WriteOptions) -> Result<Vec<u8>> {
        let mut data = ptr::null_mut();
        let mut len = 0usize;
        // SAFETY: valid handle and out-pointers.
        let status = unsafe {
            sys::nimbus_file_write_bytes(
                self.raw.as_ptr(),
                compression_to_sys(options.compression),
                i32::from(options.half),
                &mut data,
                &mut len,
            )
        };
        sys::check(status).map_err(|message| VdbError::Write { target: "<bytes>".into(), message })?;
        // SAFETY: on success the bridge returned a malloc'd buffer of `len` bytes.
        let out = unsafe { std::slice::from_raw_parts(data, len).to_vec() };
        unsafe { sys::nimbus_bytes_free(data) };
        Ok(out)
    }

    /// Writes the `.vdb` bytes to `writer` (e.g. stdout); `label` names it in errors.
    pub fn write_to(&self, mut writer: impl Write, options: &WriteOptions, label: &str) -> Result<()> {
        let bytes = self.to_bytes(options)?;
        writer
            .write_all(&bytes)
            .and_then(|()| writer.flush())
            .map_err(|e| VdbError::Write { target: label.to_string(), message: e.to_string() })
    }

    // ---- grids ---------------------------------------------------------------------------

    fn grid_count(&self) -> usize {
        // SAFETY: valid handle.
        unsafe { sys::nimbus_file_grid_count(self.raw.as_ptr()) }
    }

    fn grid_ptr(&self, index: usize) -> *const sys::nimbus_grid {
        // SAFETY: valid handle; null when out of range.
        unsafe { sys::nimbus_file_grid(self.raw.as_ptr(), index) }
    }

    fn grid_error(&self, grid: &str, message: impl Into<String>) -> VdbError {
        VdbError::Grid { file: self.label.clone(), grid: grid.to_string(), message: message.into() }
    }

    fn info_at(&self, index: usize) -> Result<GridInfo, String> {
        grid_info(self.grid_ptr(index))
    }

    /// Names of all grids, in file order.
    pub fn grid_names(&self) -> Vec<String> {
        (0..self.grid_count()).filter_map(|i| self.info_at(i).ok().map(|g| g.name)).collect()
    }

    /// Describes every grid, in file order.
    pub fn grids(&self) -> Result<Vec<GridInfo>> {
        (0..self.grid_count())
            .map(|i| self.info_at(i).map_err(|m| VdbError::Read { file: self.label.clone(), message: m }))
            .collect()
    }

    /// Index of the first grid called `name`, with its description.
    fn find(&self, name: &str) -> Result<(usize, GridInfo)> {
        for i in 0..self.grid_count() {
            let info = self.info_at(i).map_err(|m| self.grid_error(name, m))?;
            if info.name == name {
                return Ok((i, info));
            }
        }
        let names = self.grid_names();
        let available = if names.is_empty() { "no grids".to_string() } else { names.join(", ") };
        Err(VdbError::MissingGrid { file: self.label.clone(), grid: name.to_string(), available })
    }

    /// Describes the grid called `name`.
    pub fn grid(&self, name: &str) -> Result<GridInfo> {
        self.find(name).map(|(_, info)| info)
    }

    pub fn has_grid(&self, name: &str) -> bool {
        self.grid_names().iter().any(|n| n == name)
    }

    /// Removes the grid called `name`; returns whether there was one.
    pub fn remove_grid(&mut self, name: &str) -> bool {
        match self.find(name) {
            Ok((i, _)) => {
                // SAFETY: valid handle and index.
                unsafe { sys::nimbus_file_remove_grid(self.raw.as_ptr(), i) };
                true
            }
            Err(_) => false,
        }
    }

    /// Inserts an owned grid, replacing one of the same name in place, else appending.
    pub(crate) fn insert_owned(&mut self, grid: OwnedGrid, name: &str) -> Result<()> {
        // SAFETY: the bridge takes ownership of the grid whatever the outcome.
        let status = unsafe { sys::nimbus_file_insert_grid(self.raw.as_ptr(), grid.into_raw()) };
        sys::check(status).map_err(|m| self.grid_error(name, m))
    }

    /// Copies grid `name` of `other` into this file (any grid type; the voxel data is
    /// shared, not duplicated), replacing a grid of the same name.
    pub fn copy_grid_from(&mut self, other: &VdbFile, name: &str) -> Result<()> {
        let (i, _) = other.find(name)?;
        let mut out = ptr::null_mut();
        // SAFETY: valid grid pointer and out-pointer.
        let status = unsafe { sys::nimbus_grid_copy(other.grid_ptr(i), &mut out) };
        let grid = OwnedGrid::from_status(status, out).map_err(|m| other.grid_error(name, m))?;
        self.insert_owned(grid, name)
    }

    /// The affine transform of a grid, or an error naming the grid when it has none.
    fn affine(&self, info: &GridInfo) -> Result<Transform> {
        info.transform.ok_or_else(|| {
            self.grid_error(
                &info.name,
                format!(
                    "its transform ({}) is not an invertible affine map; nimbus needs an affine index-to-world map",
                    info.map_type
                ),
            )
        })
    }

    fn check_kind(&self, info: &GridInfo, want: GridKind) -> Result<()> {
        if info.kind == want {
            return Ok(());
        }
        let want = match want {
            GridKind::Float => "a float (or double) grid",
            GridKind::Vec3 => "a vec3 grid",
            GridKind::Points => "an OpenVDB points grid",
            GridKind::Other => "another grid type",
        };
        Err(self.grid_error(&info.name, format!("has value type {}, expected {want}", info.value_type)))
    }

    /// Reads a float (or double, or half-saved) grid as a volume.
    pub fn read_float(&self, name: &str) -> Result<Volume<f32>> {
        self.read_volume(name)
    }

    /// Reads a vec3s (or vec3d) grid as a volume.
    pub fn read_vec3(&self, name: &str) -> Result<Volume<Vec3>> {
        self.read_volume(name)
    }

    /// Reads grid `name` leaf by leaf into a volume; active tiles arrive voxelized, and
    /// the background and transform carry over.
    pub fn read_volume<T: GridValue>(&self, name: &str) -> Result<Volume<T>> {
        let (index, info) = self.find(name)?;
        self.check_kind(&info, T::KIND)?;
        let transform = self.affine(&info)?;
        // Active tiles arrive voxelized, so a few bytes of file (one active root tile, or a
        // corrupt one) can stand for 10^11 voxels: refuse before allocating rather than die
        // out of memory. OpenVDB counts tiles voxel by voxel without voxelizing them.
        if info.active_voxel_count > MAX_READ_VOXELS {
            return Err(self.grid_error(
                name,
                format!("holds {} active voxels (tiles counted voxel by voxel), more than the {MAX_READ_VOXELS} nimbus reads into memory", info.active_voxel_count),
            ));
        }
        let mut background = [0f32; 3];
        let mut it = ptr::null_mut();
        // SAFETY: valid grid pointer, a 3-float background buffer and out-pointer.
        let status = unsafe {
            sys::nimbus_leaf_iter_new(self.grid_ptr(index), value_kind(T::KIND), background.as_mut_ptr(), &mut it)
        };
        sys::check(status).map_err(|m| self.grid_error(name, m))?;
        let it = LeafIter(it);
        let background: T = bytemuck::pod_read_unaligned(bytemuck::cast_slice(&background[..T::CHANNELS]));
        let mut volume = Volume::new(transform, background);
        let mut values = vec![T::default(); BRICK_VOXELS];
        let mut mask = [0u64; 8];
        let mut origin = [0i32; 3];
        let values_ptr = bytemuck::cast_slice_mut::<T, f32>(&mut values).as_mut_ptr();
        // SAFETY: the buffers hold 3 ints, 512 * CHANNELS floats and 8 words.
        while unsafe { sys::nimbus_leaf_iter_next(it.0, origin.as_mut_ptr(), values_ptr, mask.as_mut_ptr()) } == 1 {
            volume.insert_brick(IVec3::from(origin), &values, &mask);
        }
        Ok(volume)
    }

    /// Writes `volume` as a float or vec3s grid called `name` (replacing a grid of that
    /// name in place), brick by brick, with its transform and background.
    pub fn insert_volume<T: GridValue>(&mut self, name: &str, volume: &Volume<T>, class: GridClass) -> Result<()> {
        let gerr = |m: String| self.grid_error(name, m);
        let cname = c_string(name, "grid name").map_err(gerr)?;
        let mut background = [0f32; 3];
        background[..T::CHANNELS].copy_from_slice(bytemuck::cast_slice(std::slice::from_ref(&volume.background())));
        let xform = volume.transform().index_to_world().to_cols_array();
        let mut out = ptr::null_mut();
        // SAFETY: valid C string, 3-float background, 12-double transform and out-pointer.
        let status = unsafe {
            sys::nimbus_grid_new(
                value_kind(T::KIND),
                cname.as_ptr(),
                class_to_sys(class),
                background.as_ptr(),
                xform.as_ptr(),
                &mut out,
            )
        };
        let grid = OwnedGrid::from_status(status, out).map_err(gerr)?;
        for brick in volume.bricks() {
            let values: &[f32] = bytemuck::cast_slice(brick.values);
            // SAFETY: 3 ints, 512 * CHANNELS floats and 8 words, all valid for the call.
            let status = unsafe {
                sys::nimbus_grid_add_leaf(grid.as_ptr(), brick.origin.as_ref().as_ptr(), values.as_ptr(), brick.active.as_ptr())
            };
            sys::check(status).map_err(gerr)?;
        }
        self.insert_owned(grid, name)
    }

    /// OpenVDB's `tools::BoxSampler` on grid `name` (float or vec3s) at `points`: the
    /// reference that [`Volume::sample_index`] is tested against.
    pub fn sample_box<T: GridValue>(&self, name: &str, points: &[DVec3], space: Space) -> Result<Vec<T>> {
        let (index, info) = self.find(name)?;
        self.check_kind(&info, T::KIND)?;
        let mut out = vec![T::default(); points.len()];
        let flat: &[f64] = bytemuck::cast_slice(points);
        // SAFETY: points.len() xyz doubles in, points.len() * CHANNELS floats out.
        let status = unsafe {
            sys::nimbus_sample_box(
                self.grid_ptr(index),
                value_kind(T::KIND),
                flat.as_ptr(),
                points.len(),
                i32::from(space == Space::World),
                bytemuck::cast_slice_mut::<T, f32>(&mut out).as_mut_ptr(),
            )
        };
        sys::check(status).map_err(|m| self.grid_error(name, m))?;
        Ok(out)
    }

    pub(crate) fn grid_ptr_by_name(&self, name: &str) -> Result<(*const sys::nimbus_grid, GridInfo)> {
        let (index, info) = self.find(name)?;
        Ok((self.grid_ptr(index), info))
    }

    pub(crate) fn error_for(&self, grid: &str, message: String) -> VdbError {
        self.grid_error(grid, message)
    }

    // ---- metadata ------------------------------------------------------------------------

    /// File-level metadata (nimbus keeps its run parameters here under `nimbus:` keys).
    pub fn metadata(&self) -> Metadata {
        // SAFETY: valid handle; the map is not modified during the call.
        unsafe { meta::read_all(sys::nimbus_file_meta(self.raw.as_ptr())) }
            .expect("reading file metadata by index within its count")
    }

    pub fn set_metadata(&mut self, name: &str, value: impl Into<MetaValue>) -> Result<()> {
        // SAFETY: valid handle, exclusively borrowed.
        unsafe { meta::set(sys::nimbus_file_meta_mut(self.raw.as_ptr()), name, &value.into()) }
            .map_err(|message| VdbError::Write { target: self.label.clone(), message })
    }

    pub fn remove_metadata(&mut self, name: &str) -> Result<()> {
        // SAFETY: valid handle, exclusively borrowed.
        unsafe { meta::remove(sys::nimbus_file_meta_mut(self.raw.as_ptr()), name) }
            .map_err(|message| VdbError::Write { target: self.label.clone(), message })
    }

    fn grid_meta_mut(&mut self, grid: &str) -> Result<*mut sys::nimbus_meta> {
        let (index, _) = self.find(grid)?;
        // SAFETY: valid handle and index.
        Ok(unsafe { sys::nimbus_grid_meta_mut(sys::nimbus_file_grid_mut(self.raw.as_ptr(), index)) })
    }

    /// Sets metadata on grid `grid` (its own metadata: see [`GridInfo::metadata`]).
    pub fn set_grid_metadata(&mut self, grid: &str, name: &str, value: impl Into<MetaValue>) -> Result<()> {
        let m = self.grid_meta_mut(grid)?;
        // SAFETY: a valid map, exclusively borrowed through &mut self.
        unsafe { meta::set(m, name, &value.into()) }.map_err(|msg| self.grid_error(grid, msg))
    }

    pub fn remove_grid_metadata(&mut self, grid: &str, name: &str) -> Result<()> {
        let m = self.grid_meta_mut(grid)?;
        // SAFETY: a valid map, exclusively borrowed through &mut self.
        unsafe { meta::remove(m, name) }.map_err(|msg| self.grid_error(grid, msg))
    }

    /// Sets the vector type of vec3 grid `grid` (OpenVDB's `GridBase::setVectorType`).
    pub fn set_vector_type(&mut self, grid: &str, vector_type: VectorType) -> Result<()> {
        let (index, _) = self.find(grid)?;
        let t = match vector_type {
            VectorType::Invariant => sys::nimbus_vector_type::NIMBUS_VEC_INVARIANT,
            VectorType::Covariant => sys::nimbus_vector_type::NIMBUS_VEC_COVARIANT,
            VectorType::CovariantNormalize => sys::nimbus_vector_type::NIMBUS_VEC_COVARIANT_NORMALIZE,
            VectorType::ContravariantRelative => sys::nimbus_vector_type::NIMBUS_VEC_CONTRAVARIANT_RELATIVE,
            VectorType::ContravariantAbsolute => sys::nimbus_vector_type::NIMBUS_VEC_CONTRAVARIANT_ABSOLUTE,
        };
        // SAFETY: valid handle and index, exclusively borrowed through &mut self.
        let status = unsafe { sys::nimbus_grid_set_vector_type(sys::nimbus_file_grid_mut(self.raw.as_ptr(), index), t) };
        sys::check(status).map_err(|m| self.grid_error(grid, m))
    }

    /// Sets the grid class of grid `grid`.
    pub fn set_grid_class(&mut self, grid: &str, class: GridClass) -> Result<()> {
        let name = match class {
            GridClass::Unknown => "unknown",
            GridClass::LevelSet => "level set",
            GridClass::FogVolume => "fog volume",
            GridClass::Staggered => "staggered",
        };
        self.set_grid_metadata(grid, "class", name)
    }
}

/// Frees the bridge's leaf iterator.
struct LeafIter(*mut sys::nimbus_leaf_iter);
impl Drop for LeafIter {
    fn drop(&mut self) {
        // SAFETY: we own the iterator (null is accepted).
        unsafe { sys::nimbus_leaf_iter_free(self.0) }
    }
}

/// Describes one grid through the bridge.
fn grid_info(grid: *const sys::nimbus_grid) -> Result<GridInfo, String> {
    if grid.is_null() {
        return Err("grid index out of range".into());
    }
    // SAFETY: a valid grid; the info's strings are taken (and freed) below.
    unsafe {
        let mut raw: sys::nimbus_grid_info = std::mem::zeroed();
        sys::check(sys::nimbus_grid_get_info(grid, &mut raw))?;
        let name = sys::take_string(raw.name);
        let grid_type = sys::take_string(raw.type_name);
        let value_type = sys::take_string(raw.value_type);
        let map_type = sys::take_string(raw.map_type);
        let metadata = meta::read_all(sys::nimbus_grid_meta(grid))?;
        let transform = if raw.is_affine != 0 {
            Transform::new(DAffine3::from_cols_array(&raw.index_to_world)).ok()
        } else {
            None
        };
        let index_bbox = (raw.has_bbox != 0).then(|| (IVec3::from(raw.bbox_min), IVec3::from(raw.bbox_max)));
        Ok(GridInfo {
            name,
            value_type,
            grid_type,
            kind: grid_kind(raw.kind),
            class: class_from_sys(raw.grid_class),
            map_type,
            transform,
            active_voxel_count: raw.active_voxel_count,
            index_bbox,
            point_count: raw.point_count,
            saved_as_half: raw.saved_as_half != 0,
            metadata,
        })
    }
}
