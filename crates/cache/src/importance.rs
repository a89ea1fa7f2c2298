//! How much each cache voxel's value moves the camera's image: where the path-traced
//! Li_multiple spends its paths.
//!
//! The march adds, per camera-ray sample x, `T (1 - exp(-sigma_t dt)) albedo Li(x)`, with
//! Li(x) interpolated trilinearly from the cache. So pixel p depends on voxel v's value
//! linearly, with derivative `a_pv = albedo * sum over p's samples of T (1 - exp(-sigma_t dt))
//! w_v(x)` (w_v the trilinear weight). A voxel estimated from n_v paths of per-path variance
//! s_v^2 adds `G_v s_v^2 / n_v` to the image's summed squared error, `G_v = sum_p a_pv^2`;
//! for a fixed number of paths that is least with n_v proportional to `sqrt(G_v) s_v`. The
//! per-path spread s_v is not known before tracing and is taken as equal (a pilot pass that
//! measured it per brick, and the paths' cost, bought nothing over this on the bundled cloud
//! at equal CPU time), so the paths go as sqrt(G_v). That follows the transmittance toward the
//! eye (what a voxel's value is seen through), the density around the voxel (a voxel in thin
//! air beside a cloud is read with small weights) and how many pixels read it at all (a
//! coarse image reads a fine lattice only along its rays).

use glam::{DVec3, IVec3};
use nimbus_optics::Camera;
use nimbus_volume::{lattice_cell, MajorantGrid, Volume};
use rayon::prelude::*;

use std::sync::atomic::{AtomicU64, Ordering};

use crate::plan::VoxelIndex;
use crate::{CacheParams, CachePlan};

/// One in G's fixed point. A pixel's derivative is at most 1 (its opacity), so each term is
/// at most 1 and G at most the rays' count ([`IMPORTANCE_RAYS`] < 2^24), well within 64 bits;
/// terms under 2^-40 (derivatives under 1e-6) are too small to earn a path anyway.
const G_FIXED_ONE: f64 = (1u64 << 40) as f64;

/// At most this many camera rays estimate the importance: 2 x 2 per pixel while the image
/// is small (the march jitters over the pixel), one through every s-th pixel's centre each way
/// beyond that. G_v is a smooth function of the image, and only its proportions matter.
pub const IMPORTANCE_RAYS: usize = 1 << 16;

/// G_v per planned voxel, in plan order ([`CachePlan::voxel_positions`]), up to one common
/// factor.
pub struct CameraImportance {
    pub g: Vec<f64>,
}

impl CameraImportance {
    /// Marches the camera's rays through the density as `vdbmarch` does (step: half the
    /// plan's voxel edge) and sums each pixel's derivatives per voxel of `plan`.
    pub fn new(plan: &CachePlan, density: &Volume<f32>, majorant: &MajorantGrid, extinction: f32, camera: &Camera, min_transmittance: f64) -> CameraImportance {
        let index = plan.voxel_index();
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        // Rays per pixel side (2) or pixels per ray side (stride).
        let (sub, stride) = if w * h * 4 <= IMPORTANCE_RAYS { (2, 1) } else { (1, ((w * h) as f64 / IMPORTANCE_RAYS as f64).sqrt().ceil() as usize) };
        let (sw, sh) = (w.div_ceil(stride), h.div_ceil(stride));
        let step = 0.5 * plan.transform.voxel_size().min_element();
        // A pixel's value is the mean of its rays'.
        let per_ray = 1.0 / (sub * sub) as f64;
        let transform = density.transform();
        // Summed in fixed point, so G (and the paths, and the cache) does not depend on the
        // order the threads add in.
        let fixed: Vec<AtomicU64> = (0..plan.stats.baked).map(|_| AtomicU64::new(0)).collect();
        (0..sw * sh).into_par_iter().for_each_init(Vec::<(u32, f64)>::new, |derivs, p| {
            derivs.clear();
            let (px, py) = ((p % sw * stride) as f64, (p / sw * stride) as f64);
            for s in 0..sub * sub {
                // The centres of the pixel's 2 x 2 quarters, or of the stride's block.
                let (jx, jy) = match stride {
                    1 => (((s % sub) as f64 + 0.5) / sub as f64, ((s / sub) as f64 + 0.5) / sub as f64),
                    _ => (0.5 * stride as f64, 0.5 * stride as f64),
                };
                let (origin, dir) = camera.ray(px + jx, py + jy);
                let (o, d) = (transform.to_index(origin), transform.dir_to_index(dir));
                let mut tr = 1.0f64;
                'ray: for seg in majorant.walk(o, d, 0.0, f64::INFINITY) {
                    if seg.majorant.is_nan() || seg.majorant <= 0.0 || seg.t_end.is_infinite() {
                        continue;
                    }
                    let mut k = (seg.t_start / step - 0.5).ceil();
                    loop {
                        let t = (k + 0.5) * step;
                        if t >= seg.t_end {
                            break;
                        }
                        k += 1.0;
                        let x = origin + dir * t;
                        let sigma_t = extinction as f64 * density.sample_world(x).max(0.0) as f64;
                        if !(sigma_t > 0.0) {
                            continue;
                        }
                        let step_transmittance = (-sigma_t * step).exp();
                        spread(&index, plan.transform.to_index(x), per_ray * tr * (1.0 - step_transmittance), derivs);
                        tr *= step_transmittance;
                        if tr < min_transmittance {
                            break 'ray;
                        }
                    }
                }
            }
            // One pixel's derivative per voxel is the sum over its samples; G adds
            // their squares.
            derivs.sort_unstable_by_key(|d| d.0);
            for run in derivs.chunk_by(|a, b| a.0 == b.0) {
                let a: f64 = run.iter().map(|d| d.1).sum();
                fixed[run[0].0 as usize].fetch_add((a * a * G_FIXED_ONE).round() as u64, Ordering::Relaxed);
            }
        });
        let g = fixed.into_iter().map(|f| f.into_inner() as f64 / G_FIXED_ONE).collect();
        CameraImportance { g }
    }

    /// The paths per voxel of `plan` for a `--paths per_voxel` bake: the one rule both
    /// backends trace by.
    pub fn path_counts(plan: &CachePlan, density: &Volume<f32>, majorant: &MajorantGrid, params: &CacheParams, per_voxel: u32) -> Vec<u32> {
        CameraImportance::new(plan, density, majorant, params.medium.extinction, &params.camera, params.min_transmittance).paths(per_voxel)
    }

    /// Paths per voxel, `per_voxel` times the voxels in all: one each (so every voxel holds
    /// an unbiased estimate, for other views too), the rest in proportion to sqrt(G_v),
    /// rounded along the running sum so the total is exact. Where the camera sees nothing,
    /// `per_voxel` each.
    pub fn paths(&self, per_voxel: u32) -> Vec<u32> {
        let total: f64 = self.g.iter().map(|g| g.sqrt()).sum();
        if !(total > 0.0 && total.is_finite()) {
            return vec![per_voxel; self.g.len()];
        }
        let rest = (per_voxel.max(1) as u64 - 1) as f64 * self.g.len() as f64;
        let (mut running, mut given) = (0.0f64, 0u64);
        self.g
            .iter()
            .map(|g| {
                running += g.sqrt();
                let due = (rest * (running / total)).round() as u64;
                let n = due.saturating_sub(given);
                given += n;
                (1 + n).min(u32::MAX as u64) as u32
            })
            .collect()
    }
}

/// Adds `weight` times each trilinear corner weight at cache index `c` (as
/// `Volume::sample_index` interpolates) to `out`, for the corners `index` plans.
fn spread(index: &VoxelIndex<'_>, c: DVec3, weight: f64, out: &mut Vec<(u32, f64)>) {
    let Some((b, f)) = lattice_cell(c) else { return };
    for corner in 0..8 {
        let o = IVec3::new((corner >> 2) & 1, (corner >> 1) & 1, corner & 1);
        let pick = |bit: i32, f: f64| if bit == 1 { f } else { 1.0 - f };
        let w = pick(o.x, f.x) * pick(o.y, f.y) * pick(o.z, f.z);
        if w > 0.0 {
            if let Some(i) = index.get(b + o) {
                out.push((i as u32, weight * w));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_add_up_exactly_and_follow_the_square_root_of_importance() {
        // Importance 0 (unseen), 1, 4, 16, 100 times over: the rest goes as 0:1:2:4.
        let g: Vec<f64> = [0.0, 1.0, 4.0, 16.0].iter().copied().cycle().take(400).collect();
        let paths = CameraImportance { g: g.clone() }.paths(8);
        assert_eq!(paths.iter().map(|&n| n as u64).sum::<u64>(), 8 * 400, "N per voxel on average, exactly");
        assert!(paths.iter().all(|&n| n >= 1), "every voxel keeps an estimate");
        let mean = |k: usize| paths.iter().skip(k).step_by(4).map(|&n| n as f64).sum::<f64>() / 100.0;
        assert_eq!(mean(0), 1.0, "unseen voxels get their one path only");
        // The 7 x 400 paths beyond the first go 1:2:4 over sqrt(G) = 1, 2, 4.
        let unit = 7.0 * 400.0 / (100.0 * 7.0);
        for (k, share) in [(1, 1.0), (2, 2.0), (3, 4.0)] {
            assert!((mean(k) - 1.0 - share * unit).abs() < 0.01, "sqrt(G) = {share}: {} paths", mean(k));
        }
    }

    #[test]
    fn a_camera_that_sees_nothing_gets_n_paths_everywhere() {
        assert_eq!(CameraImportance { g: vec![0.0; 5] }.paths(3), vec![3; 5]);
        assert_eq!(CameraImportance { g: vec![] }.paths(3), Vec::<u32>::new());
        assert_eq!(CameraImportance { g: vec![2.0, 0.0] }.paths(1), vec![1, 1]);
    }
}
