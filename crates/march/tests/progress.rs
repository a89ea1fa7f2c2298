//! The GPU march reports progress as the CPU march does (issue #31): the `march` task is
//! heard to its total (pixels) in more than one tile, and hearing it changes no pixel. One
//! test: the progress sink is the process's. Small: lavapipe runs on two cores.

mod common;

use common::{cache_for, camera, cloud, gpu, params};
use glam::DVec3;
use nimbus_march::render_gpu;
use nimbus_progress::Tally;

#[test]
fn the_gpu_march_reports_progress_and_hearing_it_changes_nothing() {
    let Some(ctx) = gpu() else { return };
    let centre = DVec3::new(2.0, -1.0, 0.5);
    let density = cloud(12, 2.0, centre);
    let cache = cache_for(&density);
    let p = params(camera(centre, 40, 30));
    let unheard = render_gpu(ctx, &density, &cache, &p).unwrap();
    let (heard, tally) = Tally::during(|| render_gpu(ctx, &density, &cache, &p).unwrap());
    let march = tally.iter().find(|t| t.what == "march").unwrap_or_else(|| panic!("no march task in {tally:?}"));
    assert!(march.total == 40 * 30 && march.done == march.total && march.steps > 1, "{march:?}");
    assert!(heard == unheard, "the image changed when heard");
}
