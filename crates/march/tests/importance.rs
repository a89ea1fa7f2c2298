//! vdbcache spends its paths by the camera's image derivatives
//! ([`nimbus_cache::CameraImportance`]); here they are checked against the march itself, one
//! cache voxel at a time: a cache holding 1 at voxel v and 0 elsewhere renders each pixel's
//! derivative with respect to v's value.

mod common;

use common::{camera, cloud, params};
use glam::{DVec3, Vec3};
use nimbus_cache::{CachePlan, CameraImportance, IlluminationCache};
use nimbus_march::{march_ray, MarchParams};
use nimbus_optics::Medium;
use nimbus_volume::MajorantGrid;

#[test]
fn importance_is_the_sum_of_squared_pixel_derivatives_of_the_march() {
    let density = cloud(24, 25.0, DVec3::ZERO);
    let (w, h) = (12, 8);
    let cam = camera(DVec3::ZERO, w, h);
    let majorant = MajorantGrid::build(&density);
    let plan = CachePlan::new(&density, &majorant, &cam, 2.0);
    let medium = Medium { extinction: 1.5, albedo: Vec3::splat(0.8), g: 0.0 };
    let importance = CameraImportance::new(&plan, &density, &majorant, medium.extinction, &cam, 0.0);
    let g = &importance.g;
    assert_eq!(g.len() as u64, plan.stats.baked);
    // The march on importance's own terms: its step (half the cache voxel), the sample
    // lattice at xi = 0.5, the centres of each pixel's quarters.
    let march = MarchParams { medium, step: 0.5 * plan.transform.voxel_size().min_element(), max_step_factor: 1, offset_noise: 0.0, min_transmittance: 0.0, ..params(cam.clone()) };

    let mut order: Vec<usize> = (0..g.len()).collect();
    order.sort_by(|&a, &b| g[b].total_cmp(&g[a]));
    let seen = order.iter().filter(|&&v| g[v] > 0.0).count();
    assert!(seen > 10 && seen < g.len(), "some voxels are read by the camera's rays and some are not: {seen} of {}", g.len());
    // The most important voxel, a few down the order, the least seen, and unseen ones.
    let picked = [order[0], order[seen / 4], order[seen / 2], order[seen - 1], order[seen], order[g.len() - 1]];
    for &v in &picked {
        let mut values = vec![Vec3::ZERO; g.len()];
        values[v] = Vec3::ONE;
        let cache = IlluminationCache { li_single: None, li_multiple: Some(plan.volume_of(&values).0) };
        let mut sum = 0.0f64;
        for py in 0..h {
            for px in 0..w {
                let mut a = 0.0f64;
                for (jx, jy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    let (origin, dir) = cam.ray(px as f64 + jx, py as f64 + jy);
                    let r = march_ray(&density, &majorant, &cache, &march, origin, dir, 0.5, 0.0);
                    a += r.multiple.x as f64 / medium.albedo.x as f64 / 4.0;
                }
                sum += a * a;
            }
        }
        eprintln!("voxel {v}: importance {:.6e}, march {sum:.6e}", g[v]);
        // G is summed in fixed point: terms under 2^-40 are dropped.
        let resolution = 2f64.powi(-40) * (w * h) as f64;
        if g[v] == 0.0 {
            assert!(sum <= resolution, "voxel {v}: the march reads it at {sum}, yet its importance is 0");
        } else {
            assert!((sum - g[v]).abs() <= 1e-4 * g[v] + resolution, "voxel {v}: importance {}, march {sum}", g[v]);
        }
    }
    // And they differ by orders of magnitude, which is what the paths follow.
    assert!(g[order[0]] > 100.0 * g[order[seen - 1]]);
}
