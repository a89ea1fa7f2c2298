//! Writes an analytic test scene's particles as a binary PLY (positions f64, masses f32).
//!
//!     cargo run --release -p nimbus-density --example gen_particles -- SCENE OUT.ply [N] [SEED]
//!
//! SCENE is knots, shell, cloud1 or plume; N overrides the particle count.

use nimbus_density::analytic::Scene;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(name), Some(out)) = (args.first(), args.get(1)) else {
        return Err("usage: gen_particles SCENE OUT.ply [N] [SEED]   (SCENE: knots, shell, cloud1, plume)".into());
    };
    let mut scene = Scene::by_name(name).ok_or_else(|| format!("unknown scene {name}"))?;
    if let Some(n) = args.get(2) {
        scene = scene.with_particles(n.parse()?);
    }
    let seed = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(1);
    let particles = scene.particles(seed);
    nimbus_density::write_ply(std::fs::File::create(out)?, &particles)?;
    eprintln!("{}: {} particles, total mass {}, suggested voxel size {} -> {out}", scene.name, particles.len(), scene.total_mass, scene.voxel_size);
    Ok(())
}
