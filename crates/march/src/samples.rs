//! How many samples a pixel takes by default, and how far apart along the ray.

use nimbus_optics::Camera;
use nimbus_volume::{Transform, Volume};

/// The default march step (world units) over a density on `transform`: a third of the
/// diagonal of a cube as thin as the voxel's thinnest width, `width / sqrt(3)`. On cubic
/// voxels that is a third of the voxel's diagonal, as it always was; on flat or sheared
/// voxels it follows the thin side, which is where the density changes fastest per unit
/// length: a third of the long diagonal of 0.04 x 0.04 x 0.01 voxels stepped 1.9 voxels
/// through a sheet six voxels thick (`nimbus-scene sheet`: 1.9% off the brute-force single
/// scattering at a quarter-voxel cache, 0.21% at this step; docs/benchmarks.md).
pub fn default_step(transform: &Transform) -> f64 {
    transform.voxel_widths().min_element() / 3f64.sqrt()
}

/// Most a default step is divided where the medium is dense ([`step_subdivision`]): the
/// march takes the divided step everywhere in the medium, so this bounds its cost (the
/// bundled plume's march 0.31 -> 1.24 s at 320 x 180 at 16, for nothing: it is thin per step
/// but for a few voxels), and a quarter already brought the dense layer below within 0.25%.
pub const MAX_STEP_SUBDIVISION: u32 = 4;

/// How many steps the default step `step` is cut into so that a step through the densest
/// medium, `extinction x density max`, holds at most [`crate::STEP_OPTICAL_DEPTH`] (1 to
/// [`MAX_STEP_SUBDIVISION`]; issue #47). A sample stands for its step as if the medium and
/// Li were constant along it, which a step of optical depth 2 is far from: `nimbus-scene
/// --random 20261207000`, a layer of 1.2 optical depths a voxel, had its single scattering
/// 0.91% off the brute-force march at the default step, 0.21% at a quarter of it. The step
/// is cut everywhere, not only in dense majorant cells: grouping the finer lattice back up
/// where the majorant allows (`max_step_factor`, the lattice of `MarchParams::step_factor`)
/// came out worse than the plain default step on a dense cloud (0.85% against 0.45% off a
/// sixty-fourth of the step, the uncut finer lattice 0.02%: `tests/render.rs`), for a
/// reason not yet found.
pub fn step_subdivision(step: f64, extinction: f32, density_max: f32) -> u32 {
    let depth = step * extinction as f64 * density_max as f64;
    let k = (depth / crate::STEP_OPTICAL_DEPTH).ceil();
    // NaN (an empty volume) and thin media keep the step.
    if k > 1.0 {
        k.min(MAX_STEP_SUBDIVISION as f64) as u32
    } else {
        1
    }
}

pub use nimbus_cache::MAX_SAMPLES_PER_PIXEL_SIDE as MAX_DEFAULT_SAMPLES_PER_SIDE;

/// The default samples per pixel for `camera` over `density`: n x n stratified samples,
/// [`nimbus_cache::pixel_samples_per_side`] (the rule and its measurements are there: the
/// cache's importance rays read the pixel at the same samples, so the bake spends its paths
/// where the march will read).
pub fn default_spp(camera: &Camera, density: &Volume<f32>) -> u32 {
    let n = nimbus_cache::pixel_samples_per_side(camera, density);
    n * n
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DVec3, IVec3};
    use nimbus_volume::Transform;

    #[test]
    fn the_step_follows_the_thinnest_width() {
        let cube = Transform::uniform(0.3, DVec3::ONE);
        assert!((default_step(&cube) - cube.voxel_size().length() / 3.0).abs() < 1e-15, "a third of a cube's diagonal");
        let flat = Transform::new(glam::DAffine3::from_scale(DVec3::new(0.04, 0.04, 0.01))).unwrap();
        assert!((default_step(&flat) - 0.01 / 3f64.sqrt()).abs() < 1e-15);
        // Sheared 45 degrees: edges 1 and sqrt 2, but opposite faces 1/sqrt 2 apart.
        let sheared = Transform::new(glam::DAffine3::from_cols(DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Z, DVec3::ZERO)).unwrap();
        assert!((sheared.voxel_widths() - DVec3::new(2f64.sqrt().recip(), 1.0, 1.0)).abs().max_element() < 1e-12, "{}", sheared.voxel_widths());
    }

    #[test]
    fn samples_follow_the_pixel_footprint_over_the_voxel() {
        let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0f32);
        v.set(IVec3::ZERO, 1.0);
        // 100 units away, 40 degrees: a pixel 72.8 / width units wide.
        let camera = |width| Camera::new(DVec3::new(0.0, -100.0, 0.0), DVec3::ZERO, DVec3::Z, 40.0, width, width / 2).unwrap();
        assert_eq!(default_spp(&camera(1024), &v), 1, "pixels a fourteenth of a voxel");
        assert_eq!(default_spp(&camera(256), &v), 4, "0.28 voxels: 2 x 2");
        assert_eq!(default_spp(&camera(128), &v), 9, "pixels 0.57 voxels wide: 3 x 3");
        assert_eq!(default_spp(&camera(64), &v), 25, "1.14 voxels: 5 x 5");
        assert_eq!(default_spp(&camera(32), &v), 64, "2.28 voxels: 8 x 8");
        assert_eq!(default_spp(&camera(8), &v), 64, "at most 8 x 8");
        assert_eq!(default_spp(&camera(128), &Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0)), 1, "an empty volume");
    }
}
