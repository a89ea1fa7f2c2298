//! Small sampling routines the stages share (all mirrored in `shaders/optics.wgsl`).

use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use glam::{Vec2, Vec3};

/// Two unit vectors `(t, b)` completing the unit vector `n` to a right-handed orthonormal
/// frame (t, b, n). Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT 2017), as
/// pbrt-v4's `CoordinateSystem`: branch-free apart from the sign, and continuous everywhere
/// except across n.z = 0's sign flip. The sign is taken with `>= 0` rather than `copysign`
/// so that -0.0 behaves like +0.0, as WGSL's `select` does.
#[inline]
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), Vec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// A direction uniform over the unit sphere (pdf 1 / 4 pi): a point light's photon.
#[inline]
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A point uniform over the unit disc (pdf 1 / pi), by Shirley and Chiu's concentric map as
/// in pbrt-v4: it keeps neighbouring `u` neighbouring, so stratified samples stay stratified.
#[inline]
pub fn sample_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() { (o.x, FRAC_PI_4 * (o.y / o.x)) } else { (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y)) };
    r * Vec2::new(theta.cos(), theta.sin())
}
