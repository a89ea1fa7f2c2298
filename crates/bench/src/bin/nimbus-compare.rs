//! Scores images against a reference the way nimbus-bench does: relative RMSE after 2x2
//! block averaging over the pixels the reference sees as covered, and the mean ratio.
//!
//!     nimbus-compare REFERENCE.exr IMAGE.exr [IMAGE.exr ...]
//!
//! and frame-to-frame flicker against a reference sequence's (issue #20): how much each
//! sequence changes between two consecutive frames, and the image's change less the
//! reference's (`image::flicker`):
//!
//!     nimbus-compare --flicker REF.0001.exr REF.0002.exr IMAGE.0001.exr IMAGE.0002.exr

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;

#[path = "../image.rs"]
mod image;

#[derive(Parser, Debug)]
#[command(name = "nimbus-compare", about = "Relative RMSE (2x2 blocks, covered pixels) and mean ratio of images against a reference")]
struct Args {
    #[arg(required_unless_present = "flicker")]
    reference: Option<PathBuf>,
    images: Vec<PathBuf>,
    /// Two consecutive reference frames, then the same two frames of the images.
    #[arg(long, num_args = 4, value_names = ["REF_A", "REF_B", "IMAGE_A", "IMAGE_B"], conflicts_with = "reference")]
    flicker: Option<Vec<PathBuf>>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if let Some(paths) = &args.flicker {
        let [ra, rb, a, b] = [0, 1, 2, 3].map(|i| image::read(&paths[i]));
        let f = image::flicker(&a?, &b?, &ra?, &rb?);
        println!("reference change {:.4}, image change {:.4}, excess {:.4}", f.reference_change, f.image_change, f.excess);
        return Ok(());
    }
    let reference = image::read(args.reference.as_ref().expect("clap requires it"))?;
    for path in &args.images {
        let e = image::compare(&image::read(path)?, &reference);
        println!("{}: relative RMSE {:.4}, mean ratio {:.4}", path.display(), e.relative_rmse, e.mean_ratio);
    }
    Ok(())
}
