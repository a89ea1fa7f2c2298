//! EXR images and the error measures.

use std::path::Path;

use anyhow::{Context, Result};
use exr::prelude::*;

/// RGBA pixels, top row first.
pub struct Rgba {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 4]>,
}

pub fn read(path: &Path) -> Result<Rgba> {
    let image = read_first_rgba_layer_from_file(
        path,
        |resolution, _| Rgba { width: resolution.width(), height: resolution.height(), pixels: vec![[0.0; 4]; resolution.area()] },
        |img: &mut Rgba, pos, (r, g, b, a): (f32, f32, f32, f32)| img.pixels[pos.y() * img.width + pos.x()] = [r, g, b, a],
    )
    .with_context(|| format!("reading {}", path.display()))?;
    Ok(image.layer_data.channel_data.pixels)
}

impl Rgba {
    /// 2x2 block means (odd last rows/columns dropped).
    pub fn blocks2(&self) -> Rgba {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut pixels = vec![[0.0f32; 4]; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut sum = [0.0f32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let p = self.pixels[(2 * y + dy) * self.width + 2 * x + dx];
                    for c in 0..4 {
                        sum[c] += 0.25 * p[c];
                    }
                }
                pixels[y * w + x] = sum;
            }
        }
        Rgba { width: w, height: h, pixels }
    }
}

/// Error of `image` against `reference` (same size): relative RMSE over covered pixels after
/// 2x2 block averaging, and the ratio of mean radiances over all pixels.
pub struct ImageError {
    pub relative_rmse: f64,
    pub mean_ratio: f64,
}

pub fn compare(image: &Rgba, reference: &Rgba) -> ImageError {
    let mean_rgb = |p: &[f32; 4]| (p[0] + p[1] + p[2]) as f64 / 3.0;
    let all = |img: &Rgba| img.pixels.iter().map(mean_rgb).sum::<f64>();
    let mean_ratio = all(image) / all(reference);
    let (a, b) = (image.blocks2(), reference.blocks2());
    let (mut sq, mut level, mut n) = (0.0, 0.0, 0usize);
    for (p, r) in a.pixels.iter().zip(&b.pixels) {
        if r[3] > 0.01 {
            for c in 0..3 {
                sq += ((p[c] - r[c]) as f64).powi(2) / 3.0;
            }
            level += mean_rgb(r);
            n += 1;
        }
    }
    let relative_rmse = if n == 0 || level <= 0.0 { f64::NAN } else { (sq / n as f64).sqrt() / (level / n as f64) };
    ImageError { relative_rmse, mean_ratio }
}

/// Frame-to-frame change of a sequence against its reference's, over one pair of consecutive
/// frames: each is the RMS over covered 2x2 blocks, relative to the reference's mean there.
#[allow(dead_code)] // image.rs is also included by nimbus-bench and nimbus-single, which measure no sequences
pub struct Flicker {
    /// How much the reference changes from frame to frame (the motion, plus its own noise).
    pub reference_change: f64,
    /// How much the image changes.
    pub image_change: f64,
    /// The image's change less the reference's: what the image adds to the motion (noise
    /// that crawls, a pattern that pops) or misses of it.
    pub excess: f64,
}

/// [`Flicker`] of images `(a, b)` (consecutive frames) against reference frames `(ra, rb)`;
/// covered is where either reference frame is.
#[allow(dead_code)]
pub fn flicker(a: &Rgba, b: &Rgba, ra: &Rgba, rb: &Rgba) -> Flicker {
    let [a, b, ra, rb] = [a, b, ra, rb].map(Rgba::blocks2);
    let (mut image, mut reference, mut excess, mut level, mut n) = (0.0, 0.0, 0.0, 0.0, 0usize);
    for i in 0..ra.pixels.len() {
        if ra.pixels[i][3] <= 0.01 && rb.pixels[i][3] <= 0.01 {
            continue;
        }
        for c in 0..3 {
            let d_image = (b.pixels[i][c] - a.pixels[i][c]) as f64;
            let d_reference = (rb.pixels[i][c] - ra.pixels[i][c]) as f64;
            image += d_image * d_image / 3.0;
            reference += d_reference * d_reference / 3.0;
            excess += (d_image - d_reference).powi(2) / 3.0;
            level += 0.5 * (ra.pixels[i][c] + rb.pixels[i][c]) as f64 / 3.0;
        }
        n += 1;
    }
    let relative = |sq: f64| if n == 0 || level <= 0.0 { f64::NAN } else { (sq / n as f64).sqrt() / (level / n as f64) };
    Flicker { reference_change: relative(reference), image_change: relative(image), excess: relative(excess) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(value: f32) -> Rgba {
        Rgba { width: 4, height: 4, pixels: vec![[value, value, value, 1.0]; 16] }
    }

    #[test]
    fn flicker_is_the_change_beyond_the_reference_s() {
        // The image follows the reference's change exactly: no excess.
        let f = flicker(&flat(1.1), &flat(1.3), &flat(1.0), &flat(1.2));
        assert!((f.reference_change - 0.2 / 1.1).abs() < 1e-6 && (f.image_change - 0.2 / 1.1).abs() < 1e-6, "{}", f.image_change);
        assert!(f.excess < 1e-6);
        // A static image of a moving reference misses the whole change.
        let f = flicker(&flat(1.0), &flat(1.0), &flat(1.0), &flat(1.2));
        assert!(f.image_change == 0.0 && (f.excess - 0.2 / 1.1).abs() < 1e-6);
    }
}
