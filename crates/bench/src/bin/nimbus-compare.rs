//! Scores images against a reference the way nimbus-bench does: relative RMSE after 2x2
//! block averaging over the pixels the reference sees as covered, and the mean ratio.
//!
//!     nimbus-compare REFERENCE.exr IMAGE.exr [IMAGE.exr ...]

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;

#[path = "../image.rs"]
mod image;

#[derive(Parser, Debug)]
#[command(name = "nimbus-compare", about = "Relative RMSE (2x2 blocks, covered pixels) and mean ratio of images against a reference")]
struct Args {
    reference: PathBuf,
    images: Vec<PathBuf>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let reference = image::read(&args.reference)?;
    for path in &args.images {
        let e = image::compare(&image::read(path)?, &reference);
        println!("{}: relative RMSE {:.4}, mean ratio {:.4}", path.display(), e.relative_rmse, e.mean_ratio);
    }
    Ok(())
}
