//! The paper's Figure 2 situation: a thin ball holding three dense balls, lit from above.
//! Traces the same photon budget with each distance-sampling mode and prints, per mode, the
//! photons emitted per photon stored (the paper's Figure 2 table), the time, and where the
//! stored photons sit: the fraction inside the dense balls and the mean height. Simpson and
//! delta tracking sample the same distribution; the exponential baseline (Eq. 1) freezes the
//! thin ball's sigma_t and flies through the dense balls.
//!
//!     cargo run --release -p nimbus-photon --example figure2 [-- PHOTONS]

use std::time::Instant;

use glam::{DVec3, IVec3};
use nimbus_optics::{Light, Medium};
use nimbus_photon::{trace_cpu, DistanceSampling, PhotonParams};
use nimbus_volume::{Transform, Volume};

const VOXEL: f64 = 0.02;
/// Centres (world) and radius of the three dense balls inside the unit-radius thin ball.
const DENSE: [[f64; 3]; 3] = [[-0.4, 0.0, 0.2], [0.35, 0.2, -0.1], [0.0, -0.3, -0.45]];
const DENSE_RADIUS: f64 = 0.22;

fn scene() -> Volume<f32> {
    let r = (1.0 / VOXEL) as i32;
    let mut v = Volume::new(Transform::uniform(VOXEL, DVec3::ZERO), 0.0);
    for x in -r..=r {
        for y in -r..=r {
            for z in -r..=r {
                let p = IVec3::new(x, y, z).as_dvec3() * VOXEL;
                if p.length() > 1.0 {
                    continue;
                }
                let dense = DENSE.iter().any(|c| (p - DVec3::from_array(*c)).length() <= DENSE_RADIUS);
                v.set(IVec3::new(x, y, z), if dense { 20.0 } else { 0.3 });
            }
        }
    }
    v
}

fn main() {
    let photons: u64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(200_000);
    let density = scene();
    println!("thin ball (density 0.3, radius 1) holding three dense balls (density 20, radius {DENSE_RADIUS}); voxel {VOXEL}; sun from above; {photons} photons stored");
    println!("{:<12} {:>10} {:>10} {:>16} {:>9} {:>14} {:>11}", "mode", "emitted", "stored", "emitted/stored", "time s", "in dense balls", "mean z");
    for mode in [DistanceSampling::Exponential, DistanceSampling::Simpson, DistanceSampling::Delta] {
        let params = PhotonParams {
            medium: Medium { extinction: 1.0, albedo: glam::Vec3::splat(0.9), g: 0.0 },
            lights: vec![Light::default_sun()],
            distance: mode,
            photons,
            seed: 2009,
            ..PhotonParams::default()
        };
        let start = Instant::now();
        let (map, stats) = trace_cpu(&density, &params).expect("valid parameters");
        let took = start.elapsed().as_secs_f64();
        let in_dense = map.positions.iter().filter(|p| DENSE.iter().any(|c| (**p - DVec3::from_array(*c)).length() <= DENSE_RADIUS)).count();
        let mean_z = map.positions.iter().map(|p| p.z).sum::<f64>() / map.len().max(1) as f64;
        println!(
            "{:<12} {:>10} {:>10} {:>16.2} {:>9.3} {:>13.1}% {:>11.4}",
            mode.name(),
            stats.emitted,
            stats.stored,
            stats.emitted as f64 / stats.stored.max(1) as f64,
            took,
            100.0 * in_dense as f64 / map.len().max(1) as f64,
            mean_z
        );
    }
}
