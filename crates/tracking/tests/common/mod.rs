//! What the tests of the tables share: the medium they are built through.

use glam::{DVec3, IVec3};
use nimbus_volume::{Transform, Volume};

/// A lumpy blob: a Gaussian with two denser knots, on `transform`'s lattice over index box
/// [-n, n]^3.
pub fn blob(transform: Transform, n: i32) -> Volume<f32> {
    let mut v = Volume::new(transform, 0.0);
    for x in -n..=n {
        for y in -n..=n {
            for z in -n..=n {
                let p = IVec3::new(x, y, z).as_dvec3() / n as f64;
                let g = |c: DVec3, s: f64| (-(p - c).length_squared() / (s * s)).exp();
                let d = g(DVec3::ZERO, 0.5) + 3.0 * g(DVec3::new(0.3, -0.2, 0.1), 0.15) + 2.0 * g(DVec3::new(-0.35, 0.3, -0.2), 0.1);
                if d > 1e-3 {
                    v.set(IVec3::new(x, y, z), d as f32);
                }
            }
        }
    }
    v
}
