//! OpenVDB points (PointDataGrid) to and from [`PointSet`]: world positions plus named
//! float and vec3 attributes. Photons travel this way (grid `photons`: `P`, `power`,
//! `dir`), and so do Houdini particles (`P`, optionally `mass`).

use std::collections::BTreeMap;
use std::ptr;

use glam::{DVec3, Vec3};

use crate::error::Result;
use crate::file::{c_string, GridInfo, GridKind, OwnedGrid, VdbFile};
use crate::sys;

/// One per-point attribute.
#[derive(Clone, Debug, PartialEq)]
pub enum PointAttribute {
    Float(Vec<f32>),
    Vec3(Vec<Vec3>),
}

impl PointAttribute {
    pub fn len(&self) -> usize {
        match self {
            PointAttribute::Float(v) => v.len(),
            PointAttribute::Vec3(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Points with world positions and attributes, one value per point each.
///
/// Positions are f64 (`DVec3`) because scenes may sit far from the origin. OpenVDB stores
/// a point as its voxel plus a float offset inside it, so a position comes back to within
/// about 1e-7 of a voxel, whatever the offset of the scene. Attribute values are exact.
///
/// Reading returns points in OpenVDB's storage order (leaf by leaf, voxel by voxel), not
/// the order they were written in; positions and attributes stay matched.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointSet {
    pub positions: Vec<DVec3>,
    /// By attribute name. `P` is the positions and never appears here.
    pub attributes: BTreeMap<String, PointAttribute>,
}

impl PointSet {
    pub fn new(positions: Vec<DVec3>) -> PointSet {
        PointSet { positions, attributes: BTreeMap::new() }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn with_float(mut self, name: &str, values: Vec<f32>) -> PointSet {
        self.attributes.insert(name.to_string(), PointAttribute::Float(values));
        self
    }

    pub fn with_vec3(mut self, name: &str, values: Vec<Vec3>) -> PointSet {
        self.attributes.insert(name.to_string(), PointAttribute::Vec3(values));
        self
    }

    /// The float attribute `name`, if there is one of that type.
    pub fn float(&self, name: &str) -> Option<&[f32]> {
        match self.attributes.get(name) {
            Some(PointAttribute::Float(v)) => Some(v),
            _ => None,
        }
    }

    /// The vec3 attribute `name`, if there is one of that type.
    pub fn vec3(&self, name: &str) -> Option<&[Vec3]> {
        match self.attributes.get(name) {
            Some(PointAttribute::Vec3(v)) => Some(v),
            _ => None,
        }
    }
}

impl VdbFile {
    /// Reads an OpenVDB points grid: positions and every float, double, vec3s or vec3d
    /// attribute (any codec; doubles narrowed to f32). Other attribute types (ints,
    /// strings, groups) are skipped.
    pub fn read_points(&self, name: &str) -> Result<PointSet> {
        let (grid, info) = self.grid_ptr_by_name(name)?;
        if info.kind != GridKind::Points {
            return Err(self.error_for(name, format!("has value type {}, expected an OpenVDB points grid", info.value_type)));
        }
        read_points(grid, &info).map_err(|m| self.error_for(name, m))
    }

    /// The point groups of points grid `name` (Houdini's), in descriptor order.
    pub fn point_groups(&self, name: &str) -> Result<Vec<String>> {
        let (grid, info) = self.grid_ptr_by_name(name)?;
        if info.kind != GridKind::Points {
            return Err(self.error_for(name, format!("has value type {}, expected an OpenVDB points grid", info.value_type)));
        }
        let mut names = ptr::null_mut();
        // SAFETY: a valid grid and out-pointer; the string is taken (freed) right after.
        let status = unsafe { sys::nimbus_points_group_names(grid, &mut names) };
        let text = unsafe { sys::take_string(names) };
        sys::check(status).map_err(|m| self.error_for(name, m))?;
        Ok(text.lines().map(str::to_string).collect())
    }

    /// Membership of each point of grid `name` in point group `group`, in the order of
    /// [`VdbFile::read_points`].
    pub fn read_point_group(&self, name: &str, group: &str) -> Result<Vec<bool>> {
        let (grid, info) = self.grid_ptr_by_name(name)?;
        let n = usize::try_from(info.point_count).map_err(|_| self.error_for(name, "too many points for this machine".into()))?;
        let cgroup = c_string(group, "group name").map_err(|m| self.error_for(name, m))?;
        let mut out = vec![0u8; n];
        // SAFETY: n bytes out.
        let status = unsafe { sys::nimbus_points_read_group(grid, cgroup.as_ptr(), out.as_mut_ptr(), n) };
        sys::check(status).map_err(|m| self.error_for(name, m))?;
        Ok(out.into_iter().map(|b| b != 0).collect())
    }

    /// Writes `points` as an OpenVDB points grid called `name` (replacing a grid of that
    /// name). `voxel_size` None picks one for about 8 points per voxel.
    pub fn insert_points(&mut self, name: &str, points: &PointSet, voxel_size: Option<f64>) -> Result<()> {
        let grid = build_points(name, points, voxel_size).map_err(|m| self.error_for(name, m))?;
        self.insert_owned(grid, name)
    }
}

fn read_points(grid: *const sys::nimbus_grid, info: &GridInfo) -> Result<PointSet, String> {
    let n = usize::try_from(info.point_count).map_err(|_| "too many points for this machine".to_string())?;
    let mut positions = vec![DVec3::ZERO; n];
    // SAFETY: n xyz doubles.
    sys::check(unsafe {
        sys::nimbus_points_read_positions(grid, bytemuck::cast_slice_mut::<DVec3, f64>(&mut positions).as_mut_ptr(), n)
    })?;
    let mut set = PointSet::new(positions);

    // SAFETY: a valid points grid.
    let count = unsafe { sys::nimbus_points_attribute_count(grid) };
    for index in 0..count {
        let (mut aname, mut atype, mut codec) = (ptr::null_mut(), ptr::null_mut(), ptr::null_mut());
        let mut kind = sys::nimbus_value_kind::NIMBUS_VALUE_OTHER;
        // SAFETY: valid out-pointers; the strings are taken (freed) right after.
        let status = unsafe { sys::nimbus_points_attribute_info(grid, index, &mut aname, &mut atype, &mut codec, &mut kind) };
        let (aname, _atype, _codec) = unsafe { (sys::take_string(aname), sys::take_string(atype), sys::take_string(codec)) };
        sys::check(status)?;
        if aname == "P" {
            continue;
        }
        let cname = c_string(&aname, "attribute name")?;
        let attribute = match kind {
            sys::nimbus_value_kind::NIMBUS_VALUE_FLOAT => {
                let mut v = vec![0f32; n];
                // SAFETY: n floats.
                sys::check(unsafe { sys::nimbus_points_read_attribute(grid, cname.as_ptr(), kind, v.as_mut_ptr(), n) })?;
                PointAttribute::Float(v)
            }
            sys::nimbus_value_kind::NIMBUS_VALUE_VEC3F => {
                let mut v = vec![Vec3::ZERO; n];
                let out = bytemuck::cast_slice_mut::<Vec3, f32>(&mut v).as_mut_ptr();
                // SAFETY: n * 3 floats.
                sys::check(unsafe { sys::nimbus_points_read_attribute(grid, cname.as_ptr(), kind, out, n) })?;
                PointAttribute::Vec3(v)
            }
            _ => continue,
        };
        set.attributes.insert(aname, attribute);
    }
    Ok(set)
}

fn build_points(name: &str, points: &PointSet, voxel_size: Option<f64>) -> Result<OwnedGrid, String> {
    let cname = c_string(name, "grid name")?;
    let n = points.len();
    for (attr, values) in &points.attributes {
        if values.len() != n {
            return Err(format!("attribute '{attr}' has {} values for {n} points", values.len()));
        }
    }
    if let Some(i) = points.positions.iter().position(|p| !p.is_finite()) {
        return Err(format!("point {i} has a non-finite position {}", points.positions[i]));
    }
    let mut out = ptr::null_mut();
    let flat: &[f64] = bytemuck::cast_slice(&points.positions);
    // SAFETY: n xyz doubles and an out-pointer.
    let status = unsafe { sys::nimbus_points_new(cname.as_ptr(), flat.as_ptr(), n, voxel_size.unwrap_or(0.0), &mut out) };
    let grid = OwnedGrid::from_status(status, out)?;
    for (attr, values) in &points.attributes {
        let cattr = c_string(attr, "attribute name")?;
        let (kind, data): (_, &[f32]) = match values {
            PointAttribute::Float(v) => (sys::nimbus_value_kind::NIMBUS_VALUE_FLOAT, v),
            PointAttribute::Vec3(v) => (sys::nimbus_value_kind::NIMBUS_VALUE_VEC3F, bytemuck::cast_slice(v)),
        };
        // SAFETY: n values of the given kind.
        sys::check(unsafe { sys::nimbus_points_add_attribute(grid.as_ptr(), cattr.as_ptr(), kind, data.as_ptr(), n) })?;
    }
    Ok(grid)
}
