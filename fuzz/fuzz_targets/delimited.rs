//! The CSV/TSV particle reader on arbitrary bytes (the first byte picks the delimiter): an
//! error or a particle set, never a panic, and every kept particle finite.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nimbus_density::{read_particles, Format};

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else { return };
    let format = if first & 1 == 0 { Format::Csv } else { Format::Tsv };
    if let Ok((set, _)) = read_particles(rest, format) {
        assert!(set.positions.iter().all(|p| p.is_finite()));
        assert!(set.masses.iter().flatten().all(|m| m.is_finite() && *m >= 0.0));
    }
});
