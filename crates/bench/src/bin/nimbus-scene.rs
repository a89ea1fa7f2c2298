//! Writes one of the unseen scenes (`nimbus_bench::scenes`) as a density VDB and prints the
//! flags that complete it: the medium and lights on the first line, the camera on the second.
//!
//!     nimbus-scene anvil anvil.vdb
//!
//! or a scene drawn from a seed (`nimbus_bench::random`, issue #47): the density, and an
//! `emission` grid beside it where the draw has emission (its flags on the first line); the
//! camera line then has `--width` and `--height`, and a third line describes the draw.
//!
//!     nimbus-scene --random 20261207001 scene.vdb [--max-pixels 6144] [--voxel-scale 0.1]

use anyhow::{bail, Result};
use clap::Parser;
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};

#[derive(Parser, Debug)]
#[command(name = "nimbus-scene", about = "Write an unseen test scene (anvil, forward, sheet, or --random SEED) as a density VDB; print its flags")]
struct Args {
    /// The scene: anvil, forward or sheet (not with --random).
    #[arg(required_unless_present = "random")]
    name: Option<String>,
    /// The VDB to write.
    output: Option<std::path::PathBuf>,
    /// Draw the scene from this seed instead; the positional argument is then the VDB.
    #[arg(long, value_name = "SEED")]
    random: Option<u64>,
    /// With --random: most pixels in the image (the footprint drawn is kept; a smaller
    /// budget sees a smaller part of the volume).
    #[arg(long, default_value_t = nimbus_bench::random::MAX_PIXELS, requires = "random")]
    max_pixels: u32,
    /// With --random: scales the drawn voxel count (the box's voxels; edges, medium, lights
    /// and footprint as drawn), for quick runs.
    #[arg(long, default_value_t = 1.0, requires = "random")]
    voxel_scale: f64,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let mut file = VdbFile::new();
    let (output, lines) = match args.random {
        Some(seed) => {
            // With --random the one positional argument is the output.
            let output = match (&args.name, &args.output) {
                (Some(out), None) => std::path::PathBuf::from(out),
                (None, Some(out)) => out.clone(),
                _ => bail!("--random SEED takes one more argument, the VDB to write"),
            };
            let options = nimbus_bench::random::Options { max_pixels: args.max_pixels, voxel_scale: args.voxel_scale };
            let r = nimbus_bench::random::scene(seed, options)?;
            file.insert_volume("density", &r.scene.density, GridClass::FogVolume)?;
            if let Some(emission) = &r.emission {
                file.insert_volume(nimbus_bench::random::EMISSION_GRID, emission, GridClass::FogVolume)?;
            }
            (output, vec![r.scene.medium.join(" "), r.scene.camera.join(" "), r.draw.describe()])
        }
        None => {
            let name = args.name.as_deref().unwrap_or_default();
            let Some(output) = args.output else { bail!("nimbus-scene NAME OUT.vdb: no OUT.vdb") };
            let Some(scene) = nimbus_bench::scenes::scene(name) else {
                bail!("no scene '{name}' (scenes: {})", nimbus_bench::scenes::NAMES.join(", "));
            };
            file.insert_volume("density", &scene.density, GridClass::FogVolume)?;
            (output, vec![scene.medium.join(" "), scene.camera.join(" ")])
        }
    };
    file.write(&output, &WriteOptions::default())?;
    // A reader that takes only the lines it needs (`| head -2`) closes the pipe early: that
    // is its choice, not an error of ours, and println! would panic on it.
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    for line in lines {
        match writeln!(out, "{line}") {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => break,
            other => other?,
        }
    }
    Ok(())
}
