//! File and grid metadata: the value types nimbus reads and writes.

use std::collections::BTreeMap;
use std::ffi::CString;

use glam::{DVec3, IVec3, Vec3};

use crate::sys;

/// A metadata value. OpenVDB's other metadata types (matrices, vec2, ...) are skipped
/// when reading, not reported as errors.
#[derive(Clone, Debug, PartialEq)]
pub enum MetaValue {
    String(String),
    Bool(bool),
    I32(i32),
    I64(i64),
    F32(f32),
    F64(f64),
    Vec3I(IVec3),
    Vec3F(Vec3),
    Vec3D(DVec3),
}

/// Metadata by name, in name order (as OpenVDB's MetaMap keeps it).
pub type Metadata = BTreeMap<String, MetaValue>;

impl MetaValue {
    pub fn as_str(&self) -> Option<&str> {
        match self {
            MetaValue::String(s) => Some(s),
            _ => None,
        }
    }

    /// Any integer value as i64.
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            MetaValue::I32(v) => Some(v.into()),
            MetaValue::I64(v) => Some(v),
            _ => None,
        }
    }

    /// Any integer or float value as f64.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            MetaValue::F32(v) => Some(v.into()),
            MetaValue::F64(v) => Some(v),
            MetaValue::I32(v) => Some(v.into()),
            MetaValue::I64(v) => Some(v as f64),
            _ => None,
        }
    }

    /// Any vec3 value as DVec3.
    pub fn as_dvec3(&self) -> Option<DVec3> {
        match *self {
            MetaValue::Vec3I(v) => Some(v.as_dvec3()),
            MetaValue::Vec3F(v) => Some(v.as_dvec3()),
            MetaValue::Vec3D(v) => Some(v),
            _ => None,
        }
    }
}

macro_rules! meta_from {
    ($($t:ty => $variant:ident),* $(,)?) => {$(
        impl From<$t> for MetaValue {
            fn from(v: $t) -> Self { MetaValue::$variant(v.into()) }
        }
    )*};
}
meta_from!(String => String, &str => String, bool => Bool, i32 => I32, i64 => I64, f32 => F32,
           f64 => F64, IVec3 => Vec3I, Vec3 => Vec3F, DVec3 => Vec3D);

/// Reads every convertible entry of a bridge metadata map.
///
/// # Safety
/// `meta` is a valid map from the bridge, not modified during the call.
pub(crate) unsafe fn read_all(meta: *const sys::nimbus_meta) -> Result<Metadata, String> {
    let mut out = Metadata::new();
    for i in 0..sys::nimbus_meta_count(meta) {
        let mut v: sys::nimbus_meta_value = std::mem::zeroed();
        sys::check(sys::nimbus_meta_get(meta, i, &mut v))?;
        let name = std::ffi::CStr::from_ptr(v.name).to_string_lossy().into_owned();
        let [x, y, z] = v.v;
        let value = match v.kind {
            sys::nimbus_meta_kind::NIMBUS_META_STRING => {
                let bytes = if v.str_len == 0 {
                    &[][..]
                } else {
                    std::slice::from_raw_parts(v.str_.cast::<u8>(), v.str_len)
                };
                MetaValue::String(String::from_utf8_lossy(bytes).into_owned())
            }
            sys::nimbus_meta_kind::NIMBUS_META_BOOL => MetaValue::Bool(v.i != 0),
            sys::nimbus_meta_kind::NIMBUS_META_I32 => MetaValue::I32(v.i as i32),
            sys::nimbus_meta_kind::NIMBUS_META_I64 => MetaValue::I64(v.i),
            sys::nimbus_meta_kind::NIMBUS_META_F32 => MetaValue::F32(v.f as f32),
            sys::nimbus_meta_kind::NIMBUS_META_F64 => MetaValue::F64(v.f),
            sys::nimbus_meta_kind::NIMBUS_META_VEC3I => MetaValue::Vec3I(IVec3::new(x as i32, y as i32, z as i32)),
            sys::nimbus_meta_kind::NIMBUS_META_VEC3F => MetaValue::Vec3F(Vec3::new(x as f32, y as f32, z as f32)),
            sys::nimbus_meta_kind::NIMBUS_META_VEC3D => MetaValue::Vec3D(DVec3::new(x, y, z)),
            _ => continue, // a type nimbus does not use: skipped by design
        };
        out.insert(name, value);
    }
    Ok(out)
}

/// Inserts or replaces one entry.
///
/// # Safety
/// `meta` is a valid, exclusively borrowed map from the bridge.
pub(crate) unsafe fn set(meta: *mut sys::nimbus_meta, name: &str, value: &MetaValue) -> Result<(), String> {
    use sys::nimbus_meta_kind as K;
    let cname = CString::new(name).map_err(|_| format!("metadata name {name:?} contains a NUL byte"))?;
    let mut v: sys::nimbus_meta_value = std::mem::zeroed();
    v.name = cname.as_ptr();
    v.kind = match value {
        MetaValue::String(s) => {
            v.str_ = s.as_ptr().cast();
            v.str_len = s.len();
            K::NIMBUS_META_STRING
        }
        MetaValue::Bool(b) => {
            v.i = i64::from(*b);
            K::NIMBUS_META_BOOL
        }
        MetaValue::I32(i) => {
            v.i = i64::from(*i);
            K::NIMBUS_META_I32
        }
        MetaValue::I64(i) => {
            v.i = *i;
            K::NIMBUS_META_I64
        }
        MetaValue::F32(f) => {
            v.f = f64::from(*f);
            K::NIMBUS_META_F32
        }
        MetaValue::F64(f) => {
            v.f = *f;
            K::NIMBUS_META_F64
        }
        MetaValue::Vec3I(p) => {
            v.v = p.as_dvec3().to_array();
            K::NIMBUS_META_VEC3I
        }
        MetaValue::Vec3F(p) => {
            v.v = p.as_dvec3().to_array();
            K::NIMBUS_META_VEC3F
        }
        MetaValue::Vec3D(p) => {
            v.v = p.to_array();
            K::NIMBUS_META_VEC3D
        }
    };
    sys::check(sys::nimbus_meta_set(meta, &v))
}

/// Removes `name` if present.
///
/// # Safety
/// `meta` is a valid, exclusively borrowed map from the bridge.
pub(crate) unsafe fn remove(meta: *mut sys::nimbus_meta, name: &str) -> Result<(), String> {
    let cname = CString::new(name).map_err(|_| format!("metadata name {name:?} contains a NUL byte"))?;
    sys::check(sys::nimbus_meta_remove(meta, cname.as_ptr()))
}
