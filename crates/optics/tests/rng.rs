//! The counter-based generator: correct Philox, deterministic, uniform, independent streams.

mod common;

use common::{chi_square, chi_square_limit, correlation};
use nimbus_optics::{philox4x32_10, unit_f32, Rng};

/// Random123's published known-answer vectors for Philox4x32-10 (tests/kat_vectors).
#[test]
fn philox_matches_random123_known_answers() {
    assert_eq!(philox4x32_10([0; 4], [0; 2]), [0x6627e8d5, 0xe169c58d, 0xbc57ac4c, 0x9b00dbd8]);
    assert_eq!(philox4x32_10([u32::MAX; 4], [u32::MAX; 2]), [0x408f276d, 0x41c83b0e, 0xa20bc7c6, 0x6d5451fd]);
    assert_eq!(
        philox4x32_10([0x243f6a88, 0x85a308d3, 0x13198a2e, 0x03707344], [0xa4093822, 0x299f31d0]),
        [0xd16cfe09, 0x94fdcceb, 0x5001e420, 0x24126ea1]
    );
}

/// The documented layout: key = seed, counter = (block, domain, index lo, index hi).
#[test]
fn stream_layout_is_the_documented_one() {
    let seed = 0x0123_4567_89ab_cdefu64;
    let index = 0xfedc_ba98_7654_3210u64;
    let mut rng = Rng::with_domain(seed, index, 5);
    let key = [seed as u32, (seed >> 32) as u32];
    let block0 = philox4x32_10([0, 5, index as u32, (index >> 32) as u32], key);
    let block1 = philox4x32_10([1, 5, index as u32, (index >> 32) as u32], key);
    let drawn: Vec<u32> = (0..8).map(|_| rng.next_u32()).collect();
    assert_eq!(drawn[..4], block0);
    assert_eq!(drawn[4..], block1);
}

#[test]
fn same_seed_and_index_give_the_same_sequence() {
    let a: Vec<u32> = {
        let mut r = Rng::new(42, 7);
        (0..1000).map(|_| r.next_u32()).collect()
    };
    let mut r = Rng::new(42, 7);
    let b: Vec<u32> = (0..1000).map(|_| r.next_u32()).collect();
    assert_eq!(a, b);
    // Drawing from other items in between changes nothing (no shared state).
    let mut r1 = Rng::new(42, 7);
    let mut other = Rng::new(42, 8);
    let c: Vec<u32> = (0..1000)
        .map(|_| {
            other.next_u32();
            r1.next_u32()
        })
        .collect();
    assert_eq!(a, c);
    // A clone replays.
    let mut r2 = Rng::new(42, 7);
    r2.next_u32();
    let mut replay = r2.clone();
    assert_eq!(r2.next_u32(), replay.next_u32());
}

#[test]
fn unit_floats_are_in_the_half_open_interval() {
    assert_eq!(unit_f32(0), 0.0);
    assert!(unit_f32(u32::MAX) < 1.0);
    assert_eq!(unit_f32(u32::MAX), 1.0 - 1.0 / 16_777_216.0);
    assert_eq!(unit_f32(1 << 31), 0.5);
    let mut r = Rng::new(0, 0);
    for _ in 0..100_000 {
        let x = r.next_f32();
        assert!((0.0..1.0).contains(&x));
        let y = r.next_f64();
        assert!((0.0..1.0).contains(&y));
    }
}

/// Top byte of 1M words, drawn 1000 per item over 1000 items: 256 buckets, limit 351 (255 dof).
/// Then next_f32 in 100 buckets, and next_vec2 in a 16 x 16 grid (pairs).
#[test]
fn output_is_uniform() {
    let mut bytes = [0u64; 256];
    let mut floats = [0u64; 100];
    let mut pairs = [0u64; 256];
    for item in 0..1000u64 {
        let mut r = Rng::new(12345, item);
        for _ in 0..1000 {
            bytes[(r.next_u32() >> 24) as usize] += 1;
        }
        for _ in 0..1000 {
            floats[(r.next_f32() * 100.0) as usize] += 1;
        }
        for _ in 0..1000 {
            let v = r.next_vec2();
            pairs[(v.x * 16.0) as usize * 16 + (v.y * 16.0) as usize] += 1;
        }
    }
    let chi_bytes = chi_square(&bytes, &[1e6 / 256.0; 256]);
    let chi_floats = chi_square(&floats, &[1e6 / 100.0; 100]);
    let chi_pairs = chi_square(&pairs, &[1e6 / 256.0; 256]);
    println!("chi2: bytes {chi_bytes:.1}, floats {chi_floats:.1}, pairs {chi_pairs:.1}");
    assert!(chi_bytes < chi_square_limit(255), "top byte chi2 {chi_bytes}");
    assert!(chi_floats < chi_square_limit(99), "f32 chi2 {chi_floats}");
    assert!(chi_pairs < chi_square_limit(255), "vec2 chi2 {chi_pairs}");
}

/// Low bits too: the bottom byte, across items' first words (where weak hashes of
/// consecutive indices tend to show structure).
#[test]
fn low_bits_of_first_words_are_uniform() {
    let mut low = [0u64; 256];
    for item in 0..256_000u64 {
        low[(Rng::new(1, item).next_u32() & 0xff) as usize] += 1;
    }
    let chi = chi_square(&low, &[1000.0; 256]);
    assert!(chi < chi_square_limit(255), "low byte chi2 {chi}");
}

/// Different index, seed or domain -> a different sequence, with no correlation between the
/// first values of neighbouring items (|r| < 5 / sqrt(N), N = 100k) and no repeated first
/// 64 bits among 100k items (a collision would mean two photons share their random choices).
#[test]
fn streams_are_independent() {
    const N: u64 = 100_000;
    let first = |seed: u64, index: u64, domain: u32| {
        let mut r = Rng::with_domain(seed, index, domain);
        [r.next_f32() as f64, r.next_f32() as f64]
    };
    let limit = 5.0 / (N as f64).sqrt();
    let base: Vec<[f64; 2]> = (0..N).map(|i| first(9, i, 0)).collect();
    let neighbours: Vec<[f64; 2]> = (0..N).map(|i| first(9, i + 1, 0)).collect();
    let next_seed: Vec<[f64; 2]> = (0..N).map(|i| first(10, i, 0)).collect();
    let next_domain: Vec<[f64; 2]> = (0..N).map(|i| first(9, i, 1)).collect();
    let col = |v: &[[f64; 2]], k: usize| v.iter().map(|x| x[k]).collect::<Vec<_>>();
    let b0 = col(&base, 0);
    for (name, other) in [("index + 1", &neighbours), ("seed + 1", &next_seed), ("domain 1", &next_domain)] {
        for k in 0..2 {
            let r = correlation(&b0, &col(other, k));
            assert!(r.abs() < limit, "{name}, value {k}: correlation {r}");
        }
    }
    // Lag-1 within an item.
    let r = correlation(&b0, &col(&base, 1));
    assert!(r.abs() < limit, "lag-1 correlation {r}");

    let mut words: Vec<u64> = (0..N)
        .map(|i| {
            let mut r = Rng::new(9, i);
            (r.next_u32() as u64) << 32 | r.next_u32() as u64
        })
        .collect();
    words.sort_unstable();
    words.dedup();
    assert_eq!(words.len(), N as usize, "two items share their first 64 bits");

    let mut a = Rng::new(3, 1 << 40);
    let mut b = Rng::new(3, 1);
    assert_ne!((a.next_u32(), a.next_u32()), (b.next_u32(), b.next_u32()), "index high word ignored");
    let mut a = Rng::new(1 << 40, 1);
    let mut b = Rng::new(0, 1);
    assert_ne!((a.next_u32(), a.next_u32()), (b.next_u32(), b.next_u32()), "seed high word ignored");
}
