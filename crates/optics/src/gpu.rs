//! Uniform/storage layouts shared with `shaders/optics.wgsl`.
//!
//! Each struct is `#[repr(C)]` + `Pod` and laid out so its WGSL twin has the same bytes in
//! both the uniform (std140-like) and storage (std430-like) address spaces: every `vec3` is
//! followed by a 4-byte scalar filling its 16-byte slot, and sizes are multiples of 16. The
//! tests check sizes and field offsets against naga's layout of the WGSL source.
//!
//! Positions go to the GPU as f32 *relative to a host-chosen origin* (the same one handed to
//! `nimbus_gpu::GpuVolume::set_world_origin`), so scenes far from the world origin keep
//! their precision.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;

use crate::{Camera, Light, Medium};

/// WGSL `Medium` (32 bytes).
///
/// ```wgsl
/// struct Medium {
///     albedo: vec3<f32>,   // offset  0
///     extinction: f32,     // offset 12
///     g: f32,              // offset 16
///     albedo_mean: f32,    // offset 20, Russian-roulette survival probability
///     _pad0: f32,          // offset 24
///     _pad1: f32,          // offset 28
/// }
/// ```
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GpuMedium {
    pub albedo: [f32; 3],
    pub extinction: f32,
    pub g: f32,
    pub albedo_mean: f32,
    pub _pad: [f32; 2],
}

impl From<&Medium> for GpuMedium {
    fn from(m: &Medium) -> Self {
        GpuMedium { albedo: m.albedo.to_array(), extinction: m.extinction, g: m.g, albedo_mean: m.albedo_mean(), _pad: [0.0; 2] }
    }
}

/// WGSL `Light` (32 bytes); `kind` is `LIGHT_SUN` (0) or `LIGHT_POINT` (1).
///
/// ```wgsl
/// struct Light {
///     vector: vec3<f32>,   // offset  0: sun: direction travelled (unit); point: position - origin
///     kind: u32,           // offset 12
///     power: vec3<f32>,    // offset 16: sun: irradiance E; point: intensity I
///     disc: f32,           // offset 28: sun: 1 - cos(half its angle), 0 parallel; point: 0
/// }
/// ```
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    pub vector: [f32; 3],
    pub kind: u32,
    pub power: [f32; 3],
    /// A sun's disc as 1 - cos of its angular radius (0: parallel light).
    pub disc: f32,
}

pub const LIGHT_SUN: u32 = 0;
pub const LIGHT_POINT: u32 = 1;

impl GpuLight {
    /// The light with positions taken relative to `origin`.
    pub fn new(light: &Light, origin: DVec3) -> Self {
        match *light {
            Light::Sun { dir, irradiance, angle } => {
                GpuLight { vector: dir.to_array(), kind: LIGHT_SUN, power: irradiance.to_array(), disc: 1.0 - (0.5 * angle).to_radians().cos() }
            }
            Light::Point { position, intensity } => {
                GpuLight { vector: (position - origin).as_vec3().to_array(), kind: LIGHT_POINT, power: intensity.to_array(), disc: 0.0 }
            }
        }
    }
}

/// WGSL `Camera` (64 bytes): the frame [`Camera::ray`] uses, in f32.
///
/// ```wgsl
/// struct Camera {
///     eye: vec3<f32>,      // offset  0: eye - origin
///     width: f32,          // offset 12: pixels
///     forward: vec3<f32>,  // offset 16: unit
///     height: f32,         // offset 28
///     right: vec3<f32>,    // offset 32: unit image right
///     tan_half_fov_x: f32, // offset 44
///     up: vec3<f32>,       // offset 48: unit image up (orthogonalised)
///     tan_half_fov_y: f32, // offset 60
/// }
/// ```
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GpuCamera {
    pub eye: [f32; 3],
    pub width: f32,
    pub forward: [f32; 3],
    pub height: f32,
    pub right: [f32; 3],
    pub tan_half_fov_x: f32,
    pub up: [f32; 3],
    pub tan_half_fov_y: f32,
}

impl GpuCamera {
    /// The camera with its eye taken relative to `origin`.
    pub fn new(camera: &Camera, origin: DVec3) -> Self {
        let tan = camera.tan_half_fov().as_vec2();
        GpuCamera {
            eye: (camera.eye() - origin).as_vec3().to_array(),
            width: camera.width() as f32,
            forward: camera.forward().as_vec3().to_array(),
            height: camera.height() as f32,
            right: camera.right().as_vec3().to_array(),
            tan_half_fov_x: tan.x,
            up: camera.image_up().as_vec3().to_array(),
            tan_half_fov_y: tan.y,
        }
    }
}
