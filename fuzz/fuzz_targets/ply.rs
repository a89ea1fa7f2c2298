//! The PLY particle reader (ASCII and binary, any property layout) on arbitrary bytes: an
//! error or a particle set, never a panic, and every kept particle finite.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nimbus_density::{read_particles, Format};

fuzz_target!(|data: &[u8]| {
    if let Ok((set, _)) = read_particles(data, Format::Ply) {
        assert!(set.positions.iter().all(|p| p.is_finite()));
        assert!(set.masses.iter().flatten().all(|m| m.is_finite() && *m >= 0.0));
    }
});
