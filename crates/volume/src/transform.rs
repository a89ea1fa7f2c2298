//! The index <-> world map of a volume, in f64 as OpenVDB keeps it.

use glam::{DAffine3, DVec3};

use crate::VolumeError;

/// An affine index-to-world map. A voxel's value sits at its integer index coordinate;
/// the voxel size along each index axis is the length of the corresponding basis vector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    index_to_world: DAffine3,
    world_to_index: DAffine3,
}

impl Transform {
    /// Accepts any invertible affine map with finite coefficients.
    pub fn new(index_to_world: DAffine3) -> Result<Transform, VolumeError> {
        let m = index_to_world;
        let finite = m.matrix3.is_finite() && m.translation.is_finite();
        let det = m.matrix3.determinant();
        // A relative test: the determinant scales with voxel volume, so compare against the
        // product of the basis lengths rather than an absolute epsilon.
        let scale = m.matrix3.x_axis.length() * m.matrix3.y_axis.length() * m.matrix3.z_axis.length();
        if !finite || !(det.abs() > 1e-12 * scale) || scale == 0.0 {
            return Err(VolumeError::SingularTransform);
        }
        Ok(Transform { index_to_world: m, world_to_index: m.inverse() })
    }

    /// Uniform voxels of edge `voxel_size`; index (0,0,0) sits at `translation`.
    pub fn uniform(voxel_size: f64, translation: DVec3) -> Transform {
        Transform::new(DAffine3::from_scale_rotation_translation(
            DVec3::splat(voxel_size),
            glam::DQuat::IDENTITY,
            translation,
        ))
        .expect("a uniform transform needs a positive finite voxel size")
    }

    pub fn index_to_world(&self) -> DAffine3 {
        self.index_to_world
    }

    pub fn world_to_index(&self) -> DAffine3 {
        self.world_to_index
    }

    pub fn to_world(&self, index: DVec3) -> DVec3 {
        self.index_to_world.transform_point3(index)
    }

    pub fn to_index(&self, world: DVec3) -> DVec3 {
        self.world_to_index.transform_point3(world)
    }

    /// World direction (not normalised) to index-space direction. Because the map is affine,
    /// a ray x(t) = o + t d keeps its parameter t in both spaces.
    pub fn dir_to_index(&self, world_dir: DVec3) -> DVec3 {
        self.world_to_index.transform_vector3(world_dir)
    }

    pub fn dir_to_world(&self, index_dir: DVec3) -> DVec3 {
        self.index_to_world.transform_vector3(index_dir)
    }

    pub fn voxel_size(&self) -> DVec3 {
        let m = self.index_to_world.matrix3;
        DVec3::new(m.x_axis.length(), m.y_axis.length(), m.z_axis.length())
    }

    /// The distances between a voxel's opposite faces, per index axis: its edge lengths
    /// where the axes are orthogonal, less where they are sheared (a face's normal is not
    /// its edge). The smallest is how thin the voxel is in any direction.
    pub fn voxel_widths(&self) -> DVec3 {
        let m = self.index_to_world.matrix3;
        let volume = m.determinant().abs();
        DVec3::new(
            volume / m.y_axis.cross(m.z_axis).length(),
            volume / m.z_axis.cross(m.x_axis).length(),
            volume / m.x_axis.cross(m.y_axis).length(),
        )
    }

    /// World volume of one voxel.
    pub fn voxel_volume(&self) -> f64 {
        self.index_to_world.matrix3.determinant().abs()
    }
}
