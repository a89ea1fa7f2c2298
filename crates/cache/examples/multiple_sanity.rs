//! Multiple-scattering sanity (issue 5): baked Li_multiple in an optically thick homogeneous
//! sphere (optical radius 4, albedo 0.99, g = 0, sun from +Z) against an independent Monte
//! Carlo reference, as photons increase. Run: cargo run --release -p nimbus-cache --example multiple_sanity

#[path = "../tests/support/sphere.rs"]
mod sphere;

use glam::DVec3;
use sphere::{POINTS, THICK};

fn main() {
    let points: Vec<DVec3> = POINTS.iter().map(|&p| DVec3::from_array(p)).collect();
    let reference: Vec<(f64, f64)> = points.iter().map(|&p| THICK.reference(p, 400_000, 1)).collect();
    println!("reference (path-traced, order >= 2), per point: value +- standard error");
    for (p, (v, e)) in points.iter().zip(&reference) {
        println!("  {p:>16}  {v:.5} +- {e:.5} ({:.2}%)", 100.0 * e / v);
    }
    println!("\n| photons | k   | mean |rel err| | worst | per point (baked / reference - 1) |");
    println!("|---------|-----|----------------|-------|-----------------------------------|");
    for (photons, k) in [(10_000u64, 32u32), (40_000, 64), (160_000, 128), (640_000, 256)] {
        // Two photon maps per size, to show the spread rather than one draw.
        for seed in [11u64, 12] {
            let baked = THICK.baked(1.0 / 24.0, photons, k, seed, &points);
            let errs: Vec<f64> = baked.iter().zip(&reference).map(|(b, r)| b / r.0 - 1.0).collect();
            let mean = errs.iter().map(|e| e.abs()).sum::<f64>() / errs.len() as f64;
            let worst = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
            let per: Vec<String> = errs.iter().map(|e| format!("{:+.1}%", 100.0 * e)).collect();
            println!("| {photons:>7} | {k:>3} | {:>13.1}% | {:>4.1}% | {} |", 100.0 * mean, 100.0 * worst, per.join(" "));
        }
    }
}
