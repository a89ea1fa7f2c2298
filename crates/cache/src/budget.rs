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

use crate::{CachePlan, PathPlan};

/// Most paths the second pass may add, as a multiple of the first pass's: bounds the bake's
/// time where the predicted noise stays high (a medium no path count tames in reasonable
/// time; `-v` reports the noise left).
pub const MAX_PATH_GROWTH: f64 = 16.0;

/// The default tolerance on the paths' predicted relative noise in the image (`vdbcache
/// --path-tolerance`). The chain's target is 2% against the reference; the prediction is
/// per pixel and runs 1.1-1.4x above what 2 x 2 blocks of the image show, which leaves the
/// lattices and the march their share (docs/benchmarks.md, "Paths by the image's noise").
pub const PATH_TOLERANCE: f64 = 0.02;

/// One voxel's paths: their mean and the mean of their squares (over the colour channels).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathMoments {
    pub mean: Vec3,
    pub mean_square: f32,
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
        PathMoments { mean: a * self.mean + b * other.mean, mean_square: a * self.mean_square + b * other.mean_square }
    }
}

/// The relative noise the paths leave in the image (module doc), from the first pass's
/// moments in plan order; `single`, Li_single where it was baked, for the image's level.
pub fn predicted_noise(paths: &PathPlan, plan: &CachePlan, moments: &[PathMoments], single: Option<&Volume<Vec3>>) -> f64 {
    let positions = single.map(|_| plan.voxel_positions());
    let (mut error, mut level) = (0.0f64, 0.0f64);
    for (v, m) in moments.iter().enumerate() {
        let n = paths.counts[v];
        if n > 0 {
            error += paths.importance[v] * m.path_variance(n) / n as f64;
        }
        let single = match (single, &positions) {
            (Some(s), Some(p)) => s.sample_world(p[v]),
            _ => Vec3::ZERO,
        };
        let value = (m.mean + single).element_sum() as f64 / 3.0;
        if value.is_finite() {
            level += paths.read_weight[v] * value;
        }
    }
    if !(level > 0.0) || !error.is_finite() {
        return 0.0;
    }
    (paths.covered_rays as f64 * error).sqrt() / level
}

/// The second pass's paths per voxel for a predicted noise `noise` against `tolerance`:
/// none where the first pass meets it.
pub fn more_paths(paths: &PathPlan, noise: f64, tolerance: f64) -> Option<Vec<u32>> {
    if !(noise > tolerance && tolerance > 0.0) {
        return None;
    }
    let growth = ((noise / tolerance).powi(2)).min(MAX_PATH_GROWTH) - 1.0;
    Some(paths.counts.iter().map(|&n| (n as f64 * growth).ceil().min(u32::MAX as f64) as u32).collect())
}

/// The second pass's seed: its own streams, so its paths are independent of the first's.
pub fn second_pass_seed(seed: u64) -> u64 {
    seed ^ 0x5345_434f_4e44_0000 // "SECOND"
}
