//! The rotated R2 sequence the paths take their first directions from.

use nimbus_optics::{r2_point, Rng};

/// Each point of a rotated R2 sequence is uniform over the square whatever j, because the
/// rotation is: over random offsets, the mean of a smooth function at point j is its
/// integral (here x^2 y + y on [0,1)^2, 2/3, checked to four standard errors), so paths
/// that take their directions from it stay unbiased; and one offset's first 64 points
/// leave no quadrant of a 4 x 4 grid of cells empty (they spread, unlike independent draws).
#[test]
fn rotated_r2_points_are_uniform_and_spread() {
    let f = |u: glam::Vec2| (u.x as f64).powi(2) * u.y as f64 + u.y as f64;
    for j in [0u32, 1, 7, 1000, 123_456] {
        let n = 20_000u64;
        let values: Vec<f64> = (0..n)
            .map(|i| {
                let mut rng = Rng::new(3, i);
                f(r2_point([rng.next_u32(), rng.next_u32()], j))
            })
            .collect();
        let mean = values.iter().sum::<f64>() / n as f64;
        let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        assert!((mean - 2.0 / 3.0).abs() < 4.0 * sd / (n as f64).sqrt(), "point {j}: mean {mean}");
    }
    let mut cells = [0u32; 16];
    for j in 0..64 {
        let u = r2_point([0x1234_5678, 0x9abc_def0], j);
        cells[(u.x * 4.0) as usize * 4 + (u.y * 4.0) as usize] += 1;
    }
    assert!(cells.iter().all(|&c| (2..=6).contains(&c)), "64 points over 16 cells: {cells:?}");
}
