//! `vdbmarch --verify`: a render that reports its own error (issue #47).
//!
//! After the march, a sample of the image's 2 x 2 blocks (or single pixels) is path traced
//! by the reference tracer itself ([`crate::reference`]'s per-sample function, the code
//! `--reference` runs, over the same scene), and the image is scored against that truth as
//! nimbus-compare scores it against a full reference (crates/bench/src/image.rs):
//!
//! - relative RMSE: over the blocks the truth covers (its alpha over 1%), the RMS over blocks
//!   and colour channels of render minus truth, over the mean (of the channels' mean) of the
//!   truth there;
//! - mean ratio: the render's mean over the truth's, over the sampled blocks.
//!
//! The sample: blocks drawn uniformly without replacement from those the render covers at
//! half the bench's threshold (alpha over 0.5%; a block the march sees as empty but the
//! truth as covered, a disagreement in transmittance the size of the threshold, is never
//! drawn), all of them where there are fewer than asked for. Blocks the truth then finds
//! uncovered count in the mean ratio only, as in the bench.
//!
//! The truth's own noise: each block's samples are independent (sample j traces path j of
//! each of the block's pixels), so their spread gives the variance of the block's mean,
//! `var(t^_i)`. Since `E[(r_i - t^_i)^2] = (r_i - t_i)^2 + var(t^_i)`, each block's squared
//! error is taken less that variance ([`BlockSample::corrected_sq`]), which removes the
//! truth's noise from the estimate in expectation. The truth is traced in two passes:
//! [`VerifyParams::first_spp`] samples a block, then, from their sample variance, as many
//! more as bring the block's noise under a third of the target times the covered truth's
//! mean (at most [`VerifyParams::max_spp`]), so that the subtraction is of a small term.
//!
//! The interval ([`estimate`]): `R = mean(d_i) / mean(l_i)^2` (d the corrected squared
//! error, l the truth's level) is a ratio of sample means; its standard error comes from
//! the spread of its linearisation `z_i = d_i / L^2 - 2 D l_i / L^3` over the blocks, no
//! finite-population correction (the spread also carries the truth's noise, which does not
//! vanish when every block is drawn: the interval stays conservative there). `R +- 1.96 se`,
//! the lower end clamped at 0, square-rooted, is the ~95% interval on the relative RMSE; the
//! mean ratio's is the same construction on `(r_i - Q t_i) / t_mean`.
//!
//! The truth draws from the seed xor [`VERIFY_SEED`]: independent of the march's samples
//! (another domain) and of a `--reference` render at the same seed.

use glam::DVec3;
use nimbus_optics::Rng;
use nimbus_tracking::DensityMedium;
use nimbus_volume::Volume;
use rayon::prelude::*;

use crate::reference::{reference_majorant, reference_sample, ReferenceParams};
use crate::{Image, MarchError, MediumFields};

/// Mixed into the seed for the verification's truth ("VERIFY").
pub const VERIFY_SEED: u64 = 0x5645_5249_4659;
/// Random-number domain of the choice of blocks.
const SELECT_DOMAIN: u32 = 0x5645_5253; // "VERS"
/// The bench's coverage threshold: a block counts where the truth's alpha exceeds it.
pub const COVERED_ALPHA: f64 = 0.01;
/// A block is drawn where the render's alpha exceeds this: half the bench's threshold, so
/// the truth's coverage, not the render's, decides at the edge.
const CANDIDATE_ALPHA: f32 = 0.005;
/// The normal quantile of a two-sided 95% interval.
const Z95: f64 = 1.96;

/// What `--verify` traces.
#[derive(Clone, Debug)]
pub struct VerifyParams {
    /// Blocks to draw (all the covered blocks where there are fewer).
    pub samples: u32,
    /// Block side in pixels: 2 (the bench's 2 x 2 blocks) or 1.
    pub block: u32,
    /// The relative RMSE the image is meant to meet: the truth's noise is driven under a
    /// third of it.
    pub target: f64,
    /// Samples per pixel of the first pass, from which each block's variance is estimated.
    pub first_spp: u32,
    /// Most samples per pixel in all.
    pub max_spp: u32,
}

impl VerifyParams {
    pub const DEFAULT_SAMPLES: u32 = 512;
    pub const DEFAULT_BLOCK: u32 = 2;
    pub const DEFAULT_TARGET: f64 = 0.02;
    pub const DEFAULT_FIRST_SPP: u32 = 64;
    pub const DEFAULT_MAX_SPP: u32 = 8192;

    pub fn validate(&self) -> Result<(), MarchError> {
        if self.samples == 0 {
            return Err(MarchError::Param("--verify-pixels must be at least 1".into()));
        }
        if !(self.block == 1 || self.block == 2) {
            return Err(MarchError::Param(format!("--verify-block must be 1 or 2, not {}", self.block)));
        }
        if !(self.target.is_finite() && self.target > 0.0) {
            return Err(MarchError::Param(format!("--verify-target must be a positive number, not {}", self.target)));
        }
        if self.first_spp < 2 {
            return Err(MarchError::Param("the verification's first pass needs at least 2 samples a pixel".into()));
        }
        if self.max_spp < self.first_spp {
            return Err(MarchError::Param(format!("--verify-max-spp {} is under the first pass's {} samples a pixel", self.max_spp, self.first_spp)));
        }
        Ok(())
    }
}

impl Default for VerifyParams {
    fn default() -> Self {
        VerifyParams {
            samples: Self::DEFAULT_SAMPLES,
            block: Self::DEFAULT_BLOCK,
            target: Self::DEFAULT_TARGET,
            first_spp: Self::DEFAULT_FIRST_SPP,
            max_spp: Self::DEFAULT_MAX_SPP,
        }
    }
}

/// One drawn block: the render's and the truth's mean RGB over it, the variance of the
/// truth's mean per channel, and the truth's alpha.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlockSample {
    pub render: DVec3,
    pub truth: DVec3,
    pub truth_var: DVec3,
    pub truth_alpha: f64,
}

impl BlockSample {
    /// The squared error over the channels' mean (the bench's), less the truth's own
    /// variance: unbiased for the squared error against the exact truth.
    pub fn corrected_sq(&self) -> f64 {
        let d = self.render - self.truth;
        (d * d - self.truth_var).element_sum() / 3.0
    }

    fn covered(&self) -> bool {
        self.truth_alpha > COVERED_ALPHA
    }

    fn level(v: DVec3) -> f64 {
        v.element_sum() / 3.0
    }
}

/// The render's error estimated from a sample of blocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// Relative RMSE over the covered blocks, the truth's noise taken out.
    pub rel_rmse: f64,
    /// ~95% interval on it.
    pub lo: f64,
    pub hi: f64,
    /// Render mean over truth mean, over every drawn block.
    pub mean_ratio: f64,
    pub ratio_lo: f64,
    pub ratio_hi: f64,
    /// Drawn blocks the truth covers: those the RMSE is over.
    pub covered: usize,
    /// The truth's own noise left in it, relative: RMS of its blocks' standard deviations
    /// over its mean (what was subtracted).
    pub truth_noise: f64,
}

/// Mean and sample standard deviation.
fn mean_sd(values: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = values.clone().count() as f64;
    let mean = values.clone().sum::<f64>() / n;
    let var = if n > 1.0 { values.map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { f64::INFINITY };
    (mean, var.sqrt())
}

/// The estimate from drawn blocks (see the module doc); none where no block is covered or
/// the truth is black there.
pub fn estimate(samples: &[BlockSample]) -> Option<Estimate> {
    let covered: Vec<&BlockSample> = samples.iter().filter(|s| s.covered()).collect();
    let k = covered.len();
    if k == 0 {
        return None;
    }
    let level = covered.iter().map(|s| BlockSample::level(s.truth)).sum::<f64>() / k as f64;
    if !(level > 0.0) {
        return None;
    }
    let d_mean = covered.iter().map(|s| s.corrected_sq()).sum::<f64>() / k as f64;
    let r = d_mean / (level * level);
    let z = covered.iter().map(|s| s.corrected_sq() / (level * level) - 2.0 * d_mean * BlockSample::level(s.truth) / level.powi(3));
    let (_, sd) = mean_sd(z);
    let se = sd / (k as f64).sqrt();
    let root = |v: f64| v.max(0.0).sqrt();

    let n = samples.len() as f64;
    let (render_sum, truth_sum) = samples.iter().fold((0.0, 0.0), |(a, b), s| (a + BlockSample::level(s.render), b + BlockSample::level(s.truth)));
    let q = render_sum / truth_sum;
    let truth_mean = truth_sum / n;
    let (_, q_sd) = mean_sd(samples.iter().map(|s| (BlockSample::level(s.render) - q * BlockSample::level(s.truth)) / truth_mean));
    let q_se = q_sd / n.sqrt();

    let truth_var = covered.iter().map(|s| s.truth_var.element_sum() / 3.0).sum::<f64>() / k as f64;
    Some(Estimate {
        rel_rmse: root(r),
        lo: root(r - Z95 * se),
        hi: root(r + Z95 * se),
        mean_ratio: q,
        ratio_lo: q - Z95 * q_se,
        ratio_hi: q + Z95 * q_se,
        covered: k,
        truth_noise: truth_var.sqrt() / level,
    })
}

/// What `--verify` found.
#[derive(Clone, Debug)]
pub struct Verification {
    /// None where no drawn block is covered (the volume is out of view, or black).
    pub estimate: Option<Estimate>,
    /// Blocks drawn (and traced).
    pub drawn: usize,
    /// Block side in pixels.
    pub block: u32,
    /// Paths traced in all.
    pub paths: u64,
    /// Fewest and most samples per pixel a block took.
    pub spp_range: (u32, u32),
    /// Blocks stopped at [`VerifyParams::max_spp`] above their noise target.
    pub capped: usize,
}

/// Running sums over a block's samples: per channel, of the block's mean colour per sample
/// and its square, and of its alpha.
#[derive(Clone, Copy, Debug, Default)]
struct Sums {
    n: u32,
    sum: DVec3,
    sum_sq: DVec3,
    alpha: f64,
}

impl Sums {
    fn mean(&self) -> DVec3 {
        self.sum / self.n as f64
    }

    /// The variance of the mean, per channel (from the samples' unbiased variance).
    fn var_of_mean(&self) -> DVec3 {
        let n = self.n as f64;
        let var = (self.sum_sq - self.sum * self.sum / n) / (n - 1.0);
        var.max(DVec3::ZERO) / n
    }
}

/// Verifies `image` against the reference tracer over `params`' scene (its seed the
/// march's: the truth draws from it xor [`VERIFY_SEED`]), on the CPU.
pub fn verify_cpu(image: &Image, density: &Volume<f32>, params: &ReferenceParams, fields: MediumFields, opts: &VerifyParams) -> Result<Verification, MarchError> {
    opts.validate()?;
    params.validate()?;
    let (w, h) = (params.camera.width(), params.camera.height());
    if (image.width, image.height) != (w, h) {
        return Err(MarchError::Param(format!("the image is {}x{}, the camera {w}x{h}", image.width, image.height)));
    }
    let params = ReferenceParams { seed: params.seed ^ VERIFY_SEED, ..params.clone() };
    let b = opts.block;
    let (bw, bh) = (w / b, h / b);
    let pixels_of = |block: u64| {
        let (bx, by) = ((block % bw as u64) as u32, (block / bw as u64) as u32);
        (0..b * b).map(move |k| (by * b + k / b) as u64 * w as u64 + (bx * b + k % b) as u64)
    };
    let per_block = 1.0 / (b * b) as f64;
    let candidates: Vec<u64> =
        (0..bw as u64 * bh as u64).filter(|&i| pixels_of(i).map(|p| image.rgba[p as usize].w).sum::<f32>() * per_block as f32 > CANDIDATE_ALPHA).collect();
    let chosen = choose(candidates, opts.samples as usize, params.seed);
    let render: Vec<DVec3> = chosen.iter().map(|&i| pixels_of(i).map(|p| image.rgba[p as usize].truncate().as_dvec3()).sum::<DVec3>() * per_block).collect();

    let MediumFields { emission, motion, .. } = fields;
    let majorant = reference_majorant(density, &params, motion);
    let medium = DensityMedium { motion: None, density, majorant: &majorant, extinction: params.medium.extinction };
    let background = crate::constant_background(params.background, params.visible_environment()).as_dvec3();
    // Samples [from, to) of a block: sample j averages path j of each of its pixels.
    let trace = |block: u64, mut sums: Sums, to: u32| {
        for j in sums.n..to {
            let (mut colour, mut alpha) = (DVec3::ZERO, 0.0);
            for p in pixels_of(block) {
                let s = reference_sample(medium, &params, emission, motion, p, j);
                colour += (s.single + s.multiple + s.emission + s.behind).as_dvec3() + background * s.transmittance as f64;
                alpha += 1.0 - s.transmittance as f64;
            }
            let (colour, alpha) = (colour * per_block, alpha * per_block);
            sums.sum += colour;
            sums.sum_sq += colour * colour;
            sums.alpha += alpha;
            sums.n += 1;
        }
        sums
    };
    let pass = |what: &str, work: Vec<(u64, Sums, u32)>| -> Vec<Sums> {
        let task = nimbus_progress::task(what, work.len() as u64);
        let out = work
            .into_par_iter()
            .map(|(block, sums, to)| {
                let s = trace(block, sums, to);
                task.advance(1);
                s
            })
            .collect();
        task.finish();
        out
    };
    let first = pass("verify (first pass)", chosen.iter().map(|&i| (i, Sums::default(), opts.first_spp)).collect());

    // Each block's noise target: a third of the target times the covered truth's mean,
    // from the first pass.
    let covered: Vec<&Sums> = first.iter().filter(|s| s.alpha / s.n as f64 > COVERED_ALPHA).collect();
    let level = covered.iter().map(|s| BlockSample::level(s.mean())).sum::<f64>() / covered.len().max(1) as f64;
    let allowed_var = (opts.target / 3.0 * level).powi(2);
    let wanted = |s: &Sums| -> u32 {
        let var = BlockSample::level(s.var_of_mean()) * s.n as f64; // one sample's
        if !(allowed_var > 0.0) || !var.is_finite() {
            return s.n;
        }
        (var / allowed_var).ceil().clamp(s.n as f64, opts.max_spp as f64) as u32
    };
    let capped = first.iter().filter(|s| allowed_var > 0.0 && BlockSample::level(s.var_of_mean()) * s.n as f64 / allowed_var > opts.max_spp as f64).count();
    let second: Vec<(u64, Sums, u32)> = chosen.iter().zip(&first).map(|(&i, s)| (i, *s, wanted(s))).collect();
    let done = pass("verify (second pass)", second);

    let samples: Vec<BlockSample> = done
        .iter()
        .zip(&render)
        .map(|(s, &r)| BlockSample { render: r, truth: s.mean(), truth_var: s.var_of_mean(), truth_alpha: s.alpha / s.n as f64 })
        .collect();
    let spp = done.iter().map(|s| s.n);
    Ok(Verification {
        estimate: estimate(&samples),
        drawn: samples.len(),
        block: b,
        paths: done.iter().map(|s| s.n as u64).sum::<u64>() * (b * b) as u64,
        spp_range: (spp.clone().min().unwrap_or(0), spp.max().unwrap_or(0)),
        capped,
    })
}

/// `count` of `candidates` drawn uniformly without replacement (a partial Fisher-Yates
/// shuffle from the seed's own stream), in raster order; all of them where there are fewer.
fn choose(mut candidates: Vec<u64>, count: usize, seed: u64) -> Vec<u64> {
    if candidates.len() > count {
        let mut rng = Rng::with_domain(seed, 0, SELECT_DOMAIN);
        for i in 0..count {
            let j = i + ((rng.next_f64() * (candidates.len() - i) as f64) as usize).min(candidates.len() - i - 1);
            candidates.swap(i, j);
        }
        candidates.truncate(count);
        candidates.sort_unstable();
    }
    candidates
}

impl Verification {
    /// The EXR header's `nimbus:verify` value: fractions, not percent.
    pub fn attribute(&self) -> String {
        let block = if self.block > 1 { format!(",block={}", self.block) } else { String::new() };
        match &self.estimate {
            Some(e) => format!("rel_rmse={:.6},lo={:.6},hi={:.6},mean_ratio={:.6},pixels={}{block}", e.rel_rmse, e.lo, e.hi, e.mean_ratio, e.covered),
            None => format!("rel_rmse=nan,lo=nan,hi=nan,mean_ratio=nan,pixels=0{block}"),
        }
    }

    /// The line on stderr.
    pub fn summary(&self) -> String {
        let what = if self.block > 1 { format!("{0}x{0} blocks", self.block) } else { "pixels".to_string() };
        let paths = if self.spp_range.0 == self.spp_range.1 { format!("{}", self.spp_range.0) } else { format!("{}-{}", self.spp_range.0, self.spp_range.1) };
        match &self.estimate {
            Some(e) => format!(
                "relative RMSE {:.2}% (95%: {:.2}-{:.2}%), mean ratio {:.3} ({:.3}-{:.3}), {} {what} against {paths} paths a pixel",
                100.0 * e.rel_rmse,
                100.0 * e.lo,
                100.0 * e.hi,
                e.mean_ratio,
                e.ratio_lo,
                e.ratio_hi,
                e.covered
            ),
            None => format!("no error to report: none of the {} {what} drawn is covered by the volume", self.drawn),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic spread of truth levels, 0.5 to 1.5.
    fn truths(n: usize) -> Vec<DVec3> {
        let mut rng = Rng::with_domain(1, 0, 7);
        (0..n).map(|_| DVec3::new(0.5 + rng.next_f64(), 0.5 + rng.next_f64(), 0.5 + rng.next_f64())).collect()
    }

    /// A standard normal draw (Box-Muller).
    fn normal(rng: &mut Rng) -> f64 {
        let (u, v) = (1.0 - rng.next_f64(), rng.next_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    #[test]
    fn a_constant_relative_bias_is_its_relative_rmse() {
        // render = 1.03 truth: the RMS of 0.03 t over the mean of t is 0.03 sqrt(<t^2>)/<t>,
        // exactly what nimbus-compare would say; the mean ratio is 1.03.
        let t = truths(400);
        let samples: Vec<BlockSample> = t.iter().map(|&t| BlockSample { render: 1.03 * t, truth: t, truth_var: DVec3::ZERO, truth_alpha: 1.0 }).collect();
        let e = estimate(&samples).unwrap();
        let sq = t.iter().map(|t| (t * t).element_sum() / 3.0).sum::<f64>() / 400.0;
        let mean = t.iter().map(|t| t.element_sum() / 3.0).sum::<f64>() / 400.0;
        let expect = 0.03 * sq.sqrt() / mean;
        assert!((e.rel_rmse - expect).abs() < 1e-12, "{} vs {expect}", e.rel_rmse);
        assert!((e.mean_ratio - 1.03).abs() < 1e-12);
        assert!(e.lo <= e.rel_rmse && e.rel_rmse <= e.hi && e.hi - e.lo < 0.01, "{e:?}");
        // An absolute bias on a constant truth: exactly the bias over the level.
        let flat: Vec<BlockSample> = (0..50).map(|_| BlockSample { render: DVec3::splat(2.04), truth: DVec3::splat(2.0), truth_var: DVec3::ZERO, truth_alpha: 0.5 }).collect();
        let e = estimate(&flat).unwrap();
        assert!((e.rel_rmse - 0.02).abs() < 1e-12 && (e.lo - 0.02).abs() < 1e-9 && (e.hi - 0.02).abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn uncovered_blocks_count_in_the_mean_ratio_only() {
        let mut samples = vec![BlockSample { render: DVec3::splat(1.1), truth: DVec3::ONE, truth_var: DVec3::ZERO, truth_alpha: 0.9 }; 10];
        samples.push(BlockSample { render: DVec3::splat(5.0), truth: DVec3::splat(0.01), truth_var: DVec3::ZERO, truth_alpha: 0.005 });
        let e = estimate(&samples).unwrap();
        assert_eq!(e.covered, 10);
        assert!((e.rel_rmse - 0.1).abs() < 1e-12);
        assert!((e.mean_ratio - 16.0 / 10.01).abs() < 1e-12);
        // Nothing covered: nothing to report.
        assert!(estimate(&samples[10..]).is_none());
        assert!(estimate(&[]).is_none());
    }

    #[test]
    fn the_truth_s_noise_is_taken_out_and_the_interval_covers() {
        // The render is 2% off the exact truth everywhere (a relative bias, so the error is
        // known in closed form); the truth is seen through noise of 4% of its level per block,
        // twice the error. Uncorrected, the measure would say sqrt(2^2 + 4^2) = 4.5%; the
        // correction must find 2%, and its interval must hold 2% in about 95% of trials.
        let t = truths(512);
        let sq = t.iter().map(|t| (t * t).element_sum() / 3.0).sum::<f64>() / t.len() as f64;
        let mean = t.iter().map(|t| t.element_sum() / 3.0).sum::<f64>() / t.len() as f64;
        let exact = 0.02 * sq.sqrt() / mean;
        let trials = 400;
        let (mut covered, mut sum, mut raw_sum) = (0, 0.0, 0.0);
        for trial in 0..trials {
            let mut rng = Rng::with_domain(trial, 0, 9);
            let samples: Vec<BlockSample> = t
                .iter()
                .map(|&t| {
                    let sd = 0.04 * t;
                    let seen = t + sd * DVec3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng));
                    // The variance as a sample variance of 64 draws would estimate it: scaled
                    // by a chi-square-ish factor around 1.
                    let noisy_var = sd * sd * (1.0 + 0.18 * normal(&mut rng));
                    BlockSample { render: 1.02 * t, truth: seen, truth_var: noisy_var, truth_alpha: 1.0 }
                })
                .collect();
            let e = estimate(&samples).unwrap();
            let raw = (samples.iter().map(|s| (s.render - s.truth).length_squared() / 3.0).sum::<f64>() / 512.0).sqrt() / mean;
            sum += e.rel_rmse;
            raw_sum += raw;
            if e.lo <= exact && exact <= e.hi {
                covered += 1;
            }
            assert!(e.lo <= e.rel_rmse && e.rel_rmse <= e.hi, "{e:?}");
        }
        let (mean_estimate, mean_raw) = (sum / trials as f64, raw_sum / trials as f64);
        eprintln!("exact {exact:.5}, corrected {mean_estimate:.5}, uncorrected {mean_raw:.5}, interval covered {covered}/{trials}");
        assert!(mean_raw > 2.0 * exact, "the noise dominates the uncorrected measure: {mean_raw}");
        assert!((mean_estimate / exact - 1.0).abs() < 0.05, "corrected {mean_estimate} against {exact}");
        // 95% nominal; 400 trials put the count's standard deviation at 4.4.
        assert!((360..=395).contains(&covered), "the interval held the exact error {covered} times in {trials}");
    }

    #[test]
    fn the_choice_is_uniform_reproducible_and_takes_all_when_few() {
        let all: Vec<u64> = (0..1000).collect();
        let a = choose(all.clone(), 100, 5);
        assert_eq!(a, choose(all.clone(), 100, 5));
        assert_ne!(a, choose(all.clone(), 100, 6));
        assert_eq!(a.len(), 100);
        assert!(a.windows(2).all(|w| w[0] < w[1]), "distinct, in raster order");
        // Roughly uniform: as many from each half.
        let low = a.iter().filter(|&&i| i < 500).count();
        assert!((35..=65).contains(&low), "{low}");
        assert_eq!(choose(vec![3, 1, 2], 10, 0), vec![3, 1, 2]);
    }

    #[test]
    fn a_reference_verifies_near_its_noise_and_a_scaled_one_near_its_scale() {
        use crate::cpu::scenes::{camera, cloud};
        use nimbus_optics::{Light, Medium};
        let centre = glam::DVec3::new(0.3, -0.2, 0.1);
        let density = cloud(16, 4.0, centre);
        let params = ReferenceParams {
            environment: None,
            environment_visible: false,
            medium: Medium { extinction: 1.0, albedo: glam::Vec3::new(0.9, 0.8, 0.7), g: 0.3 },
            lights: vec![Light::default_sun()],
            camera: camera(centre, 32, 24),
            spp: 256,
            max_depth: ReferenceParams::DEFAULT_MAX_DEPTH,
            background: glam::Vec3::ZERO,
            seed: 4,
            aovs: false,
        };
        let image = crate::render_reference_cpu(&density, &params, &|_| {}).unwrap();
        let opts = VerifyParams::default();
        let v = verify_cpu(&image, &density, &params, MediumFields::default(), &opts).unwrap();
        let e = v.estimate.unwrap();
        eprintln!("the reference at 256 spp: {} ({e:?}, {v:?})", v.summary());
        // Its only error is its own noise, 256 paths a pixel over 2 x 2 blocks: 4.7% here
        // (the truth's blocks need up to 8192 paths a pixel for 0.7%, so 1024 give ~5%).
        assert!(e.rel_rmse < 0.08 && e.lo <= e.rel_rmse && e.rel_rmse <= e.hi, "{e:?}");
        assert!((e.mean_ratio - 1.0).abs() < 0.02, "{e:?}");
        // A third of the target where no block meets the cap on paths; here over half of
        // them do (a sun from above the cloud's edge: a path's radiance varies 1.2x its mean).
        assert!(e.truth_noise < opts.target / if v.capped == 0 { 2.9 } else { 1.5 }, "the truth's noise is driven under the target: {e:?}");
        assert!(v.drawn < 192 && e.covered > 30, "every covered block of 16 x 12 is drawn: {v:?}");
        // The same image 10% too bright is 10% of its RMS level off (14.5% here: the blocks
        // vary about their mean, and the 1.1x noise adds in quadrature).
        let mut bright = image.clone();
        bright.rgba.iter_mut().for_each(|p| *p = glam::Vec4::new(1.1 * p.x, 1.1 * p.y, 1.1 * p.z, p.w));
        let b = verify_cpu(&bright, &density, &params, MediumFields::default(), &opts).unwrap();
        let be = b.estimate.unwrap();
        eprintln!("10% brighter: {}", b.summary());
        assert!(be.rel_rmse > 0.09 && be.rel_rmse < 0.2 && be.lo < be.rel_rmse && be.hi > be.rel_rmse, "{be:?}");
        assert!((be.mean_ratio - 1.1).abs() < 0.02 && be.ratio_lo < 1.1 && be.ratio_hi > 1.1, "{be:?}");
        // Reproducible: the same seed draws the same truth.
        assert_eq!(verify_cpu(&bright, &density, &params, MediumFields::default(), &opts).unwrap().estimate, b.estimate);
        // A mismatched image is refused, not read out of bounds.
        let small = Image { width: 8, height: 6, rgba: vec![glam::Vec4::ZERO; 48], ..image };
        assert!(verify_cpu(&small, &density, &params, MediumFields::default(), &opts).is_err());
    }

    #[test]
    fn the_attribute_is_fractions() {
        let v = Verification {
            estimate: Some(Estimate { rel_rmse: 0.0162, lo: 0.0141, hi: 0.0185, mean_ratio: 0.998, ratio_lo: 0.99, ratio_hi: 1.0, covered: 512, truth_noise: 0.005 }),
            drawn: 520,
            block: 2,
            paths: 0,
            spp_range: (64, 900),
            capped: 0,
        };
        assert_eq!(v.attribute(), "rel_rmse=0.016200,lo=0.014100,hi=0.018500,mean_ratio=0.998000,pixels=512,block=2");
        assert!(v.summary().starts_with("relative RMSE 1.62% (95%: 1.41-1.85%), mean ratio 0.998"), "{}", v.summary());
    }
}
