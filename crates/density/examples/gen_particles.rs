//! Writes an analytic test scene's particles as a binary PLY (positions f64, masses f32), and
//! optionally the true density on the scene's grid as a .npy array (f32, shape (z, y, x)), so
//! other tools (scripts/bench_sarracen.py) score themselves against the same reference.
//!
//!     cargo run --release -p nimbus-density --example gen_particles -- SCENE OUT.ply [N] [SEED] [TRUTH.npy]
//!
//! SCENE is knots, shell, cloud1, plume, smoke or cumulus; N overrides the particle count. The grid is the one
//! `particles2vdb --voxel-size V [--bounds ...]` builds with the scene's suggested voxel size
//! (and bounds, where the scene has them) and the default method: printed on stderr.

use std::io::Write;

use nimbus_density::analytic::{Scene, TrueGrid};
use nimbus_density::{plan_grid, DensityParams, Resolution};

/// NumPy's .npy format 1.0: magic, a Python-literal header padded to 64 bytes, raw data.
fn write_npy(path: &str, shape: [usize; 3], values: &[f64]) -> std::io::Result<()> {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}, {}), }}", shape[0], shape[1], shape[2]);
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(b"\x93NUMPY\x01\x00")?;
    out.write_all(&(header.len() as u16).to_le_bytes())?;
    out.write_all(header.as_bytes())?;
    for &v in values {
        out.write_all(&(v as f32).to_le_bytes())?;
    }
    out.flush()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(name), Some(out)) = (args.first(), args.get(1)) else {
        return Err("usage: gen_particles SCENE OUT.ply [N] [SEED] [TRUTH.npy]   (SCENE: knots, shell, cloud1, plume, smoke, cumulus)".into());
    };
    let mut scene = Scene::by_name(name).ok_or_else(|| format!("unknown scene {name}"))?;
    if let Some(n) = args.get(2) {
        scene = scene.with_particles(n.parse()?);
    }
    let seed = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(1);
    let particles = scene.particles(seed);
    nimbus_density::write_ply(std::fs::File::create(out)?, &particles)?;
    eprintln!("{}: {} particles, total mass {}, suggested voxel size {} -> {out}", scene.name, particles.len(), scene.total_mass, scene.voxel_size);
    if let Some(truth_path) = args.get(4) {
        let params = DensityParams { resolution: Resolution::VoxelSize(scene.voxel_size), bounds: scene.bounds, ..Default::default() };
        let grid = plan_grid(&particles, &params)?;
        let truth = TrueGrid::new(&scene, grid);
        let d = grid.dims;
        write_npy(truth_path, [d.z as usize, d.y as usize, d.x as usize], &truth.values)?;
        let (lo, hi) = grid.bounds;
        eprintln!(
            "true density on {}x{}x{} voxels of {}, bounds {},{},{},{},{},{} -> {truth_path}",
            d.x, d.y, d.z, grid.voxel_size, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        );
    }
    Ok(())
}
