//! Counter-based random numbers (design.md section 7 "Reproducible").
//!
//! Every random choice in nimbus is keyed by `(seed, item index)`: photon `i` of a run, voxel
//! `i` of the cache, pixel `i` of the image. [`Rng::new`] builds a generator from that pair
//! alone, so a thread picks up any item without knowing how many numbers other items drew,
//! and the CPU (rayon, any thread count) and the GPU (one invocation per item) produce the
//! same numbers.
//!
//! # Generator: Philox4x32-10
//!
//! Salmon, Moraes, Dror and Shaw, "Parallel Random Numbers: As Easy as 1, 2, 3" (SC 2011).
//! Philox is a keyed bijection on 128-bit counters built from ten rounds of 32x32->64-bit
//! multiplies and xors. Chosen because
//! - quality is established, not argued: Philox4x32-10 passes TestU01's BigCrush for every
//!   counter/key pattern its authors tried (including the structured, incrementing counters
//!   used here), with three rounds to spare (7 already pass); it is what cuRAND, JAX/XLA,
//!   TensorFlow and numpy's `Philox` ship.
//! - it needs only u32 arithmetic: the high half of a 32x32 product is emulated in WGSL from
//!   16-bit halves (`philox_mulhilo` in `optics.wgsl`), so the GPU result is bit-exact.
//! - a 2^64 key and a 2^128 counter hold the seed, the item index, a domain tag and a
//!   draw counter without hashing them together first, so distinct keys and counters can
//!   never collide (a bijection cannot), unlike a hash of (seed, index).
//!
//! Layout: key = (seed lo, seed hi); counter = (block, domain, index lo, index hi). Each
//! block gives four u32s, handed out in order; the block counter has 2^32 values, i.e.
//! 2^34 numbers per item, far more than any item draws.
//!
//! `domain` separates independent uses of the same item index (photon emission vs. cache
//! jitter, say) so they do not see the same stream; [`Rng::new`] is domain 0.
//! It is checked against Random123's published known-answer vectors in the tests.

use glam::Vec2;

const PHILOX_M0: u32 = 0xD251_1F53;
const PHILOX_M1: u32 = 0xCD9E_8D57;
// Weyl sequence key increments: golden ratio and sqrt(3) - 1, as in Random123.
const PHILOX_W0: u32 = 0x9E37_79B9;
const PHILOX_W1: u32 = 0xBB67_AE85;

/// The Philox4x32-10 block function: the bijection of `counter` keyed by `key`.
#[inline]
pub fn philox4x32_10(counter: [u32; 4], key: [u32; 2]) -> [u32; 4] {
    let mut c = counter;
    let mut k = key;
    for round in 0..10 {
        if round > 0 {
            k = [k[0].wrapping_add(PHILOX_W0), k[1].wrapping_add(PHILOX_W1)];
        }
        let p0 = (PHILOX_M0 as u64) * (c[0] as u64);
        let p1 = (PHILOX_M1 as u64) * (c[2] as u64);
        let (hi0, lo0) = ((p0 >> 32) as u32, p0 as u32);
        let (hi1, lo1) = ((p1 >> 32) as u32, p1 as u32);
        c = [hi1 ^ c[1] ^ k[0], lo1, hi0 ^ c[3] ^ k[1], lo0];
    }
    c
}

/// A u32 to a float in [0,1): the top 24 bits times 2^-24, exact in f32 and in WGSL, so the
/// largest value is 1 - 2^-24 and 1.0 is never returned (a float built from all 32 bits
/// would round u32::MAX up to 1.0).
#[inline]
pub fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Random numbers for one item: a Philox4x32-10 stream keyed by (seed, index, domain).
/// The sequence depends on nothing else. Cheap to create (no work until the first draw);
/// clone it to replay.
#[derive(Debug, Clone)]
pub struct Rng {
    key: [u32; 2],
    counter: [u32; 4],
    block: [u32; 4],
    /// Next unused word of `block`; 4 means "generate the next block".
    slot: u32,
}

impl Rng {
    /// The stream of item `index` in a run with `seed` (domain 0).
    #[inline]
    pub fn new(seed: u64, index: u64) -> Self {
        Self::with_domain(seed, index, 0)
    }

    /// The stream of item `index` in `domain`, a tag that keeps different uses of the same
    /// item index independent.
    #[inline]
    pub fn with_domain(seed: u64, index: u64, domain: u32) -> Self {
        let [key_lo, key_hi] = split_u64(seed);
        let [index_lo, index_hi] = split_u64(index);
        Rng { key: [key_lo, key_hi], counter: [0, domain, index_lo, index_hi], block: [0; 4], slot: 4 }
    }

    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        if self.slot == 4 {
            self.block = philox4x32_10(self.counter, self.key);
            self.counter[0] = self.counter[0].wrapping_add(1);
            self.slot = 0;
        }
        let value = self.block[self.slot as usize];
        self.slot += 1;
        value
    }

    /// Uniform in [0,1) with 24-bit resolution; never 1.0.
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        unit_f32(self.next_u32())
    }

    /// Two uniforms in [0,1): x drawn first, then y.
    #[inline]
    pub fn next_vec2(&mut self) -> Vec2 {
        let x = self.next_f32();
        let y = self.next_f32();
        Vec2::new(x, y)
    }

    /// Uniform in [0,1) with 53-bit resolution (two words, high first); CPU only, for
    /// the rare f64 decision.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        let hi = (self.next_u32() >> 5) as u64; // 27 bits
        let lo = (self.next_u32() >> 6) as u64; // 26 bits
        ((hi << 26) | lo) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
}

/// A u64 as the (lo, hi) u32 pair the WGSL side takes as a `vec2<u32>`.
#[inline]
pub fn split_u64(x: u64) -> [u32; 2] {
    [x as u32, (x >> 32) as u32]
}

/// The R2 sequence's generators (Roberts 2018, the plastic number's 1/phi2 and 1/phi2^2) in
/// 32-bit fixed point: point j of a rotated R2 sequence is `offset + j * R2_STEP` modulo 2^32
/// per axis, integer arithmetic that every backend computes bit for bit.
pub const R2_STEP: [u32; 2] = [3_242_174_889, 2_447_445_413];

/// Point `j` of the R2 sequence rotated by `offset` (Cranley-Patterson: each point is
/// uniform over the unit square, the points of one offset spread evenly), as [`unit_f32`]
/// maps bits to [0, 1).
#[inline]
pub fn r2_point(offset: [u32; 2], j: u32) -> glam::Vec2 {
    glam::Vec2::new(unit_f32(offset[0].wrapping_add(j.wrapping_mul(R2_STEP[0]))), unit_f32(offset[1].wrapping_add(j.wrapping_mul(R2_STEP[1]))))
}
