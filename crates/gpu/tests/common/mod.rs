//! Shared by the GPU tests and the sampling bench: a device (or a loud skip), a small
//! deterministic RNG, and random sparse volumes.
#![allow(dead_code)] // each test binary uses a different subset

use glam::{DVec3, IVec3, Vec3};
use nimbus_gpu::GpuContext;
use nimbus_volume::{Transform, Volume, BRICK_DIM, BRICK_VOXELS};

/// The process-wide test device (see [`nimbus_gpu::test_context`]).
pub fn gpu() -> Option<&'static GpuContext> {
    nimbus_gpu::test_context()
}

/// SplitMix64: enough randomness for test data, and reproducible.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32)
    }

    pub fn below(&mut self, n: u32) -> u32 {
        (self.next_u64() % u64::from(n)) as u32
    }

    pub fn point_in(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        Vec3::new(self.range(lo.x, hi.x), self.range(lo.y, hi.y), self.range(lo.z, hi.z))
    }
}

/// A sparse volume of random values in [-1, 2) over about `bricks` bricks chosen at random
/// (some neighbours, some isolated, negative coordinates included) in a 6x5x6-brick region,
/// with random activity masks and a non-zero background.
pub fn random_sparse_volume(rng: &mut Rng, bricks: usize) -> Volume<f32> {
    let transform = Transform::uniform(0.5, DVec3::new(10.0, -3.0, 2.5));
    let mut volume = Volume::new(transform, 0.25f32);
    for _ in 0..bricks {
        let coord = IVec3::new(rng.below(6) as i32 - 2, rng.below(5) as i32 - 1, rng.below(6) as i32 - 3);
        let values: Vec<f32> = (0..BRICK_VOXELS).map(|_| rng.range(-1.0, 2.0)).collect();
        let active: [u64; 8] = std::array::from_fn(|_| rng.next_u64());
        volume.insert_brick(coord * BRICK_DIM, &values, &active);
    }
    volume
}

/// Index-space box around the volume's bricks, grown by `margin` voxels.
pub fn brick_bounds(volume: &Volume<f32>, margin: f32) -> (Vec3, Vec3) {
    volume.bricks().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), b| {
        let o = b.origin.as_vec3();
        (lo.min(o - margin), hi.max(o + BRICK_DIM as f32 + margin))
    })
}
