//! What the density tests share: particle sets with every case of the adaptive lengths.

#![allow(dead_code)]

use glam::DVec3;
use nimbus_density::analytic::Rng;
use nimbus_density::ParticleSet;

/// Two clumps of very different density plus a sparse background, so every case of the
/// corrector (too few, too many, an empty shell) occurs somewhere: of every `period`
/// particles, all but two in a tight clump at (3, 3, 3), one in the wide clump `wide`
/// (centre, spread), one anywhere in [0, `extent`]^3; masses 0.5 to 2.
pub fn clumpy(n: usize, seed: u64, period: usize, wide: (DVec3, f64), extent: f64) -> ParticleSet {
    let mut rng = Rng::new(seed, 0);
    let positions = (0..n)
        .map(|i| {
            let g = DVec3::new(rng.normal(), rng.normal(), rng.normal());
            match i % period {
                k if k + 2 < period => DVec3::new(3.0, 3.0, 3.0) + 0.6 * g,
                k if k + 2 == period => wide.0 + wide.1 * g,
                _ => DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * extent,
            }
        })
        .collect();
    let masses = Some((0..n).map(|i| 0.5 + (i % 7) as f32 * 0.25).collect());
    ParticleSet { positions, masses, ..Default::default() }
}
