//! The error-versus-time plot: every rung per scene, the Pareto front joined.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::ladder::Row;

const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
const SIZE: (u32, u32) = (1000, 640);

pub fn error_vs_time(rows: &[Row], png: &Path) -> Result<()> {
    let rows: Vec<&Row> = rows.iter().filter(|r| r.relative_rmse.is_finite() && r.total_s() > 0.0).collect();
    if rows.is_empty() {
        return Err(anyhow!("nothing to plot"));
    }
    // ab_glyph draws text from a font we hand it: DejaVu Sans (Debian's fonts-dejavu-core).
    let font: &'static [u8] = Box::leak(std::fs::read(FONT).with_context(|| format!("reading {FONT} (apt install fonts-dejavu-core)"))?.into_boxed_slice());
    register_font("sans-serif", FontStyle::Normal, font).map_err(|_| anyhow!("{FONT} is not a usable font"))?;

    let (t0, t1) = rows.iter().fold((f64::MAX, 0.0f64), |(a, b), r| (a.min(r.total_s()), b.max(r.total_s())));
    let (e0, e1) = rows.iter().fold((f64::MAX, 0.0f64), |(a, b), r| (a.min(r.relative_rmse), b.max(r.relative_rmse)));
    let mut buffer = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("nimbus: error against the path-traced reference vs run time", ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(64)
            // Explicit keys: plotters' own log keys leave an axis's lowest decade unlabelled,
            // which is where the fast rungs and the accurate ones sit.
            .build_cartesian_2d(
                (t0 / 1.3..t1 * 1.3).log_scale().with_key_points(log_keys(t0 / 1.3, t1 * 1.3)),
                (e0 / 1.3..e1 * 1.3).log_scale().with_key_points(log_keys(e0 / 1.3, e1 * 1.3)),
            )?;
        chart
            .configure_mesh()
            .x_desc("vdbphoton + vdbcache + vdbmarch, seconds")
            .y_desc("relative RMSE (2x2 blocks)")
            .label_style(("sans-serif", 14))
            .x_label_formatter(&|v| if *v < 1.0 { format!("{v:.1}") } else { format!("{v:.0}") })
            .y_label_formatter(&|v| format!("{v:.2}"))
            .draw()?;
        let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene).collect();
        scenes.dedup();
        for (i, scene) in scenes.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let mine: Vec<&&Row> = rows.iter().filter(|r| r.scene == *scene).collect();
            chart
                .draw_series(mine.iter().map(|r| Circle::new((r.total_s(), r.relative_rmse), 4, colour.filled())))?
                .label(*scene)
                .legend(move |(x, y)| Circle::new((x, y), 4, colour.filled()));
            chart.draw_series(mine.iter().map(|r| {
                Text::new(r.rung.name.clone(), (r.total_s() * 1.04, r.relative_rmse), ("sans-serif", 11).into_font().color(&colour))
            }))?;
            let mut front: Vec<(f64, f64)> = mine.iter().filter(|r| r.pareto).map(|r| (r.total_s(), r.relative_rmse)).collect();
            front.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart.draw_series(LineSeries::new(front, colour.stroke_width(2)))?;
        }
        chart.configure_series_labels().border_style(BLACK).background_style(WHITE.mix(0.8)).label_font(("sans-serif", 14)).draw()?;
        root.present()?;
    }
    let mut out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut out, SIZE.0, SIZE.1);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.write_header()?.write_image_data(&buffer)?;
    }
    std::fs::write(png, out).with_context(|| format!("writing {}", png.display()))
}

/// 1, 2, 3 and 5 times the powers of ten inside `[lo, hi]`.
fn log_keys(lo: f64, hi: f64) -> Vec<f64> {
    let mut keys = Vec::new();
    let mut decade = 10f64.powf(lo.log10().floor());
    while decade <= hi {
        keys.extend([1.0, 2.0, 3.0, 5.0].iter().map(|m| m * decade).filter(|k| (lo..=hi).contains(k)));
        decade *= 10.0;
    }
    keys
}

#[cfg(test)]
mod tests {
    #[test]
    fn log_keys_label_every_decade_the_range_touches() {
        let keys = super::log_keys(0.016, 0.25);
        let expected = [0.02, 0.03, 0.05, 0.1, 0.2];
        assert_eq!(keys.len(), expected.len(), "{keys:?}");
        assert!(keys.iter().zip(expected).all(|(k, e)| (k - e).abs() < 1e-12), "{keys:?}");
    }
}
