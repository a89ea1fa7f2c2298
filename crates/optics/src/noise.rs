//! Seeded 3D gradient (Perlin) noise and its fractal sum (fBm).
//!
//! Self-contained on purpose: it depends on nothing but glam, so it can move to a shared
//! crate and be reused by the renderer's offset noise, and every operation has a direct WGSL
//! equivalent (u32 wrapping arithmetic for the hash, f32 for the interpolation).
//!
//! Reproducibility: the gradient at a lattice point is chosen by an integer hash of
//! (ix, iy, iz, seed), not by a shuffled permutation table, so the noise is a pure function of
//! its arguments with no state and no period shorter than 2^32 lattice cells.
//!
//! Precision: positions are f64 and split into an integer lattice cell and an f32 fraction,
//! so noise evaluated at world coordinates far from the origin (1e6) stays as detailed as
//! near it; a field tied to world space does not swim when a scene's bounds change.

use glam::{DVec3, Vec3};

/// The PCG output hash (O'Neill), a good 32-bit integer mix.
#[inline]
fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Hash of a lattice point and seed, nested so each coordinate is fully mixed before the next
/// (what perlin3 computes with the nesting shared among a cell's corners, and noise.wgsl).
#[cfg(test)]
fn lattice_hash(x: u32, y: u32, z: u32, seed: u32) -> u32 {
    pcg(x ^ pcg(y ^ pcg(z ^ pcg(seed))))
}

/// Dot product of the offset d with one of the 12 cube-edge gradients (Perlin 2002; the
/// last four entries repeat four of the twelve so a 4-bit hash selects uniformly enough).
#[inline]
fn grad(hash: u32, d: Vec3) -> f32 {
    let h = hash & 15;
    let u = if h < 8 { d.x } else { d.y };
    let v = if h < 4 {
        d.y
    } else if h == 12 || h == 14 {
        d.x
    } else {
        d.z
    };
    (if h & 1 == 0 { u } else { -u }) + (if h & 2 == 0 { v } else { -v })
}

/// The gradient [`grad`] dots with: `gradient(h).x * d.x + gradient(h).y * d.y +
/// gradient(h).z * d.z`, summed in that order, is `grad(h, d)` (its two terms, each times
/// one, and a zero). Looked up once per lattice point of a block ([`fbm3_vec_block`]), it
/// takes the branches on random hash bits out of the per-point loop, where they were
/// mispredicted about half the time.
#[inline]
fn gradient(hash: u32) -> Vec3 {
    GRADIENTS[(hash & 15) as usize]
}

/// [`gradient`] of each 4-bit hash: a table, as the hashes are random.
const GRADIENTS: [Vec3; 16] = {
    let mut t = [Vec3::ZERO; 16];
    let mut h = 0;
    while h < 16 {
        let u = if h & 1 == 0 { 1.0 } else { -1.0 };
        let v = if h & 2 == 0 { 1.0 } else { -1.0 };
        t[h] = match h {
            0..=3 => Vec3::new(u, v, 0.0),
            4..=7 => Vec3::new(u, 0.0, v),
            12 | 14 => Vec3::new(v, u, 0.0),
            _ => Vec3::new(0.0, u, v),
        };
        h += 1;
    }
    t
};

/// Quintic fade 6t^5 - 15t^4 + 10t^3: C2 continuity across lattice cells.
#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + t * (b - a)
}

/// Perlin gradient noise at `p`, seeded. Zero on the integer lattice, values roughly in
/// [-1, 1], mean zero; smooth (C2) everywhere.
pub fn perlin3(p: DVec3, seed: u32) -> f32 {
    let cell = DVec3::new(floor(p.x), floor(p.y), floor(p.z));
    let f = (p - cell).as_vec3();
    // Wrapping i64 -> u32 keeps the hash defined for any finite coordinate.
    let (ix, iy, iz) = (cell.x as i64 as u32, cell.y as i64 as u32, cell.z as i64 as u32);
    // lattice_hash's nesting shared among the corners: the seed once, each z twice, each
    // (y, z) four times, so 15 mixes instead of 32, the same hashes.
    let s = pcg(seed);
    let hz = [pcg(iz ^ s), pcg(iz.wrapping_add(1) ^ s)];
    let hyz = |dy: u32, dz: usize| pcg(iy.wrapping_add(dy) ^ hz[dz]);
    let yz = [hyz(0, 0), hyz(0, 1), hyz(1, 0), hyz(1, 1)];
    let corner = |dx: u32, dy: u32, dz: u32| {
        let h = pcg(ix.wrapping_add(dx) ^ yz[(2 * dy + dz) as usize]);
        grad(h, f - Vec3::new(dx as f32, dy as f32, dz as f32))
    };
    let (u, v, w) = (fade(f.x), fade(f.y), fade(f.z));
    lerp(
        lerp(lerp(corner(0, 0, 0), corner(0, 0, 1), w), lerp(corner(0, 1, 0), corner(0, 1, 1), w), v),
        lerp(lerp(corner(1, 0, 0), corner(1, 0, 1), w), lerp(corner(1, 1, 0), corner(1, 1, 1), w), v),
        u,
    )
}

/// floor without libm's call (the baseline x86-64 target has no rounding instruction): exact
/// for every finite f64 below 2^63 in magnitude, and the identity beyond, where every f64 is
/// an integer.
#[inline]
fn floor(x: f64) -> f64 {
    if x.abs() >= 9.2e18 || x.is_nan() {
        return x;
    }
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// Fractal Brownian motion: a sum of octaves of [`perlin3`], each at `lacunarity` times the
/// frequency and `gain` times the amplitude of the previous, normalised by the sum of the
/// amplitudes so the result stays roughly in [-1, 1] whatever the octave count.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fbm {
    pub octaves: u32,
    pub lacunarity: f64,
    pub gain: f32,
    pub seed: u32,
}

impl Fbm {
    pub fn new(octaves: u32, seed: u32) -> Fbm {
        Fbm { octaves, lacunarity: 2.0, gain: 0.5, seed }
    }

    pub fn eval(&self, p: DVec3) -> f32 {
        // Each octave gets its own seed and a shift, so the octaves' lattice zeros do not line
        // up (otherwise every octave vanishes at the origin and the sum has visible grid points).
        // Arbitrary irrational-looking offsets (their closeness to 1/pi and ln 2 is harmless);
        // shaders/noise.wgsl uses the same digits, so they must not be "corrected".
        #[allow(clippy::approx_constant)]
        const SHIFT: DVec3 = DVec3::new(0.318_309_886, 0.577_215_665, 0.693_147_181);
        let (mut sum, mut norm) = (0.0f32, 0.0f32);
        let (mut freq, mut amp) = (1.0f64, 1.0f32);
        for octave in 0..self.octaves {
            sum += amp * perlin3(p * freq + SHIFT * octave as f64, self.seed.wrapping_add(octave));
            norm += amp;
            freq *= self.lacunarity;
            amp *= self.gain;
        }
        if norm > 0.0 {
            sum / norm
        } else {
            0.0
        }
    }
}

/// fBm with the usual lacunarity 2 and gain 1/2.
pub fn fbm3(p: DVec3, octaves: u32, seed: u32) -> f32 {
    Fbm::new(octaves, seed).eval(p)
}

/// A smooth vector field: three decorrelated fBm channels (seeds seed, seed+101, seed+202,
/// far enough apart that no octave of one channel shares a seed with another's).
pub fn fbm3_vec(p: DVec3, octaves: u32, seed: u32) -> Vec3 {
    Vec3::new(fbm3(p, octaves, seed), fbm3(p, octaves, seed.wrapping_add(101)), fbm3(p, octaves, seed.wrapping_add(202)))
}

/// [`fbm3_vec`] at every point `(origin + j) * spacing`, j in [0, n)^3, of a block of a
/// lattice, into `out` (x-major, z fastest), what [`fbm3_vec`] gives at each to f32
/// rounding ([`fbm3_vec_grid`]): what baking the field on a lattice costs (vdbmarch's
/// offset noise).
pub fn fbm3_vec_block(origin: [i64; 3], n: usize, spacing: f64, octaves: u32, seed: u32, out: &mut [Vec3]) {
    fbm3_vec_grid(origin.map(|o| o as f64), [spacing; 3], [n; 3], octaves, seed, out)
}

/// [`fbm3_vec_block`] at the points `(origin + j) * spacing` per axis, j in [0, n) per
/// axis: a box of any axis-aligned lattice (a volume's lattice points in noise units, say),
/// `spacing` positive. What [`fbm3_vec`] gives at each point to f32 rounding (a few ulps of
/// the unit amplitude; the sums are taken in another order).
///
/// Gradient noise is a sum over a cell's corners of products of per-axis weights and, in
/// each gradient component, one per-axis offset: `sum Wx Wy Wz (gx (fx - dx) + gy (fy - dy)
/// + gz (fz - dz))`. On a box each factor depends on one axis alone, so the sum is taken
/// an axis at a time (z, then y, then x) over the noise lattice's gradients, which costs
/// four multiply-adds a point, octave and channel at the last axis (the first two run over
/// the noise lattice's rows, about as many) instead of eight dot products and seven lerps;
/// the cells, fractions and weights are found once per axis and octave, shared by the
/// three channels, and the hashes once per noise lattice point the box spans.
pub fn fbm3_vec_grid(origin: [f64; 3], spacing: [f64; 3], n: [usize; 3], octaves: u32, seed: u32, out: &mut [Vec3]) {
    assert_eq!(out.len(), n[0] * n[1] * n[2], "one output per point");
    if out.is_empty() {
        return;
    }
    assert!(spacing.iter().all(|&s| s > 0.0), "positive spacing: {spacing:?}");
    // Fbm::eval's constants (lacunarity 2, gain 1/2, the octave shift).
    #[allow(clippy::approx_constant)]
    const SHIFT: [f64; 3] = [0.318_309_886, 0.577_215_665, 0.693_147_181];
    let [_, ny, nz] = n;
    let mut sums = [vec![0.0f32; out.len()], vec![0.0f32; out.len()], vec![0.0f32; out.len()]];
    // Per axis and point: its cell (relative to the box's first) and the weights of the
    // cell's lower and upper corner: the lerp's (1 - t, t) and those times the offset from
    // the corner ((1 - t) f, t (f - 1)), t the faded fraction f.
    let mut axes: [Vec<AxisWeights>; 3] = Default::default();
    let (mut gradients, mut z_done, mut y_done) = (Vec::new(), Vec::new(), Vec::new());
    let (mut norm, mut freq, mut amp) = (0.0f32, 1.0f64, 1.0f32);
    for octave in 0..octaves {
        let mut first = [0u32; 3];
        let mut span = [0usize; 3];
        for a in 0..3 {
            let q = |j: usize| ((origin[a] + j as f64) * spacing[a]) * freq + SHIFT[a] * octave as f64;
            let c0 = floor(q(0));
            first[a] = c0 as i64 as u32;
            axes[a].clear();
            for j in 0..n[a] {
                let c = floor(q(j));
                let f = (q(j) - c) as f32;
                let t = fade(f);
                axes[a].push(AxisWeights { cell: (c - c0) as usize, lerp: [1.0 - t, t], offset: [(1.0 - t) * f, t * (f - 1.0)] });
            }
            span[a] = axes[a][n[a] - 1].cell + 2;
        }
        let [sx, sy, _] = span;
        for (channel, sum) in sums.iter_mut().enumerate() {
            let s = pcg(seed.wrapping_add(101 * channel as u32).wrapping_add(octave));
            // The gradient of every noise lattice point the box's cells touch, from its
            // hash (perlin3's nesting), x-major, z fastest.
            gradients.clear();
            gradients.resize(span[0] * span[1] * span[2], Vec3::ZERO);
            for z in 0..span[2] {
                let hz = pcg(first[2].wrapping_add(z as u32) ^ s);
                for y in 0..span[1] {
                    let hyz = pcg(first[1].wrapping_add(y as u32) ^ hz);
                    for x in 0..span[0] {
                        gradients[(x * span[1] + y) * span[2] + z] = gradient(pcg(first[0].wrapping_add(x as u32) ^ hyz));
                    }
                }
            }
            // Along z, per noise lattice (x, y) and point z: gx and gy lerped, gz times its
            // offset.
            z_done.clear();
            z_done.resize(sx * sy * nz, Vec3::ZERO);
            for xy in 0..sx * sy {
                let column = &gradients[xy * span[2]..][..span[2]];
                for (w, out) in axes[2].iter().zip(&mut z_done[xy * nz..][..nz]) {
                    let (g0, g1) = (column[w.cell], column[w.cell + 1]);
                    *out = Vec3::new(w.lerp[0] * g0.x + w.lerp[1] * g1.x, w.lerp[0] * g0.y + w.lerp[1] * g1.y, w.offset[0] * g0.z + w.offset[1] * g1.z);
                }
            }
            // Along y, per noise lattice x and point (y, z): the x term lerped, and the y
            // and z terms summed (both are lerped along x).
            y_done.clear();
            y_done.resize(sx * ny * nz * 2, 0.0f32);
            for x in 0..sx {
                for (jy, w) in axes[1].iter().enumerate() {
                    let (r0, r1) = (&z_done[(x * sy + w.cell) * nz..][..nz], &z_done[(x * sy + w.cell + 1) * nz..][..nz]);
                    let (xs, yz) = y_done[(x * ny + jy) * nz * 2..][..nz * 2].split_at_mut(nz);
                    for jz in 0..nz {
                        let (a, b) = (r0[jz], r1[jz]);
                        xs[jz] = w.lerp[0] * a.x + w.lerp[1] * b.x;
                        yz[jz] = w.offset[0] * a.y + w.offset[1] * b.y + (w.lerp[0] * a.z + w.lerp[1] * b.z);
                    }
                }
            }
            // Along x, into the sum.
            let plane = ny * nz;
            for (jx, w) in axes[0].iter().enumerate() {
                let (s0, s1) = (&y_done[w.cell * plane * 2..][..plane * 2], &y_done[(w.cell + 1) * plane * 2..][..plane * 2]);
                let out = &mut sum[jx * plane..][..plane];
                for jy in 0..ny {
                    let (x0, yz0) = s0[jy * nz * 2..][..nz * 2].split_at(nz);
                    let (x1, yz1) = s1[jy * nz * 2..][..nz * 2].split_at(nz);
                    for (jz, o) in out[jy * nz..][..nz].iter_mut().enumerate() {
                        *o += amp * (w.offset[0] * x0[jz] + w.offset[1] * x1[jz] + (w.lerp[0] * yz0[jz] + w.lerp[1] * yz1[jz]));
                    }
                }
            }
        }
        norm += amp;
        freq *= 2.0;
        amp *= 0.5;
    }
    let scale = if norm > 0.0 { 1.0 / norm } else { 0.0 };
    for (i, o) in out.iter_mut().enumerate() {
        *o = Vec3::new(sums[0][i], sums[1][i], sums[2][i]) * scale;
    }
}

/// One point's cell and weights along one axis of [`fbm3_vec_grid`]'s box.
#[derive(Clone, Copy, Default)]
struct AxisWeights {
    cell: usize,
    lerp: [f32; 2],
    offset: [f32; 2],
}

#[cfg(test)]
mod tests {
    /// perlin3 as first written: every corner hashed on its own, libm's floor.
    fn perlin3_naive(p: glam::DVec3, seed: u32) -> f32 {
        let cell = p.floor();
        let f = (p - cell).as_vec3();
        let (ix, iy, iz) = (cell.x as i64 as u32, cell.y as i64 as u32, cell.z as i64 as u32);
        let corner = |dx: u32, dy: u32, dz: u32| {
            let h = super::lattice_hash(ix.wrapping_add(dx), iy.wrapping_add(dy), iz.wrapping_add(dz), seed);
            super::grad(h, f - glam::Vec3::new(dx as f32, dy as f32, dz as f32))
        };
        let (u, v, w) = (super::fade(f.x), super::fade(f.y), super::fade(f.z));
        super::lerp(
            super::lerp(super::lerp(corner(0, 0, 0), corner(0, 0, 1), w), super::lerp(corner(0, 1, 0), corner(0, 1, 1), w), v),
            super::lerp(super::lerp(corner(1, 0, 0), corner(1, 0, 1), w), super::lerp(corner(1, 1, 0), corner(1, 1, 1), w), v),
            u,
        )
    }

    #[test]
    fn shared_hashing_and_the_own_floor_change_no_value() {
        let mut x = 0x1234_5678_9abc_def0u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for scale in [1.0, 37.5, 1e6, 3e9] {
            for _ in 0..2000 {
                let p = glam::DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * (2.0 * scale);
                for seed in [0, 7, 0xdead_beef] {
                    assert_eq!(super::perlin3(p, seed).to_bits(), perlin3_naive(p, seed).to_bits(), "at {p} seed {seed}");
                }
            }
        }
        for v in [-2.5, -1.0, -0.0, 0.0, 0.3, 1.0, 4.5e15, -4.5e15, 1e300, f64::INFINITY, -f64::INFINITY] {
            assert_eq!(super::floor(v), v.floor(), "floor({v})");
        }
    }

    use super::*;

    #[test]
    fn gradients_dot_as_grad_computes() {
        for h in 0..16u32 {
            for d in [Vec3::new(0.3, -0.7, 0.11), Vec3::new(-1.0, 0.25, 0.9), Vec3::new(0.0, 0.5, -0.0)] {
                let g = gradient(h);
                assert_eq!(g.x * d.x + g.y * d.y + g.z * d.z, grad(h, d), "hash {h}, {d}");
            }
        }
    }

    /// The largest component difference the grid's order of summation may make against
    /// [`fbm3_vec`] at a point: a few ulps of the octaves' unit amplitude.
    const GRID_ROUNDING: f32 = 4e-6;

    fn assert_near_fbm3_vec(got: Vec3, p: DVec3, octaves: u32, seed: u32, at: &str) {
        let want = fbm3_vec(p, octaves, seed);
        assert!((got - want).abs().max_element() <= GRID_ROUNDING, "{at}: {got} against {want}");
    }

    #[test]
    fn a_block_is_fbm3_vec_at_each_point() {
        for (origin, spacing) in [([0i64, 0, 0], 0.125), ([-5, 3, 17], 0.25), ([8_000_000, -1_000_000, 40], 0.125), ([3, -2, 1], 1.5)] {
            let n = 9;
            let mut out = vec![Vec3::ZERO; n * n * n];
            fbm3_vec_block(origin, n, spacing, 3, 11, &mut out);
            for (i, &got) in out.iter().enumerate() {
                let j = [(i / (n * n)) as i64, (i / n % n) as i64, (i % n) as i64];
                let p = DVec3::new((origin[0] + j[0]) as f64, (origin[1] + j[1]) as f64, (origin[2] + j[2]) as f64) * spacing;
                assert_near_fbm3_vec(got, p, 3, 11, &format!("{origin:?} + {j:?}"));
            }
        }
    }

    #[test]
    fn a_grid_is_fbm3_vec_at_each_point() {
        for (origin, spacing, n, octaves) in [
            ([1.0e6 + 0.3, -2.25, 17.0], [0.25, 0.5, 0.2], [9, 4, 6], 3),
            ([-3.7, 0.0, 2.5], [0.7, 0.05, 1.3], [3, 11, 1], 5),
            ([0.3, 0.6, 0.1], [2.0, 2.0, 2.0], [2, 2, 2], 1),
        ] {
            let mut out = vec![Vec3::ZERO; n[0] * n[1] * n[2]];
            fbm3_vec_grid(origin, spacing, n, octaves, 5, &mut out);
            let mut moved = 0.0f32;
            for (i, &got) in out.iter().enumerate() {
                let j = [(i / (n[1] * n[2])) as f64, (i / n[2] % n[1]) as f64, (i % n[2]) as f64];
                let p = DVec3::new((origin[0] + j[0]) * spacing[0], (origin[1] + j[1]) * spacing[1], (origin[2] + j[2]) * spacing[2]);
                assert_near_fbm3_vec(got, p, octaves, 5, &format!("{origin:?} + {j:?}"));
                moved = moved.max(got.abs().max_element());
            }
            // Not a field of zeros that a zero reference would pass.
            assert!(moved > 0.05, "{origin:?}: largest component {moved}");
        }
        let mut none = vec![Vec3::ONE; 8];
        fbm3_vec_grid([0.3; 3], [0.5; 3], [2; 3], 0, 5, &mut none);
        assert!(none.iter().all(|&v| v == Vec3::ZERO), "no octaves, no noise: {none:?}");
    }

    #[test]
    fn zero_on_lattice_and_bounded() {
        assert_eq!(perlin3(DVec3::new(3.0, -7.0, 1e6), 1), 0.0);
        let mut max = 0.0f32;
        let mut mean = 0.0f64;
        let n = 20_000;
        for i in 0..n {
            let p = DVec3::new(i as f64 * 0.137, (i % 97) as f64 * 0.311, (i % 13) as f64 * 0.73);
            let v = perlin3(p, 7);
            max = max.max(v.abs());
            mean += v as f64;
        }
        assert!(max <= 1.1 && max > 0.4, "max {max}");
        assert!((mean / n as f64).abs() < 0.05, "mean {}", mean / n as f64);
    }

    #[test]
    fn seeded_and_continuous() {
        let p = DVec3::new(1.3, 2.7, -0.4);
        assert_eq!(perlin3(p, 5), perlin3(p, 5));
        assert_ne!(perlin3(p, 5), perlin3(p, 6));
        let e = DVec3::splat(1e-4);
        assert!((perlin3(p, 5) - perlin3(p + e, 5)).abs() < 1e-3);
        // Far from the origin the fraction keeps full precision.
        let far = DVec3::splat(1e6) + p;
        assert!((perlin3(far, 5) - perlin3(far + e, 5)).abs() < 1e-3);
        assert_eq!(fbm3(p, 1, 9), perlin3(p, 9));
    }
}
