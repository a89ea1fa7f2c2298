//! How many paths the image asks for: the paths' own spread, measured, against a tolerance.
//!
//! The preset's paths per voxel (`--paths`' default) are a first pass. Each voxel's paths
//! give its mean L_v and the spread of one path, s_v^2 (the sample variance, averaged over
//! the colour channels). Pixel p reads voxel v with derivative a_pv (importance.rs), so the
//! image's summed squared error from the paths is `sum_v G_v s_v^2 / n_v`, and its summed
//! level `sum_v W_v (L_v + Li_single(v))` (W_v = sum_p a_pv). Their ratio over the pixels
//! the rays cover is the relative noise the paths leave in the image, predicted:
//!
//! `e = sqrt(P sum_v G_v s_v^2 / n_v) / sum_v W_v (L_v + Li_single(v))`, P the covered rays.
//!
//! Where e exceeds the tolerance, a second pass traces `(e / tolerance)^2 - 1` times each
//! voxel's paths again (at most [`MAX_PATH_GROWTH`] times the first pass in all), with a
//! seed of their own, and each voxel keeps the mean of all its paths. The count depends on
//! the first pass's spread, not on the scene's name: strong forward scattering, whose paths
//! reach the light rarely and with large weights, gets many more paths; a bright, diffuse
//! medium gets none beyond the first pass. Both backends run the same rule on the host.

use glam::Vec3;
use nimbus_volume::Volume;

use crate::{BakeStats, CacheParams, CachePlan, PathPlan};

/// Most paths the second pass may add, as a multiple of the first pass's: bounds the bake's
/// time where the predicted noise stays high (a medium no path count tames in reasonable
/// time; `-v` reports the noise left).
pub const MAX_PATH_GROWTH: f64 = 16.0;

/// The default tolerance on the image's relative error against the reference (`vdbcache
/// --path-tolerance`, alias `--tolerance`): the chain's target, 2%. It is a budget (issue
/// #47): the errors the bake estimates (Li_single's and Li_multiple's lattice biases, the
/// paths' noise) and a margin for what it does not (the march's quadrature of the pixel and
/// the step, the light tables, what the estimates miss) add in quadrature to at most it; the
/// paths get what the rest leave ([`paths_share`]).
pub const PATH_TOLERANCE: f64 = 0.02;

/// The margin for what the bake does not estimate, as a fraction of the tolerance: a quarter
/// (0.5% of 2%). The march at its default samples and step measured 0.2-0.4% against
/// brute-force marches of the same cache (design.md section 5). What Li_multiple's lattice
/// estimates miss is not in it: the budget takes them at
/// [`crate::LATTICE_BIAS_UNDER_READ`] times their value.
pub const UNESTIMATED_SHARE: f64 = 0.25;

/// Least share of the tolerance the paths get, however large the lattices' estimates: the
/// lattices refine where their own tolerances ask, so a larger estimate here is one they
/// could not bring down (at their finest), and halving the paths' noise costs four times
/// the paths for what may be the estimate's own error.
pub const LEAST_PATHS_SHARE: f64 = 0.5;

/// The paths' share of the image's `tolerance`: what the lattices' estimated biases
/// (relative, in the image) and the unestimated margin leave of it, in quadrature, and at
/// least [`LEAST_PATHS_SHARE`] of it.
pub fn paths_share(tolerance: f64, biases: &[f64]) -> f64 {
    let spent: f64 = (UNESTIMATED_SHARE * tolerance).powi(2) + biases.iter().filter(|b| b.is_finite()).map(|b| b * b).sum::<f64>();
    (tolerance * tolerance - spent).max((LEAST_PATHS_SHARE * tolerance).powi(2)).sqrt()
}

/// One voxel's paths: their mean and the mean of their squares (over the colour channels).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathMoments {
    pub mean: Vec3,
    pub mean_square: f32,
    /// The paths' estimates (the channels' mean) summed by the parity of their index and the
    /// octant of their origin about the node, index `8 * parity + octant`: two independent
    /// halves of the paths, spread over the footprint (multiple_lattice.rs).
    pub halves: [f32; 16],
}

impl PathMoments {
    /// The sample variance of one path (the channels' mean), from `n` paths.
    fn path_variance(&self, n: u32) -> f64 {
        if n < 2 {
            return 0.0;
        }
        let square_of_mean = self.mean.length_squared() as f64 / 3.0;
        (self.mean_square as f64 - square_of_mean).max(0.0) * n as f64 / (n - 1) as f64
    }

    /// The mean over both passes' paths.
    pub fn merged(self, n: u32, other: PathMoments, m: u32) -> PathMoments {
        if m == 0 {
            return self;
        }
        let (a, b) = (n as f32 / (n + m) as f32, m as f32 / (n + m) as f32);
        let halves = std::array::from_fn(|k| self.halves[k] + other.halves[k]);
        PathMoments { mean: a * self.mean + b * other.mean, mean_square: a * self.mean_square + b * other.mean_square, halves }
    }
}

/// The relative noise the paths leave in the image (module doc), from the moments of
/// `counts[v]` paths per voxel in plan order, weighed by `paths`' image weights; `single`,
/// Li_single's level (the channels' mean) at each voxel where it was baked (else empty),
/// counts toward the image's level.
pub fn predicted_noise(paths: &PathPlan, counts: &[u32], moments: &[PathMoments], single: &[f32]) -> f64 {
    let (mut error, mut level) = (0.0f64, 0.0f64);
    for (v, m) in moments.iter().enumerate() {
        let n = counts[v];
        if n > 0 {
            error += paths.importance[v] * m.path_variance(n) / n as f64;
        }
        let value = m.mean.element_sum() as f64 / 3.0 + single.get(v).copied().unwrap_or(0.0) as f64;
        if value.is_finite() {
            level += paths.read_weight[v] * value;
        }
    }
    if !(level > 0.0) || !error.is_finite() {
        return 0.0;
    }
    (paths.covered_rays as f64 * error).sqrt() / level
}

/// Li_single's level (the channels' mean) at each of `plan`'s voxels, for
/// [`predicted_noise`]; empty without it.
pub fn single_levels(plan: &CachePlan, single: Option<&Volume<Vec3>>) -> Vec<f32> {
    single.map_or_else(Vec::new, |s| plan.voxel_positions().iter().map(|&x| s.sample_world(x).element_sum() / 3.0).collect())
}

/// The second pass's paths per voxel for a predicted noise `noise` against `tolerance`:
/// none where the first pass meets it.
pub fn more_paths(paths: &PathPlan, noise: f64, tolerance: f64) -> Option<Vec<u32>> {
    extra_paths(&paths.counts, &paths.counts, noise, tolerance, MAX_PATH_GROWTH)
}

/// The next pass's paths per voxel for voxels holding `counts` paths (`first` of them the
/// first pass's) at a predicted noise `noise` against `tolerance`: each voxel's count grown
/// by the squared ratio, up to `cap` times its first pass ([`MAX_PATH_GROWTH`], more where
/// the first pass was cut: [`Passes::growth_cap`]); none where the paths so far meet it (or
/// no voxel may grow).
fn extra_paths(counts: &[u32], first: &[u32], noise: f64, tolerance: f64, cap: f64) -> Option<Vec<u32>> {
    if !(noise > tolerance && tolerance > 0.0) {
        return None;
    }
    let growth = wanted_growth(noise, tolerance);
    let extra: Vec<u32> = counts
        .iter()
        .zip(first)
        .map(|(&n, &f)| {
            let wanted = (n as f64 * growth).min(f as f64 * cap).ceil();
            (wanted - n as f64).clamp(0.0, u32::MAX as f64) as u32
        })
        .collect();
    extra.iter().any(|&e| e > 0).then_some(extra)
}

/// The paths in all, as a multiple of the first pass's, that a first pass of predicted noise
/// `noise` asks for to meet `tolerance` (the noise goes as one over the root of the paths).
fn wanted_growth(noise: f64, tolerance: f64) -> f64 {
    (noise / tolerance).powi(2)
}

/// The noise the paths were left at where the growth cap (`cap` times the first pass,
/// [`BakeStats::path_growth_cap`]) stopped the top-ups short of `tolerance` (`path_noise` as
/// [`BakeStats::path_noise`]: first pass, final); None where the tolerance was met or the cap
/// not reached (a fresh estimate after an uncapped second pass may land a hair above the
/// tolerance: that is not a shortfall).
pub fn noise_short_of(tolerance: f64, path_noise: Option<(f64, f64)>, cap: f64) -> Option<f64> {
    let (first, last) = path_noise?;
    (tolerance > 0.0 && wanted_growth(first, tolerance) > cap && last > tolerance).then_some(last)
}

/// The second pass's seed: its own streams, so its paths are independent of the first's.
pub fn second_pass_seed(seed: u64) -> u64 {
    seed ^ 0x5345_434f_4e44_0000 // "SECOND"
}

/// The paths stage both backends share, in passes so that the lattice's bias can be
/// estimated between them (multiple_lattice.rs): [`trace_first`] traces `plan`'s paths by
/// `trace(progress label, plan, seed)`; each [`Passes::top_up`] then adds a pass where the
/// predicted noise exceeds the tolerance it is given, merged in (at most [`MAX_PATH_GROWTH`]
/// times the first pass in all). `single` is Li_single's level at the voxels
/// ([`single_levels`], or empty). Records the paths traced, the noise predicted and the
/// stage's time in `stats`.
pub(crate) struct Passes {
    pub moments: Vec<PathMoments>,
    /// Paths per voxel so far, and the plans of the passes after the first.
    counts: Vec<u32>,
    pub more: Vec<PathPlan>,
    /// Most the top-ups grow a voxel's first pass: [`MAX_PATH_GROWTH`], times what the first
    /// pass was cut by on a refined lattice (multiple_lattice.rs), so a voxel may reach the
    /// same paths it could on the first lattice.
    growth_cap: f64,
}

/// [`Passes`]' first.
pub(crate) fn trace_first<E>(
    plan: &PathPlan,
    growth_cap: f64,
    params: &CacheParams,
    stats: &mut BakeStats,
    trace: &mut impl FnMut(&str, &PathPlan, u64) -> Result<Vec<PathMoments>, E>,
) -> Result<Passes, E> {
    let started = std::time::Instant::now();
    let moments = trace("paths", plan, params.seed)?;
    stats.add_stage("paths", started.elapsed().as_millis() as u64);
    stats.paths += plan.total();
    stats.path_growth_cap = growth_cap;
    Ok(Passes { moments, counts: plan.counts.clone(), more: Vec::new(), growth_cap })
}

/// The seed of the pass after `passes` earlier top-ups: each its own streams.
fn top_up_seed(seed: u64, passes: usize) -> u64 {
    match passes {
        0 => second_pass_seed(seed),
        n => second_pass_seed(seed) ^ ((n as u64) << 8) ^ 0x5448_4952_4400_0000, // "THIRD"
    }
}

impl Passes {
    /// Another pass where the noise predicted from the paths so far exceeds
    /// `noise_tolerance` (the module doc), merged in.
    pub(crate) fn top_up<E>(
        &mut self,
        plan: &PathPlan,
        single: &[f32],
        noise_tolerance: f64,
        params: &CacheParams,
        stats: &mut BakeStats,
        trace: &mut impl FnMut(&str, &PathPlan, u64) -> Result<Vec<PathMoments>, E>,
    ) -> Result<(), E> {
        let started = std::time::Instant::now();
        stats.path_noise_tolerance = Some(noise_tolerance);
        let noise = predicted_noise(plan, &self.counts, &self.moments, single);
        let first = stats.path_noise.map_or(noise, |(first, _)| first);
        stats.path_noise = Some((first, noise));
        if let Some(extra) = extra_paths(&self.counts, &plan.counts, noise, noise_tolerance, self.growth_cap) {
            let more = plan.more(extra);
            let again = trace("more paths", &more, top_up_seed(params.seed, self.more.len()))?;
            for (v, (m, s)) in self.moments.iter_mut().zip(&again).enumerate() {
                *m = m.merged(self.counts[v], *s, more.counts[v]);
                self.counts[v] += more.counts[v];
            }
            stats.path_noise = Some((first, predicted_noise(plan, &self.counts, &self.moments, single)));
            stats.paths += more.total();
            self.more.push(more);
        }
        stats.add_stage("paths", started.elapsed().as_millis() as u64);
        Ok(())
    }

    /// Li_multiple on `voxels` (the moments' means), and its count of non-finite values
    /// (stored as zero).
    pub fn volume(&self, voxels: &CachePlan) -> (Volume<Vec3>, u64) {
        let values: Vec<Vec3> = self.moments.iter().map(|m| m.mean).collect();
        voxels.volume_of(&values)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paths_get_what_the_lattices_and_the_margin_leave_in_quadrature() {
        // Nothing estimated: the margin alone, sqrt(2^2 - 0.5^2) = 1.936%.
        assert!((paths_share(0.02, &[]) - 0.019365).abs() < 1e-6);
        // Li_multiple 1%, Li_single 0.6%: sqrt(4 - 0.25 - 1 - 0.36) = 1.546%.
        let share = paths_share(0.02, &[0.01, 0.006]);
        assert!((share - 0.015460).abs() < 1e-6, "{share}");
        let total = (share * share + 0.01f64.powi(2) + 0.006f64.powi(2) + (UNESTIMATED_SHARE * 0.02f64).powi(2)).sqrt();
        assert!((total - 0.02).abs() < 1e-12, "the parts add in quadrature to the tolerance");
        // Biases beyond the budget: the paths keep half of it; a NaN estimate counts nothing.
        assert_eq!(paths_share(0.02, &[0.03]), LEAST_PATHS_SHARE * 0.02);
        assert_eq!(paths_share(0.02, &[f64::NAN]), paths_share(0.02, &[]));
    }

    #[test]
    fn a_paths_spread_is_its_sample_variance_and_passes_merge_by_their_counts() {
        // Paths of 1 and 3 (grey): mean 2, mean square 5, sample variance 2.
        let m = PathMoments { mean: Vec3::splat(2.0), mean_square: 5.0, ..Default::default() };
        assert!((m.path_variance(2) - 2.0).abs() < 1e-12);
        assert_eq!(m.path_variance(1), 0.0, "one path has no spread to measure");
        let other = PathMoments { mean: Vec3::splat(5.0), mean_square: 25.0, ..Default::default() };
        let merged = m.merged(2, other, 1);
        assert!((merged.mean - Vec3::splat(3.0)).abs().max_element() < 1e-6);
        assert!((merged.mean_square - 35.0 / 3.0).abs() < 1e-5);
        assert_eq!(m.merged(2, other, 0), m, "no second pass: the first's moments");
    }

    #[test]
    fn the_predicted_noise_is_the_importance_weighted_variance_over_the_weighted_level() {
        // Two voxels: G 4 and 1, W 2 and 1, 4 and 2 paths of spread 3 and 0, means 1 and 2
        // (grey), Li_single 0.5 at the first; two covered rays.
        let plan = PathPlan { counts: vec![4, 2], first: vec![0; 2], origins: Vec::new(), octants: Vec::new(), importance: vec![4.0, 1.0], read_weight: vec![2.0, 1.0], covered_rays: 2 };
        // Sample variance 3 from 4 paths: mean square = 1 + 3 * 3 / 4.
        let moments = [PathMoments { mean: Vec3::ONE, mean_square: 1.0 + 2.25, ..Default::default() }, PathMoments { mean: Vec3::splat(2.0), mean_square: 4.0, ..Default::default() }];
        let error = 4.0 * 3.0 / 4.0; // G var / n, the second voxel's spread being 0
        let level = 2.0 * (1.0 + 0.5) + 1.0 * 2.0;
        let expected = (2.0f64 * error).sqrt() / level;
        assert!((predicted_noise(&plan, &plan.counts, &moments, &[0.5, 0.0]) - expected).abs() < 1e-6 * expected);
        assert_eq!(predicted_noise(&plan, &plan.counts, &[PathMoments::default(); 2], &[]), 0.0, "no light: nothing to be relative to");
    }

    #[test]
    fn the_second_pass_scales_every_voxels_paths_by_the_squared_noise_ratio_up_to_the_cap() {
        let plan = PathPlan { counts: vec![0, 1, 8, 20], first: vec![0; 4], origins: Vec::new(), octants: Vec::new(), importance: vec![0.0; 4], read_weight: vec![0.0; 4], covered_rays: 1 };
        assert_eq!(more_paths(&plan, 0.01, 0.02), None, "under the tolerance: no second pass");
        assert_eq!(more_paths(&plan, 0.03, 0.0), None, "0 turns it off");
        // Twice the tolerance: four times the paths in all, three more per path.
        assert_eq!(more_paths(&plan, 0.04, 0.02), Some(vec![0, 3, 24, 60]));
        // Ten times: capped at MAX_PATH_GROWTH in all.
        let capped = more_paths(&plan, 0.2, 0.02).unwrap();
        assert_eq!(capped, vec![0, 15, 120, 300]);
    }

    #[test]
    fn a_shortfall_is_the_noise_the_cap_left_above_the_tolerance() {
        // Ten times the tolerance asks for 100x the paths: the cap (16x) leaves 2.5x.
        assert_eq!(noise_short_of(0.02, Some((0.2, 0.05)), MAX_PATH_GROWTH), Some(0.05));
        assert_eq!(noise_short_of(0.02, Some((0.2, 0.019)), MAX_PATH_GROWTH), None, "the cap was enough");
        // Twice the tolerance asks for 4x: no cap, so a final 0.0201 is the estimate's wobble.
        assert_eq!(noise_short_of(0.02, Some((0.04, 0.0201)), MAX_PATH_GROWTH), None);
        assert_eq!(noise_short_of(0.02, None, MAX_PATH_GROWTH), None, "no tolerance asked for, nothing predicted");
        // A cut first pass may grow further: 100x within a cap of 128x is no shortfall.
        assert_eq!(noise_short_of(0.02, Some((0.2, 0.0201)), 128.0), None);
    }
}
