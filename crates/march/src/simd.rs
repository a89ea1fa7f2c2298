//! The march's arithmetic, written once for any x86-64 or other CPU ([`Unfused`]) and
//! specialised where the CPU has AVX2 and FMA ([`Fused`], picked at run time): fused
//! multiply-adds, eight samples' cells found at once, eight exponentials and the
//! transmittance along them at once.

use glam::{IVec3, Vec3A, Vec4};

use nimbus_volume::BRICK_DIM;

/// Lattice points a brick stores per axis: its 8 cells' lower corners and the apron. The
/// layout's ([`crate::layout`]), defined here because [`Arith::cells`] indexes the points
/// with it, and the layout builds on this arithmetic.
pub(crate) const EDGE: usize = BRICK_DIM as usize + 1;

/// Samples a march handles together: their cells are found together (vectorised), and
/// their exponentials computed together.
pub(crate) const LANES: usize = 8;

/// Where `LANES` samples fall in a brick's cells ([`Arith::cells`]).
pub(crate) struct Cells {
    /// The offset of each sample's cell's first corner in the brick's points, or
    /// [`OUTSIDE`] where rounding put it in a neighbour's cell.
    pub index: [u32; LANES],
    /// The fractions across the cell, per axis.
    pub w: [[f32; LANES]; 3],
}

pub(crate) const OUTSIDE: u32 = u32::MAX;


/// Multiply-adds, fused where the CPU has FMA ([`Fused`]), else a multiply and an add
/// ([`Unfused`]): the march's lerps and exponentials are chains of them.
pub(crate) trait Arith: Copy + Send + Sync {
    /// `a * b + c`.
    fn fma(self, a: f32, b: f32, c: f32) -> f32;
    fn fma4(self, a: Vec4, b: Vec4, c: Vec4) -> Vec4;

    /// The cells of the samples `first + step * (from + j)`, j < [`LANES`], positions
    /// relative to a brick's origin that lie in its cells but for rounding.
    #[inline(always)]
    fn cells(self, first: Vec3A, step: Vec3A, from: f32) -> Cells {
        let mut c = Cells { index: [0; LANES], w: [[0.0; LANES]; 3] };
        for j in 0..LANES {
            let q = (first + step * (from + j as f32)).clamp(Vec3A::splat(-1.0), Vec3A::splat(9.0));
            let f = q.floor();
            let l = f.as_ivec3();
            for a in 0..3 {
                c.w[a][j] = q[a] - f[a];
            }
            c.index[j] = cell_index(l);
        }
        c
    }

    /// Over the first `n` samples of a batch, of optical depths `tau`, from transmittance
    /// `tr`: each sample's weight `T_before (1 - e^-tau)`; the transmittance after the
    /// `n`th; and bit masks of the samples after which the transmittance is below
    /// `threshold` and below 0.99 (it only falls, so a mask's lowest bit is the first).
    #[inline(always)]
    fn composite(self, tr: f32, tau: &[f32; LANES], n: usize, threshold: f32) -> Composited {
        let mut c = Composited { weight: [0.0; LANES], tr, below: 0, deep: 0 };
        for i in 0..n.min(LANES) {
            let e = exp_neg(self, tau[i]);
            c.weight[i] = c.tr * one_minus_exp_neg(tau[i], e);
            c.tr *= e;
            c.below |= ((c.tr < threshold) as u32) << i;
            c.deep |= ((c.tr < 0.99) as u32) << i;
        }
        c
    }
}

/// What [`Arith::composite`] gives.
pub(crate) struct Composited {
    pub weight: [f32; LANES],
    pub tr: f32,
    pub below: u32,
    pub deep: u32,
}

/// The offset of cell `l`'s first corner in a brick's points, or [`OUTSIDE`] for a cell
/// outside the brick.
#[inline(always)]
fn cell_index(l: IVec3) -> u32 {
    // Negative cells wrap to large unsigned ones.
    if ((l.x | l.y | l.z) as u32) < BRICK_DIM as u32 {
        ((l.x * EDGE as i32 + l.y) * EDGE as i32 + l.z) as u32
    } else {
        OUTSIDE
    }
}

#[derive(Clone, Copy)]
pub(crate) struct Unfused;

impl Arith for Unfused {
    #[inline(always)]
    fn fma(self, a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
    #[inline(always)]
    fn fma4(self, a: Vec4, b: Vec4, c: Vec4) -> Vec4 {
        a * b + c
    }
}

/// FMA instructions; a value exists only where the CPU has them ([`Fused::detect`]). Its
/// code is meant to be inlined into functions compiled with `target_feature(enable = "fma")`.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Fused(());

#[cfg(target_arch = "x86_64")]
impl Fused {
    pub fn detect() -> Option<Fused> {
        (std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")).then_some(Fused(()))
    }
}

#[cfg(target_arch = "x86_64")]
impl Arith for Fused {
    #[inline(always)]
    fn fma(self, a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
    #[inline(always)]
    fn fma4(self, a: Vec4, b: Vec4, c: Vec4) -> Vec4 {
        use std::arch::x86_64::_mm_fmadd_ps;
        // SAFETY: a `Fused` exists only where the CPU has FMA.
        unsafe { Vec4::from(_mm_fmadd_ps(a.into(), b.into(), c.into())) }
    }

    /// Eight lanes of AVX2 (LLVM left the portable loop scalar).
    #[inline(always)]
    fn cells(self, first: Vec3A, step: Vec3A, from: f32) -> Cells {
        use std::arch::x86_64::*;
        const _: () = assert!(LANES == 8);
        let mut c = Cells { index: [0; LANES], w: [[0.0; LANES]; 3] };
        // SAFETY: a `Fused` exists only where the CPU has AVX2 and FMA; the stores write
        // 8 lanes into arrays of 8.
        unsafe {
            let j = _mm256_add_ps(_mm256_set1_ps(from), _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0));
            let mut l = [_mm256_setzero_si256(); 3];
            for a in 0..3 {
                let q = _mm256_fmadd_ps(_mm256_set1_ps(step[a]), j, _mm256_set1_ps(first[a]));
                // Clamped so that the conversion is in range (NaN goes to -1).
                let q = _mm256_min_ps(_mm256_max_ps(q, _mm256_set1_ps(-1.0)), _mm256_set1_ps(9.0));
                let f = _mm256_floor_ps(q);
                _mm256_storeu_ps(c.w[a].as_mut_ptr(), _mm256_sub_ps(q, f));
                l[a] = _mm256_cvttps_epi32(f);
            }
            let nine = |v| _mm256_add_epi32(_mm256_slli_epi32::<3>(v), v);
            let index = _mm256_add_epi32(nine(_mm256_add_epi32(nine(l[0]), l[1])), l[2]);
            // Inside when no bit above the low three is set in any axis (negatives have).
            let any = _mm256_or_si256(_mm256_or_si256(l[0], l[1]), l[2]);
            let inside = _mm256_cmpeq_epi32(_mm256_and_si256(any, _mm256_set1_epi32(!(BRICK_DIM - 1))), _mm256_setzero_si256());
            let index = _mm256_blendv_epi8(_mm256_set1_epi32(OUTSIDE as i32), index, inside);
            _mm256_storeu_si256(c.index.as_mut_ptr().cast(), index);
        }
        c
    }

    /// The exponentials eight at once, and the transmittance as a product scan (three
    /// shift-and-multiply steps) instead of a chain of eight multiplies.
    #[inline(always)]
    fn composite(self, tr: f32, tau: &[f32; LANES], n: usize, threshold: f32) -> Composited {
        use std::arch::x86_64::*;
        let mut c = Composited { weight: [0.0; LANES], tr, below: 0, deep: 0 };
        // SAFETY: a `Fused` exists only where the CPU has AVX2; loads and stores move 8
        // lanes from and to arrays of 8.
        unsafe {
            let iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
            // Lanes past n are stale: no extinction there.
            let live = _mm256_cmpgt_epi32(_mm256_set1_epi32(n.min(LANES) as i32), iota);
            let tau = _mm256_and_ps(_mm256_loadu_ps(tau.as_ptr()), _mm256_castsi256_ps(live));
            let (mut t, mut e, mut absorbed) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
            _mm256_storeu_ps(t.as_mut_ptr(), tau);
            for i in 0..LANES {
                e[i] = exp_neg(self, t[i]);
                absorbed[i] = one_minus_exp_neg(t[i], e[i]);
            }
            let one = _mm256_set1_ps(1.0);
            // x shifted up by k lanes, ones shifted in.
            let shift = |x: __m256, k: i32| {
                let idx = _mm256_max_epi32(_mm256_sub_epi32(iota, _mm256_set1_epi32(k)), _mm256_setzero_si256());
                let keep = _mm256_castsi256_ps(_mm256_cmpgt_epi32(iota, _mm256_set1_epi32(k - 1)));
                _mm256_blendv_ps(one, _mm256_permutevar8x32_ps(x, idx), keep)
            };
            let mut p = _mm256_loadu_ps(e.as_ptr());
            for k in [1, 2, 4] {
                p = _mm256_mul_ps(p, shift(p, k));
            }
            let tr = _mm256_set1_ps(tr);
            let before = _mm256_mul_ps(tr, shift(p, 1));
            _mm256_storeu_ps(c.weight.as_mut_ptr(), _mm256_mul_ps(before, _mm256_loadu_ps(absorbed.as_ptr())));
            let after = _mm256_mul_ps(tr, p);
            let lanes = (1u32 << n.min(LANES)) - 1;
            c.below = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(after, _mm256_set1_ps(threshold))) as u32 & lanes;
            c.deep = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(after, _mm256_set1_ps(0.99))) as u32 & lanes;
            // Lanes past n multiply by 1: the last lane is the transmittance after the nth.
            c.tr = _mm_cvtss_f32(_mm256_extractf128_ps::<1>(_mm256_permute_ps::<0xff>(after)));
        }
        c
    }
}

/// `e^-x` for `x >= 0` in f32 (Cephes' expf: a degree-7 polynomial on [-ln2/2, ln2/2]
/// after a two-part ln 2 reduction, within 2 ulp); about 1e-38 past e^-87, the least
/// normal, instead of 0. Branch-free, so a batch of them vectorises. libm's f64 exp took
/// a tenth of the march.
#[inline(always)]
fn exp_neg<A: Arith>(a: A, x: f32) -> f32 {
    let x = x.min(87.0);
    // Round to nearest without a libm call or a float-to-int conversion: adding 1.5 * 2^23
    // pushes the fraction out, leaving n in the low bits of the sum.
    const SHIFTER: f32 = 12_582_912.0;
    let shifted = a.fma(-x, std::f32::consts::LOG2_E, SHIFTER);
    let n = shifted - SHIFTER;
    let r = a.fma(n, 2.121_944_4e-4, a.fma(n, -0.693_359_4, -x));
    let mut p = a.fma(1.987_569_1e-4, r, 1.398_199_9e-3);
    // (Cephes' last coefficient, 0.50000001201, is 0.5 in f32.)
    for c in [8.333_452e-3, 4.166_579_6e-2, 1.666_666_5e-1, 0.5] {
        p = a.fma(p, r, c);
    }
    let e = a.fma(p, r * r, r + 1.0);
    // 2^n from its bits (n is whole, in [-126, 0]).
    let n = shifted.to_bits().wrapping_sub(SHIFTER.to_bits());
    e * f32::from_bits(n.wrapping_add(127) << 23)
}

/// `1 - e^-x` for `x >= 0`, given `e = e^-x`, without the cancellation that costs thin
/// media their precision in f32 (the same series as `shaders/march.wgsl`).
#[inline(always)]
fn one_minus_exp_neg(x: f32, e: f32) -> f32 {
    let series = x * (1.0 - 0.5 * x * (1.0 - x / 3.0 * (1.0 - 0.25 * x)));
    if x < 0.03 {
        series
    } else {
        1.0 - e
    }
}


#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponentials_are_within_a_few_ulps() {
        let mut worst = 0.0f64;
        for i in 0..200_000 {
            let x = i as f32 * 87.0 / 200_000.0;
            for a in [exp_neg(Unfused, x)] {
                let want = (-(x as f64)).exp();
                worst = worst.max((a as f64 - want).abs() / want);
            }
            // 1 - e^-x keeps its relative precision in thin media.
            let want = -(-(x as f64)).exp_m1();
            let got = one_minus_exp_neg(x, exp_neg(Unfused, x)) as f64;
            if x > 0.0 {
                assert!((got - want).abs() <= 3e-6 * want, "1 - e^-{x}: {got} vs {want}");
            }
        }
        assert!(worst < 4.0 * f32::EPSILON as f64, "worst relative error {worst:e}");
        assert_eq!(exp_neg(Unfused, 0.0), 1.0);
        assert!(exp_neg(Unfused, 1e9) < 1e-37 && exp_neg(Unfused, f32::INFINITY) < 1e-37);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_composite_and_cells_match_the_portable_ones() {
        let Some(fused) = Fused::detect() else { return eprintln!("no AVX2+FMA: skipped") };
        for case in 0..200u32 {
            let f = case as f32;
            let tau: [f32; LANES] = std::array::from_fn(|i| ((f * 0.37 + i as f32 * 1.3).sin() * 0.5 + 0.5) * if case % 3 == 0 { 3.0 } else { 0.05 });
            let (n, tr) = ((case % 9) as usize, 0.2 + (case % 7) as f32 * 0.1);
            let (a, b) = (Unfused.composite(tr, &tau, n, 0.05), fused.composite(tr, &tau, n, 0.05));
            assert_eq!((a.below, a.deep), (b.below, b.deep), "case {case}");
            assert!((a.tr - b.tr).abs() <= 1e-6 * a.tr.max(1e-30), "case {case}: {} vs {}", a.tr, b.tr);
            for i in 0..n {
                assert!((a.weight[i] - b.weight[i]).abs() <= 1e-6 * a.weight[i].abs().max(1e-30), "case {case}, lane {i}");
            }
            // Sample positions inside a brick, a few just outside.
            let first = Vec3A::new((f * 0.71).sin() * 4.0 + 4.0, (f * 0.33).cos() * 4.0 + 4.0, f % 8.0);
            let step = Vec3A::new(0.3, -0.2, 0.45) * (1.0 + (case % 4) as f32);
            let (a, b) = (Unfused.cells(first, step, 0.0), fused.cells(first, step, 0.0));
            assert_eq!(a.index, b.index, "case {case}");
            for ax in 0..3 {
                for j in 0..LANES {
                    if a.index[j] != OUTSIDE {
                        assert!((a.w[ax][j] - b.w[ax][j]).abs() <= 1e-6, "case {case}");
                    }
                }
            }
        }
    }
}
