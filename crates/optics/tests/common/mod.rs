//! Statistics shared by the tests.
#![allow(dead_code)]

/// Pearson's chi-square statistic of observed counts against expected counts.
pub fn chi_square(observed: &[u64], expected: &[f64]) -> f64 {
    assert_eq!(observed.len(), expected.len());
    observed.iter().zip(expected).map(|(&o, &e)| (o as f64 - e) * (o as f64 - e) / e).sum()
}

/// Acceptance threshold for a chi-square statistic with `dof` degrees of freedom: the mean
/// plus six standard deviations, dof + 6 sqrt(2 dof). For dof in the tens to hundreds this
/// is a tail probability below about 1e-6 (Wilson-Hilferty), so a correct sampler fails it
/// essentially never, while a wrong density (a sign, a factor, a missing Jacobian) overshoots
/// it by orders of magnitude at the sample sizes used here. The seeds are fixed, so a pass is
/// reproducible.
pub fn chi_square_limit(dof: usize) -> f64 {
    dof as f64 + 6.0 * (2.0 * dof as f64).sqrt()
}

/// Pearson correlation of two equally long samples.
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}
