//! The host mirrors of WGSL structs, checked against the WGSL through naga.
//!
//! Every `#[repr(C)]` + `Pod` struct a stage uploads has a WGSL twin of the same bytes. A
//! stage's tests describe the host side with [`host_layout!`] (field names, offsets, sizes
//! and types, all from the compiler) and hand it, with the WGSL struct's name, to
//! [`check_layouts`] together with the shader source exactly as the stage builds it for its
//! pipeline. naga parses that source and lays the struct out; the check fails, naming both
//! structs and the field, when
//!
//! - a field is missing on either side, renamed or in another order,
//! - a field's offset or size differs, or its scalars do (`f32` against `u32`, a `vec3<f32>`
//!   against `[i32; 3]`; arrays, vectors and matrices compare element for element, so
//!   `array<vec4<f32>, 2>` matches `[f32; 8]`),
//! - the struct's size (naga's span) differs.
//!
//! Fields whose names start with `_` are padding: they are not matched by name, and only
//! the bytes the other fields leave over (equal, since offsets and the span are) are theirs.
//! A field whose type is a struct is compared by size; its own struct has its own check.
//! Pod structs have no implicit padding, so the listed fields must tile the host struct:
//! leaving one out of [`host_layout!`] is an error too.

use std::fmt::Write as _;

use naga::proc::Layouter;
use naga::{ArraySize, Handle, Module, Scalar, ScalarKind, Type, TypeInner};

/// One field of a host struct, as [`host_layout!`] records it.
#[derive(Clone, Debug)]
pub struct HostField {
    pub name: &'static str,
    pub offset: usize,
    pub size: usize,
    /// `std::any::type_name` of the field's type: `f32`, `[f32; 3]`, `[[f32; 4]; 4]`, a path.
    pub ty: &'static str,
}

/// A host struct's layout: its name, size and fields in declaration order.
#[derive(Clone, Debug)]
pub struct HostStruct {
    pub name: &'static str,
    pub size: usize,
    pub fields: Vec<HostField>,
}

/// The size and type name of the value `_field` returns (never called): how
/// [`host_layout!`] learns a field's type without an instance.
#[doc(hidden)]
pub fn field_of<T, F>(_field: fn(T) -> F) -> (usize, &'static str) {
    (std::mem::size_of::<F>(), std::any::type_name::<F>())
}

/// The [`HostStruct`] of `Type { field, field, ... }`; list every field, padding included,
/// in declaration order.
///
/// ```
/// #[repr(C)]
/// #[derive(Clone, Copy)]
/// struct GpuThing { position: [f32; 3], count: u32 }
/// let host = nimbus_gpu::host_layout!(GpuThing { position, count });
/// nimbus_gpu::wgsl_layout::check_layouts(
///     "struct Thing { position: vec3<f32>, count: u32, }",
///     &[("Thing", host)],
/// );
/// ```
#[macro_export]
macro_rules! host_layout {
    ($t:ty { $($field:ident),+ $(,)? }) => {
        $crate::wgsl_layout::HostStruct {
            name: stringify!($t),
            size: ::std::mem::size_of::<$t>(),
            fields: vec![$({
                let (size, ty) = $crate::wgsl_layout::field_of(|s: $t| s.$field);
                $crate::wgsl_layout::HostField { name: stringify!($field), offset: ::std::mem::offset_of!($t, $field), size, ty }
            }),+],
        }
    };
}

/// Parses `source` with naga (the compiler inside wgpu) and checks each `(wgsl_name, host)`
/// pair; panics with every difference found, each naming the two structs and the field.
pub fn check_layouts(source: &str, pairs: &[(&str, HostStruct)]) {
    let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("the WGSL does not parse:\n{}", e.emit_to_string(source)));
    let mut layouter = Layouter::default();
    layouter.update(module.to_ctx()).unwrap_or_else(|e| panic!("naga cannot lay out the WGSL: {e}"));
    let errors: Vec<String> = pairs.iter().filter_map(|(name, host)| compare(&module, &layouter, name, host).err()).collect();
    assert!(errors.is_empty(), "host structs differ from their WGSL twins:\n{}", errors.join("\n"));
}

/// One pair: `Err` lists every difference.
pub fn compare(module: &Module, layouter: &Layouter, wgsl_name: &str, host: &HostStruct) -> Result<(), String> {
    let title = format!("host {} vs WGSL {wgsl_name}", host.name);
    let Some((members, span)) = module.types.iter().find_map(|(_, ty)| match &ty.inner {
        TypeInner::Struct { members, span } if ty.name.as_deref() == Some(wgsl_name) => Some((members, *span)),
        _ => None,
    }) else {
        return Err(format!("{title}: the WGSL has no struct {wgsl_name}"));
    };
    let mut errors = Vec::new();

    // The host list must tile the struct (Pod: no implicit padding), so no field is left out.
    let mut end = 0;
    for f in &host.fields {
        if f.offset != end {
            errors.push(format!("host field `{}` at offset {} where {end} was expected: list every field of {} in declaration order", f.name, f.offset, host.name));
        }
        end = f.offset + f.size;
    }
    if end != host.size {
        errors.push(format!("the listed host fields end at {end}, {} is {} bytes: a field is missing from the list", host.name, host.size));
    }

    if span as usize != host.size {
        errors.push(format!("size: host {} bytes, WGSL {span}", host.size));
    }

    let wgsl: Vec<(&str, u32, u32, Handle<Type>)> =
        members.iter().map(|m| (m.name.as_deref().unwrap_or(""), m.offset, layouter[m.ty].size, m.ty)).filter(|m| !m.0.starts_with('_')).collect();
    let hosts: Vec<&HostField> = host.fields.iter().filter(|f| !f.name.starts_with('_')).collect();
    for i in 0..wgsl.len().max(hosts.len()) {
        match (hosts.get(i), wgsl.get(i)) {
            (Some(h), Some(&(name, offset, size, ty))) => {
                if h.name != name {
                    errors.push(format!("field {i}: host `{}` (offset {}), WGSL `{name}` (offset {offset})", h.name, h.offset));
                    continue;
                }
                let mut diff = String::new();
                if h.offset != offset as usize {
                    let _ = write!(diff, " offset host {} WGSL {offset};", h.offset);
                }
                if h.size != size as usize {
                    let _ = write!(diff, " size host {} WGSL {size};", h.size);
                }
                let (host_scalars, wgsl_scalars) = (host_scalars(h.ty), wgsl_scalars(module, layouter, ty));
                if host_scalars != wgsl_scalars {
                    let _ = write!(diff, " type host {} WGSL {};", h.ty, describe(module, ty));
                }
                if !diff.is_empty() {
                    errors.push(format!("field `{name}`:{}", diff.trim_end_matches(';')));
                }
            }
            (Some(h), None) => errors.push(format!("field `{}` (host offset {}) has no WGSL twin", h.name, h.offset)),
            (None, Some(&(name, offset, ..))) => errors.push(format!("field `{name}` (WGSL offset {offset}) has no host twin")),
            (None, None) => unreachable!(),
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(errors.iter().map(|e| format!("  {title}: {e}")).collect::<Vec<_>>().join("\n"))
    }
}

/// A value's 4-byte words as scalar kinds (`None` in a hole: array stride beyond the
/// element); `None` for a struct, which is compared by size only.
type Words = Option<Vec<Option<&'static str>>>;

fn scalar_name(s: Scalar) -> &'static str {
    match (s.kind, s.width) {
        (ScalarKind::Float, 4) => "f32",
        (ScalarKind::Uint, 4) => "u32",
        (ScalarKind::Sint, 4) => "i32",
        (ScalarKind::Float, 2) => "f16",
        (ScalarKind::Float, 8) => "f64",
        (ScalarKind::Uint, 8) => "u64",
        (ScalarKind::Sint, 8) => "i64",
        (ScalarKind::Bool, _) => "bool",
        _ => "?",
    }
}

fn words(scalar: &'static str, count: usize) -> Vec<Option<&'static str>> {
    vec![Some(scalar); count]
}

fn wgsl_scalars(module: &Module, layouter: &Layouter, ty: Handle<Type>) -> Words {
    match &module.types[ty].inner {
        TypeInner::Scalar(s) | TypeInner::Atomic(s) => Some(words(scalar_name(*s), 1)),
        TypeInner::Vector { size, scalar } => Some(words(scalar_name(*scalar), *size as usize)),
        TypeInner::Matrix { columns, rows, scalar } => {
            // Columns are vectors of `rows` aligned as vec4 for 3 rows: pad the hole.
            let column_words = (layouter[ty].size as usize / 4) / *columns as usize;
            let mut out = Vec::new();
            for _ in 0..*columns as usize {
                out.extend(words(scalar_name(*scalar), *rows as usize));
                out.extend(vec![None; column_words - *rows as usize]);
            }
            Some(out)
        }
        TypeInner::Array { base, size: ArraySize::Constant(n), stride } => {
            let element = wgsl_scalars(module, layouter, *base)?;
            let hole = (*stride as usize / 4).saturating_sub(element.len());
            let mut out = Vec::new();
            for _ in 0..n.get() {
                out.extend(element.iter().copied());
                out.extend(vec![None; hole]);
            }
            Some(out)
        }
        _ => None,
    }
}

/// The same words from a host field's `type_name`: scalars and nested arrays of them.
fn host_scalars(ty: &str) -> Words {
    match ty {
        "f32" | "u32" | "i32" | "f64" | "u64" | "i64" | "bool" => Some(words(["f32", "u32", "i32", "f64", "u64", "i64", "bool"].into_iter().find(|s| *s == ty).unwrap_or("?"), 1)),
        _ if ty.starts_with('[') && ty.ends_with(']') => {
            let inner = &ty[1..ty.len() - 1];
            let (element, n) = inner.rsplit_once("; ")?;
            let element = host_scalars(element)?;
            Some(element.repeat(n.trim().parse().ok()?))
        }
        _ => None,
    }
}

/// A WGSL type as written, for messages.
fn describe(module: &Module, ty: Handle<Type>) -> String {
    let t = &module.types[ty];
    if let Some(name) = &t.name {
        return name.clone();
    }
    match &t.inner {
        TypeInner::Scalar(s) => scalar_name(*s).to_string(),
        TypeInner::Atomic(s) => format!("atomic<{}>", scalar_name(*s)),
        TypeInner::Vector { size, scalar } => format!("vec{}<{}>", *size as u8, scalar_name(*scalar)),
        TypeInner::Matrix { columns, rows, scalar } => format!("mat{}x{}<{}>", *columns as u8, *rows as u8, scalar_name(*scalar)),
        TypeInner::Array { base, size: ArraySize::Constant(n), .. } => format!("array<{}, {n}>", describe(module, *base)),
        other => format!("{other:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[repr(C)]
    #[derive(Clone, Copy)]
    struct GpuThing {
        position: [f32; 3],
        count: u32,
        matrix: [[f32; 4]; 4],
        eight: [f32; 8],
        _pad: [u32; 4],
    }

    const THING: &str = "struct Thing { position: vec3<f32>, count: u32, matrix: mat4x4<f32>, eight: array<vec4<f32>, 2>, _pad0: u32, _pad1: u32, _pad2: u32, _pad3: u32, }";

    fn errors(source: &str, host: HostStruct) -> String {
        let module = naga::front::wgsl::parse_str(source).unwrap();
        let mut layouter = Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        compare(&module, &layouter, "Thing", &host).err().unwrap_or_default()
    }

    #[test]
    fn a_matching_struct_passes() {
        check_layouts(THING, &[("Thing", host_layout!(GpuThing { position, count, matrix, eight, _pad }))]);
    }

    #[test]
    fn a_retyped_field_is_named() {
        let e = errors(&THING.replace("count: u32", "count: f32"), host_layout!(GpuThing { position, count, matrix, eight, _pad }));
        assert!(e.contains("host GpuThing vs WGSL Thing: field `count`: type host u32 WGSL f32"), "{e}");
    }

    #[test]
    fn reordered_fields_are_named() {
        let e = errors(
            "struct Thing { count: u32, position: vec3<f32>, matrix: mat4x4<f32>, eight: array<vec4<f32>, 2>, _pad0: u32, _pad1: u32, _pad2: u32, _pad3: u32, }",
            host_layout!(GpuThing { position, count, matrix, eight, _pad }),
        );
        assert!(e.contains("field 0: host `position` (offset 0), WGSL `count` (offset 0)"), "{e}");
    }

    #[test]
    fn a_size_or_offset_difference_is_named() {
        // vec3 then vec4 alignment: every later offset moves, and the span.
        let e = errors(&THING.replace("count: u32,", ""), host_layout!(GpuThing { position, count, matrix, eight, _pad }));
        assert!(e.contains("field 1: host `count`"), "{e}");
        let e = errors(&THING.replace("array<vec4<f32>, 2>", "array<vec3<f32>, 2>"), host_layout!(GpuThing { position, count, matrix, eight, _pad }));
        assert!(e.contains("field `eight`: type host [f32; 8] WGSL array<vec3<f32>, 2>"), "{e}");
        let e = errors(&THING.replace("_pad3: u32,", "_pad3: u32, extra: u32,"), host_layout!(GpuThing { position, count, matrix, eight, _pad }));
        assert!(e.contains("size: host 128 bytes, WGSL 144") && e.contains("field `extra` (WGSL offset 128) has no host twin"), "{e}");
    }

    #[test]
    fn a_field_left_out_of_the_list_is_an_error() {
        let e = errors(THING, host_layout!(GpuThing { position, matrix, eight, _pad }));
        assert!(e.contains("host field `matrix` at offset 16 where 12 was expected"), "{e}");
    }

    #[test]
    fn a_missing_struct_is_named() {
        let e = errors("struct Other { x: f32, }", host_layout!(GpuThing { position, count, matrix, eight, _pad }));
        assert!(e.contains("the WGSL has no struct Thing"), "{e}");
    }
}
