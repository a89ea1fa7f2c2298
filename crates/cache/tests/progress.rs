//! The GPU bake reports progress as the CPU bake does (issue #31): single scattering in
//! voxels and the paths in paths, each task heard to its total in more than one dispatch,
//! and hearing it changes nothing baked. One test: the progress sink is the process's.
//! Small: lavapipe runs on two cores.

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_gpu, CacheParams, MultipleEstimator};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_photon::PhotonMap;
use nimbus_progress::Tally;
use nimbus_volume::{Transform, Volume};

mod support;

#[test]
fn the_gpu_bake_reports_progress_and_hearing_it_changes_nothing() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let mut density = Volume::new(Transform::uniform(0.1, DVec3::ZERO), 0.0);
    for x in -6..=6 {
        for y in -6..=6 {
            for z in -6..=6 {
                let r = IVec3::new(x, y, z).as_vec3().length() / 6.0;
                if r < 1.0 {
                    density.set(IVec3::new(x, y, z), 2.0 * (1.0 - r));
                }
            }
        }
    }
    let (lo, hi) = density.world_bounds().unwrap();
    let medium = Medium { extinction: 3.0, albedo: Vec3::splat(0.9), g: 0.3 };
    let sun = Light::sun(Vec3::new(0.3, 0.2, -1.0).normalize(), Vec3::ONE).unwrap();
    let camera = Camera::new(DVec3::new(0.3, -4.0, 1.0), 0.5 * (lo + hi), DVec3::Z, 45.0, 24, 16).unwrap();
    let params = CacheParams { multiple: true, multiple_scale: Some(1.0), estimator: MultipleEstimator::Paths { per_voxel: 8 }, seed: 1, ..support::params(medium, vec![sun], camera) };
    let photons = PhotonMap::default();
    let unheard = bake_gpu(ctx, &density, &photons, &params).unwrap().0;
    let (heard, tally) = Tally::during(|| bake_gpu(ctx, &density, &photons, &params).unwrap().0);
    for what in ["single scattering", "paths"] {
        let task = tally.iter().find(|t| t.what == what).unwrap_or_else(|| panic!("no task '{what}' in {tally:?}"));
        assert!(task.total > 1 && task.done == task.total && task.steps > 1, "{task:?}");
    }
    let values = |v: &Option<Volume<Vec3>>| v.as_ref().unwrap().bricks().map(|b| (b.origin, b.values.to_vec())).collect::<Vec<_>>();
    assert!(values(&heard.li_single) == values(&unheard.li_single), "Li_single changed when heard");
    assert!(values(&heard.li_multiple) == values(&unheard.li_multiple), "Li_multiple changed when heard");
}
