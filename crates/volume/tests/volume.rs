use glam::{DAffine3, DMat3, DVec3, IVec3};
use nimbus_volume::{brick_local, brick_offset, MajorantGrid, Transform, Volume, BRICK_VOXELS};
use proptest::prelude::*;

/// A small deterministic generator so the tests need no RNG crate.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Bricks scattered with gaps, values everywhere inside them, a few voxels left inactive.
fn random_volume(seed: u64, background: f32) -> Volume<f32> {
    let mut rng = Lcg(seed);
    let mut v = Volume::new(Transform::uniform(0.5, DVec3::new(1.0, -2.0, 3.0)), background);
    for _ in 0..12 {
        let origin = IVec3::new(
            (rng.next() * 6.0) as i32 - 3,
            (rng.next() * 6.0) as i32 - 3,
            (rng.next() * 4.0) as i32 - 2,
        ) * 8;
        let values: Vec<f32> = (0..BRICK_VOXELS).map(|_| rng.next() as f32 * 4.0).collect();
        let mut mask = [u64::MAX; 8];
        mask[3] = 0x00ff_00ff_00ff_00ff;
        v.insert_brick(origin, &values, &mask);
    }
    v
}

/// Trilinear interpolation written from the definition, corner by corner.
fn naive_sample(v: &Volume<f32>, p: DVec3) -> f64 {
    let b = p.floor();
    let f = p - b;
    let mut sum = 0.0;
    for n in 0..8 {
        let d = IVec3::new((n >> 2) & 1, (n >> 1) & 1, n & 1);
        let w = (if d.x == 1 { f.x } else { 1.0 - f.x })
            * (if d.y == 1 { f.y } else { 1.0 - f.y })
            * (if d.z == 1 { f.z } else { 1.0 - f.z });
        sum += w * v.get(b.as_ivec3() + d) as f64;
    }
    sum
}

#[test]
fn brick_offsets_follow_openvdb_leaf_order() {
    assert_eq!(brick_offset(IVec3::new(0, 0, 1)), 1);
    assert_eq!(brick_offset(IVec3::new(0, 1, 0)), 8);
    assert_eq!(brick_offset(IVec3::new(1, 0, 0)), 64);
    for o in 0..BRICK_VOXELS {
        assert_eq!(brick_offset(brick_local(o)), o);
    }
}

#[test]
fn get_set_and_background() {
    let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.25f32);
    assert_eq!(v.get(IVec3::new(100, -3, 7)), 0.25);
    v.set(IVec3::new(-1, -9, 17), 2.0);
    assert_eq!(v.get(IVec3::new(-1, -9, 17)), 2.0);
    assert!(v.is_active(IVec3::new(-1, -9, 17)));
    // Other voxels of the new brick hold the background and are inactive.
    assert_eq!(v.get(IVec3::new(-2, -9, 17)), 0.25);
    assert!(!v.is_active(IVec3::new(-2, -9, 17)));
    assert_eq!(v.brick_count(), 1);
    assert_eq!(v.active_voxel_count(), 1);
    assert_eq!(v.active_index_bbox(), Some((IVec3::new(-1, -9, 17), IVec3::new(-1, -9, 17))));
}

#[test]
fn trilinear_matches_definition_everywhere() {
    let v = random_volume(7, 0.5);
    let mut rng = Lcg(99);
    for _ in 0..20_000 {
        let p = DVec3::new(rng.next() * 70.0 - 35.0, rng.next() * 70.0 - 35.0, rng.next() * 50.0 - 25.0);
        let got = v.sample_index(p) as f64;
        let want = naive_sample(&v, p);
        assert!((got - want).abs() <= 1e-5 * (1.0 + want.abs()), "at {p}: {got} vs {want}");
    }
    // At lattice points the sample is the stored value.
    for brick in v.bricks().take(3) {
        for o in [0, 7, 63, 511] {
            let ijk = brick.origin + brick_local(o);
            assert_eq!(v.sample_index(ijk.as_dvec3()), brick.values[o]);
        }
    }
}

#[test]
fn world_sampling_uses_the_affine_map() {
    let m = DMat3::from_rotation_z(0.3) * DMat3::from_diagonal(DVec3::new(0.5, 1.0, 2.0));
    let t = Transform::new(DAffine3::from_mat3_translation(m, DVec3::new(1e5, -3.0, 7.0))).unwrap();
    let mut v = random_volume(3, 0.0);
    v.set_transform(t);
    let p_index = DVec3::new(3.3, -4.7, 1.25);
    let p_world = t.to_world(p_index);
    assert!((v.sample_world(p_world) - v.sample_index(p_index)).abs() < 1e-4);
    let vs = t.voxel_size();
    assert!((vs - DVec3::new(0.5, 1.0, 2.0)).abs().max_element() < 1e-12);
}

#[test]
fn singular_transform_is_refused() {
    let m = DMat3::from_cols(DVec3::X, DVec3::X, DVec3::Z);
    assert!(Transform::new(DAffine3::from_mat3(m)).is_err());
    assert!(Transform::new(DAffine3::from_scale(DVec3::new(1.0, f64::NAN, 1.0))).is_err());
}

#[test]
fn from_brick_fn_drops_empty_bricks() {
    let origins: Vec<IVec3> = (0..4).map(|i| IVec3::new(i * 8, 0, 0)).collect();
    let v = Volume::from_brick_fn(Transform::uniform(1.0, DVec3::ZERO), 0.0f32, &origins, |o, values| {
        let mut mask = [0u64; 8];
        if o.x % 16 == 0 {
            values[5] = 1.0;
            mask[0] = 1 << 5;
        }
        mask
    });
    assert_eq!(v.brick_count(), 2);
    assert_eq!(v.get(IVec3::new(16, 0, 5)), 1.0);
}

#[test]
fn majorant_bounds_every_sample() {
    let v = random_volume(11, 0.0);
    for log2 in [3, 4] {
        let m = MajorantGrid::with_cell_log2(&v, log2);
        let mut rng = Lcg(5);
        for _ in 0..50_000 {
            let p = DVec3::new(rng.next() * 80.0 - 40.0, rng.next() * 80.0 - 40.0, rng.next() * 60.0 - 30.0);
            assert!(v.sample_index(p) <= m.at(p), "at {p}: sample above its majorant");
        }
    }
}

#[test]
fn box_maximum_sees_what_points_see() {
    let v = random_volume(19, 0.0);
    let m = MajorantGrid::build(&v);
    let mut rng = Lcg(8);
    for _ in 0..2000 {
        let lo = DVec3::new(rng.next() * 90.0 - 45.0, rng.next() * 90.0 - 45.0, rng.next() * 70.0 - 35.0);
        let hi = lo + DVec3::new(rng.next(), rng.next(), rng.next()) * 6.0;
        let boxmax = m.max_in_box(lo, hi);
        for k in 0..8 {
            let p = lo + (hi - lo) * DVec3::new((k & 1) as f64, ((k >> 1) & 1) as f64, ((k >> 2) & 1) as f64);
            assert!(m.at(p) <= boxmax);
            assert!(v.sample_index(p) <= boxmax);
        }
    }
    assert_eq!(m.max_in_box(DVec3::splat(1000.0), DVec3::splat(1001.0)), 0.0);
}

#[test]
fn empty_volume_has_no_majorant() {
    let v: Volume<f32> = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0);
    let m = MajorantGrid::build(&v);
    assert_eq!(m.max(), 0.0);
    let segs: Vec<_> = m.walk(DVec3::ZERO, DVec3::X, 0.0, 10.0).collect();
    assert_eq!(segs.len(), 1);
    assert_eq!(segs[0].majorant, 0.0);
}

#[test]
fn axis_aligned_ray_visits_cells_in_order() {
    let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0f32);
    v.set(IVec3::new(3, 3, 3), 1.0);
    v.set(IVec3::new(27, 3, 3), 5.0);
    let m = MajorantGrid::build(&v);
    let segs: Vec<_> = m.walk(DVec3::new(-100.0, 3.5, 3.5), DVec3::X, 0.0, 300.0).collect();
    let nonzero: Vec<_> = segs.iter().filter(|s| s.majorant > 0.0).collect();
    // Brick 0 influences cells -1 and 0, brick 3 cells 2 and 3 along x.
    assert_eq!(nonzero.len(), 4, "{segs:?}");
    assert_eq!(nonzero[0].t_start, 92.0);
    assert_eq!(nonzero.last().unwrap().t_end, 132.0);
}

/// Integrates the volume along a ray both by the DDA (skipping zero-majorant segments) and by
/// brute force: skipping must not lose anything.
fn march(v: &Volume<f32>, o: DVec3, d: DVec3, t1: f64, segments: Option<&MajorantGrid>) -> f64 {
    let dt = 0.01;
    let mut sum = 0.0;
    let mut add = |a: f64, b: f64| {
        // Sample points on one lattice k * dt, so both walks see the very same points.
        let mut k = (a / dt).ceil() as i64;
        while (k as f64) * dt < b {
            sum += v.sample_index(o + d * (k as f64 * dt)) as f64 * dt;
            k += 1;
        }
    };
    match segments {
        Some(m) => m.walk(o, d, 0.0, t1).filter(|s| s.majorant > 0.0).for_each(|s| add(s.t_start, s.t_end)),
        None => add(0.0, t1),
    }
    sum
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn walk_covers_the_interval_in_order(
        ox in -60.0f64..60.0, oy in -60.0f64..60.0, oz in -60.0f64..60.0,
        dx in -1.0f64..1.0, dy in -1.0f64..1.0, dz in -1.0f64..1.0,
        t0 in 0.0f64..10.0, len in 0.0f64..200.0,
    ) {
        let v = random_volume(13, 0.0);
        let m = MajorantGrid::build(&v);
        let d = DVec3::new(dx, dy, dz);
        prop_assume!(d.length() > 1e-3);
        let segs: Vec<_> = m.walk(DVec3::new(ox, oy, oz), d, t0, t0 + len).collect();
        let mut t = t0;
        for s in &segs {
            prop_assert!((s.t_start - t).abs() < 1e-9, "gap at {}: {:?}", t, segs);
            prop_assert!(s.t_end > s.t_start);
            t = s.t_end;
        }
        if len > 0.0 {
            prop_assert!((t - (t0 + len)).abs() < 1e-9);
        }
        // Every point of every segment is bounded by its segment's majorant.
        for s in &segs {
            for k in 0..5 {
                let tt = s.t_start + (s.t_end - s.t_start) * (k as f64 + 0.5) / 5.0;
                let p = DVec3::new(ox, oy, oz) + d * tt;
                prop_assert!(v.sample_index(p) <= s.majorant, "{} > {} at t={}", v.sample_index(p), s.majorant, tt);
            }
        }
    }

    /// Trilinear sampling is a convex combination of the cell's eight corners: bounded by
    /// their min and max, anywhere (inside bricks, across brick edges, in the background,
    /// and far from the origin, where the cell fraction is computed from large coordinates).
    #[test]
    fn trilinear_sample_lies_between_its_corners(
        seed in 0u64..1000, background in prop::sample::select(vec![0.0f32, 0.5, -1.0]),
        p in prop::array::uniform3(-40.0f64..40.0), far in prop::sample::select(vec![0.0f64, 1e6, -3e7]),
    ) {
        let v = random_volume(seed, background);
        let p = DVec3::from(p) + DVec3::splat(far);
        let b = p.floor().as_ivec3();
        let corners: Vec<f32> = (0..8).map(|n| v.get(b + IVec3::new((n >> 2) & 1, (n >> 1) & 1, n & 1))).collect();
        let lo = corners.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = corners.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let got = v.sample_index(p);
        let slack = 1e-6 * lo.abs().max(hi.abs()).max(1.0);
        prop_assert!(got >= lo - slack && got <= hi + slack, "{} outside [{}, {}] at {}", got, lo, hi, p);
    }
}

#[test]
fn skipping_empty_cells_loses_nothing() {
    let v = random_volume(17, 0.0);
    let m = MajorantGrid::build(&v);
    let mut rng = Lcg(23);
    for _ in 0..20 {
        let o = DVec3::new(rng.next() * 80.0 - 40.0, rng.next() * 80.0 - 40.0, -40.0);
        let d = DVec3::new(rng.next() - 0.5, rng.next() - 0.5, 1.0).normalize();
        let full = march(&v, o, d, 90.0, None);
        let skipped = march(&v, o, d, 90.0, Some(&m));
        assert!((full - skipped).abs() <= 1e-6 * (1.0 + full), "{full} vs {skipped}");
    }
}
