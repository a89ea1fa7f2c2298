//! The GPU backend reports progress as the CPU backend does (issue #31): each pass's task
//! is heard to its total in more than one step, and hearing it changes nothing the estimate
//! computes. One test: the progress sink is the process's. Small: lavapipe runs on two cores.

use glam::DVec3;
use nimbus_density::{estimate_gpu, DensityParams, Method, ParticleSet, Resolution};
use nimbus_progress::Tally;

/// A ball of particles, jittered by a hash (no dependency on a generator).
fn ball(n: usize) -> ParticleSet {
    let jitter = |i: usize, k: u64| ((i as u64 * 2654435761 + k * 40503) % 1000) as f64 / 1000.0 - 0.5;
    let positions = (0..n).map(|i| DVec3::new(jitter(i, 1), jitter(i, 2), jitter(i, 3)) * 4.0).filter(|p| p.length() < 2.0).collect();
    ParticleSet::new(positions)
}

#[test]
fn every_gpu_pass_reports_progress_and_hearing_it_changes_nothing() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let particles = ball(3000);
    for (method, conserve_mass, tasks) in [
        (Method::Asl3, false, &["density"][..]),
        (Method::Ici, false, &["smoothing lengths", "density"][..]),
        (Method::Asl2, true, &["smoothing lengths", "density"][..]),
    ] {
        let params = DensityParams { method, conserve_mass, resolution: Resolution::Longest(40), ..DensityParams::default() };
        let unheard = estimate_gpu(ctx, &particles, &params).unwrap();
        let (heard, tally) = Tally::during(|| estimate_gpu(ctx, &particles, &params).unwrap());
        for &what in tasks {
            let task = tally.iter().find(|t| t.what == what).unwrap_or_else(|| panic!("{method:?}: no task '{what}' in {tally:?}"));
            assert!(task.total > 1 && task.done == task.total && task.steps > 1, "{method:?}: {task:?}");
        }
        let values = |v: &nimbus_volume::Volume<f32>| v.bricks().map(|b| (b.origin, b.values.to_vec())).collect::<Vec<_>>();
        assert!(values(&heard.density) == values(&unheard.density), "{method:?}: the estimate changed when heard");
    }
}
