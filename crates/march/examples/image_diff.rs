//! Two EXR images (RGBA) compared: the worst relative difference over lit pixels (as the
//! GPU agreement tests measure it: scattered light above 1e-3 of the brightest pixel,
//! floored at 1e-3 of it), the largest alpha difference, and the relative RMSE over
//! covered pixels after 2x2 block means (as `make bench` measures error against a
//! reference, the second image).
//!
//!     cargo run --release -p nimbus-march --example image_diff -- a.exr b.exr

use exr::prelude::*;

struct Rgba {
    width: usize,
    height: usize,
    pixels: Vec<[f32; 4]>,
}

fn read(path: &str) -> Rgba {
    let image = read_first_rgba_layer_from_file(
        path,
        |res, _| Rgba { width: res.width(), height: res.height(), pixels: vec![[0.0; 4]; res.area()] },
        |img: &mut Rgba, pos, (r, g, b, a): (f32, f32, f32, f32)| img.pixels[pos.y() * img.width + pos.x()] = [r, g, b, a],
    )
    .unwrap_or_else(|e| panic!("{path}: {e}"));
    image.layer_data.channel_data.pixels
}

fn blocks2(img: &Rgba) -> Vec<[f32; 4]> {
    let (w, h) = (img.width / 2, img.height / 2);
    let mut out = vec![[0.0f32; 4]; w * h];
    for y in 0..h {
        for x in 0..w {
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = img.pixels[(2 * y + dy) * img.width + 2 * x + dx];
                for c in 0..4 {
                    out[y * w + x][c] += 0.25 * p[c];
                }
            }
        }
    }
    out
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (a, b) = (read(&args[1]), read(&args[2]));
    assert_eq!((a.width, a.height), (b.width, b.height), "sizes differ");
    let lum = |p: &[f32; 4]| p[0] + p[1] + p[2];
    let max = b.pixels.iter().map(lum).fold(0.0f32, f32::max);
    let floor = 1e-3 * max / 3.0;
    let (mut worst, mut alpha, mut lit, mut sum_rel) = (0.0f32, 0.0f32, 0usize, 0.0f64);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        alpha = alpha.max((p[3] - q[3]).abs());
        if lum(q) > 1e-3 * max {
            lit += 1;
            let rel = (0..3).map(|c| (p[c] - q[c]).abs() / q[c].abs().max(floor)).fold(0.0f32, f32::max);
            worst = worst.max(rel);
            sum_rel += rel as f64;
        }
    }
    let (pa, pb) = (blocks2(&a), blocks2(&b));
    let (mut sq, mut level, mut n, mut sq_alpha) = (0.0f64, 0.0f64, 0usize, 0.0f64);
    for (p, r) in pa.iter().zip(&pb) {
        if r[3] > 0.01 {
            sq_alpha += ((p[3] - r[3]) as f64).powi(2);
            for c in 0..3 {
                sq += ((p[c] - r[c]) as f64).powi(2) / 3.0;
            }
            level += lum(r) as f64 / 3.0;
            n += 1;
        }
    }
    // With a third argument: a PNG of |alpha difference| (white = 0.02) and, in red, the
    // relative colour difference (red = 0.05).
    if let Some(out) = args.get(3) {
        let mut data = Vec::with_capacity(a.pixels.len() * 3);
        for (p, q) in a.pixels.iter().zip(&b.pixels) {
            let da = ((p[3] - q[3]).abs() / 0.02).min(1.0);
            let dc = ((lum(p) - lum(q)).abs() / lum(q).abs().max(floor) / 0.05).min(1.0);
            data.extend([(255.0 * da.max(dc)) as u8, (255.0 * da) as u8, (255.0 * da) as u8]);
        }
        let file = std::fs::File::create(out).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), a.width as u32, a.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&data).unwrap();
    }
    let mean = |img: &Rgba| img.pixels.iter().map(|p| lum(p) as f64).sum::<f64>();
    println!(
        "lit pixels {lit}: max rel diff {worst:.3e}, mean rel diff {:.3e}; max |alpha diff| {alpha:.3e}; rel RMSE (2x2 blocks, covered) {:.5}; alpha RMSE {:.5}; mean ratio {:.5}",
        sum_rel / lit.max(1) as f64,
        (sq / n as f64).sqrt() / (level / n as f64),
        (sq_alpha / n as f64).sqrt(),
        mean(&a) / mean(&b)
    );
}
