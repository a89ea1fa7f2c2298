//! Writes one of the unseen scenes (`nimbus_bench::scenes`) as a density VDB and prints the
//! flags that complete it: the medium and lights on the first line, the camera on the second.
//!
//!     nimbus-scene anvil anvil.vdb

use anyhow::{bail, Result};
use clap::Parser;
use nimbus_vdb::{GridClass, VdbFile, WriteOptions};

#[derive(Parser, Debug)]
#[command(name = "nimbus-scene", about = "Write an unseen test scene (anvil, forward, sheet) as a density VDB; print its flags")]
struct Args {
    /// The scene: anvil, forward or sheet.
    name: String,
    /// The VDB to write.
    output: std::path::PathBuf,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let Some(scene) = nimbus_bench::scenes::scene(&args.name) else {
        bail!("no scene '{}' (scenes: {})", args.name, nimbus_bench::scenes::NAMES.join(", "));
    };
    let mut file = VdbFile::new();
    file.insert_volume("density", &scene.density, GridClass::FogVolume)?;
    file.write(&args.output, &WriteOptions::default())?;
    println!("{}", scene.medium.join(" "));
    println!("{}", scene.camera.join(" "));
    Ok(())
}
