//! A sun's emitting lattice (design.md section 5: photons are emitted only where they can meet
//! medium): it must cover every ray that meets density (or the estimate loses light), hug
//! the medium's projection (or the photons are wasted), and be sampled uniformly (or the
//! power per photon is wrong).

use glam::{DAffine3, DMat3, DVec2, DVec3, IVec3, Vec3};
use nimbus_optics::{sample_uniform_sphere, Light, Rng};
use nimbus_photon::{emitted_power, PhotonParams, PointEmission, SunEmission, DIRECTION_COLUMNS, DIRECTION_ROWS};
use nimbus_volume::{Transform, Volume};

/// Sparse medium on a sheared, anisotropic lattice: a few lone voxels, some on brick faces
/// (whose support reaches into the next brick), and a small lump across bricks.
fn scattered() -> Volume<f32> {
    let m = DMat3::from_cols(DVec3::new(0.5, 0.0, 0.0), DVec3::new(0.1, 0.7, 0.0), DVec3::new(-0.05, 0.15, 0.4));
    let mut v = Volume::new(Transform::new(DAffine3::from_mat3_translation(m, DVec3::new(3.0, -2.0, 1.0))).unwrap(), 0.0);
    for ijk in [IVec3::new(3, 3, 3), IVec3::new(40, -16, 8), IVec3::new(-24, 31, -1), IVec3::new(16, 0, 23), IVec3::new(7, 47, 40)] {
        v.set(ijk, 0.5);
    }
    for x in 60..64 {
        for y in 10..13 {
            for z in -3..2 {
                v.set(IVec3::new(x, y, z), 2.0);
            }
        }
    }
    v
}

fn suns() -> Vec<Vec3> {
    vec![Vec3::NEG_Z, Vec3::X, Vec3::new(-0.7, 0.5, -0.5), Vec3::new(0.3, -0.2, -1.0), Vec3::new(1.0, 1e-3, -2e-3), Vec3::new(0.2, 0.9, 0.1)]
}

/// Index-space boxes where each positive voxel interpolates to a positive value (trilinear
/// sampling reads voxel v from positions in (v - 1, v + 1)): the medium's true support,
/// voxel by voxel.
fn supports(v: &Volume<f32>) -> Vec<(DVec3, DVec3)> {
    let mut boxes = Vec::new();
    for brick in v.bricks() {
        for (offset, &value) in brick.values.iter().enumerate() {
            if value > 0.0 {
                let c = (brick.origin + nimbus_volume::brick_local(offset)).as_dvec3();
                boxes.push((c - 1.0, c + 1.0));
            }
        }
    }
    boxes
}

/// Whether the ray `o + t d`, t >= 0, passes through the open box (slab test).
fn ray_meets(o: DVec3, d: DVec3, (lo, hi): (DVec3, DVec3)) -> bool {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] <= lo[a] || o[a] >= hi[a] {
                return false;
            }
        } else {
            let (u, w) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
            t0 = t0.max(u.min(w));
            t1 = t1.min(u.max(w));
        }
    }
    t0 < t1
}

/// Rays sampled against an emitter's marked cells: one from an unmarked cell must not meet
/// medium (what keeps the estimate unbiased); the counts show the check was not idle.
#[derive(Default)]
struct Coverage {
    unmarked: u32,
    marked_hits: u32,
}

impl Coverage {
    fn add(&mut self, marked: bool, hits: bool, ray: impl std::fmt::Display) {
        if marked {
            self.marked_hits += hits as u32;
        } else {
            self.unmarked += 1;
            assert!(!hits, "{ray}: from an unmarked cell, it meets medium");
        }
    }

    fn assert_busy(&self, unmarked: u32, marked_hits: u32, what: impl std::fmt::Display) {
        assert!(self.unmarked > unmarked && self.marked_hits > marked_hits, "{what}: {} unmarked rays, {} marked ones meeting medium", self.unmarked, self.marked_hits);
    }
}

fn lattice_extent(e: &SunEmission) -> (u32, u32) {
    e.cells.iter().fold((0, 0), |(c, r), cell| (c.max(cell[0] + 1), r.max(cell[1] + 1)))
}

#[test]
fn no_ray_from_outside_the_marked_cells_meets_medium() {
    let v = scattered();
    let support = supports(&v);
    for dir in suns() {
        let e = SunEmission::new(dir, &v).unwrap();
        let (columns, rows) = lattice_extent(&e);
        let mut rng = Rng::new(5, 0);
        let mut coverage = Coverage::default();
        for _ in 0..40_000 {
            // Anywhere over the lattice's rectangle and a margin of three cells around it.
            let q = DVec2::new(rng.next_f64() * (columns + 6) as f64 - 3.0, rng.next_f64() * (rows + 6) as f64 - 3.0);
            let p = e.corner + (q.x * e.tangent + q.y * e.bitangent) * e.cell;
            let (o, d) = (v.transform().to_index(p), v.transform().dir_to_index(e.normal));
            coverage.add(e.cell_of(p).is_some(), support.iter().any(|&b| ray_meets(o, d, b)), format_args!("sun {dir}, ray from {p}"));
        }
        coverage.assert_busy(1000, 100, format_args!("sun {dir}"));
        // Every photon starts upstream of all medium, inside a marked cell.
        for i in 0..2000 {
            let p = e.sample_point(&mut Rng::new(9, i));
            assert!(e.cell_of(p).is_some(), "sun {dir}: sampled point {p} outside the marked cells");
            let o = v.transform().to_index(p);
            assert!(!support.iter().any(|&(lo, hi)| o.cmpgt(lo).all() && o.cmplt(hi).all()), "sun {dir}: {p} starts inside medium");
            let d = v.transform().dir_to_index(e.normal);
            assert!(!support.iter().any(|&b| ray_meets(o, -d, b)), "sun {dir}: medium upstream of {p}");
        }
    }
}

#[test]
fn the_marked_area_hugs_the_medium() {
    // One voxel, unit voxels, sun straight down: its support is a 2 x 2 column, and the
    // unit lattice cells may add up to one cell on each side.
    let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0f32);
    v.set(IVec3::new(3, 4, 5), 1.0);
    let e = SunEmission::new(Vec3::NEG_Z, &v).unwrap();
    assert!((4.0..=16.0).contains(&e.area()), "area {}", e.area());

    // Two such specks far apart: a disc over their bounding box is ~10^4 times larger.
    v.set(IVec3::new(203, 204, 105), 1.0);
    let e = SunEmission::new(Vec3::new(-0.7, 0.5, -0.5), &v).unwrap();
    let (lo, hi) = v.world_bounds().unwrap();
    let normal = Vec3::new(-0.7, 0.5, -0.5).as_dvec3().normalize();
    let half = 0.5 * (hi - lo);
    let radius = (0..8)
        .map(|n| {
            let c = DVec3::new(if n & 1 == 0 { -half.x } else { half.x }, if n & 2 == 0 { -half.y } else { half.y }, if n & 4 == 0 { -half.z } else { half.z });
            (c - c.dot(normal) * normal).length()
        })
        .fold(0.0, f64::max);
    let disc = std::f64::consts::PI * radius * radius;
    assert!(e.area() < disc / 100.0, "area {} against the bounds' disc {disc}", e.area());
    // Each speck's support is a cube of edge 2, whose shadow is at least a square of edge 2
    // (its smallest cross-section): the marked area cannot be below that.
    assert!(e.area() >= 2.0 * 4.0, "area {}", e.area());
}

#[test]
fn start_points_are_uniform_over_the_marked_cells() {
    let v = scattered();
    let e = SunEmission::new(Vec3::new(0.3, -0.2, -1.0), &v).unwrap();
    let n = e.cells.len();
    let draws = 400 * n;
    let mut counts = vec![0u32; n];
    let mut lower_half = 0u64;
    for i in 0..draws as u64 {
        let p = e.sample_point(&mut Rng::new(2, i));
        counts[e.cell_of(p).expect("a marked cell")] += 1;
        let across = (p - e.corner).dot(e.tangent) / e.cell;
        lower_half += (across.fract() < 0.5) as u64;
    }
    // Pearson's chi-square over the cells: mean n - 1, sd sqrt(2 (n - 1)); 5 sd.
    let expected = draws as f64 / n as f64;
    let chi2: f64 = counts.iter().map(|&c| (c as f64 - expected).powi(2) / expected).sum();
    let dof = (n - 1) as f64;
    assert!((chi2 - dof).abs() < 5.0 * (2.0 * dof).sqrt(), "chi-square {chi2} over {dof} degrees of freedom");
    let half = lower_half as f64 / draws as f64;
    assert!((half - 0.5).abs() < 5.0 * (0.25 / draws as f64).sqrt(), "within-cell fraction {half}");
}

#[test]
fn a_sun_emits_irradiance_times_the_marked_area() {
    let v = scattered();
    let sun = Light::sun(Vec3::new(-0.7, 0.5, -0.5), Vec3::new(2.0, 1.0, 0.5)).unwrap();
    let params = PhotonParams { lights: vec![sun], ..PhotonParams::default() };
    let e = SunEmission::new(Vec3::new(-0.7, 0.5, -0.5), &v).unwrap();
    let power = emitted_power(&v, &params).unwrap().unwrap();
    assert!((power - Vec3::new(2.0, 1.0, 0.5) * e.area() as f32).abs().max_element() < 1e-5 * power.max_element());
}

/// Point lights around and inside the scattered medium: far, beside the lump (boxes split
/// before their cones are marked), among the specks, and on top of a voxel.
fn point_lights(v: &Volume<f32>) -> Vec<DVec3> {
    let t = v.transform();
    vec![
        DVec3::new(-40.0, 25.0, 60.0),
        t.to_world(DVec3::new(58.5, 11.0, 0.0)),
        t.to_world(DVec3::new(20.0, 20.0, 20.0)),
        t.to_world(DVec3::new(3.0, 3.0, 3.0)),
    ]
}

#[test]
fn no_direction_outside_the_marked_cells_meets_medium() {
    let v = scattered();
    let support = supports(&v);
    let cells = (DIRECTION_ROWS * DIRECTION_COLUMNS) as usize;
    for (n, position) in point_lights(&v).into_iter().enumerate() {
        let e = PointEmission::new(position, &v);
        let o = v.transform().to_index(position);
        if n == 3 {
            assert_eq!(e.cells.len(), cells, "a light on a voxel sees medium in every direction");
            continue;
        }
        let mut rng = Rng::new(6, n as u64);
        let mut coverage = Coverage::default();
        let (lo, hi) = v.world_bounds().unwrap();
        for k in 0..40_000 {
            // Uniform over the sphere, toward random points of the medium's bounding box, and
            // toward random points of the voxels' supports (those always meet medium).
            let mut random_point = |lo: DVec3, hi: DVec3| lo + (hi - lo) * DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
            let dir = match k % 3 {
                0 => sample_uniform_sphere(rng.next_vec2()).as_dvec3().normalize(),
                1 => (random_point(lo, hi) - position).normalize(),
                _ => {
                    let (a, b) = support[k / 3 % support.len()];
                    (v.transform().to_world(random_point(a, b)) - position).normalize()
                }
            };
            let hits = support.iter().any(|&b| ray_meets(o, v.transform().dir_to_index(dir), b));
            coverage.add(e.cell_of(dir).is_some(), hits, format_args!("light {position}, direction {dir}"));
        }
        coverage.assert_busy(1000, 10_000, format_args!("light {position}"));
        assert!(e.cells.len() < cells / 2, "light {position}: {} of {cells} cells marked", e.cells.len());
        for i in 0..2000 {
            let dir = e.sample_direction(&mut Rng::new(8, i));
            assert!(e.cell_of(dir).is_some(), "light {position}: sampled {dir} outside the marked cells");
        }
    }
}

#[test]
fn the_marked_directions_hug_the_medium() {
    // One voxel 100 voxels away: its support, a cube of edge 2, subtends at most about
    // pi (sqrt(3) / 100)^2 sr; the cells add at most their own width around it.
    let mut v = Volume::new(Transform::uniform(1.0, DVec3::ZERO), 0.0f32);
    v.set(IVec3::new(3, 4, 5), 1.0);
    let e = PointEmission::new(DVec3::new(3.0, 4.0, 105.0), &v);
    let cell = 4.0 * std::f64::consts::PI / (DIRECTION_ROWS * DIRECTION_COLUMNS) as f64;
    let cone = std::f64::consts::PI * (3.0f64.sqrt() / 99.0).powi(2);
    assert!(e.solid_angle() >= 4.0 / 101.0f64.powi(2), "{} sr", e.solid_angle());
    assert!(e.solid_angle() <= cone + 40.0 * cell, "{} sr: {} cells", e.solid_angle(), e.cells.len());
}

#[test]
fn directions_are_uniform_over_the_marked_cells() {
    let v = scattered();
    let e = PointEmission::new(DVec3::new(-40.0, 25.0, 60.0), &v);
    let n = e.cells.len();
    let draws = 200 * n;
    let mut counts = vec![0u32; n];
    for i in 0..draws as u64 {
        counts[e.cell_of(e.sample_direction(&mut Rng::new(2, i))).expect("a marked cell")] += 1;
    }
    let expected = draws as f64 / n as f64;
    let chi2: f64 = counts.iter().map(|&c| (c as f64 - expected).powi(2) / expected).sum();
    let dof = (n - 1) as f64;
    assert!((chi2 - dof).abs() < 5.0 * (2.0 * dof).sqrt(), "chi-square {chi2} over {dof} degrees of freedom");
}

#[test]
fn a_point_light_emits_intensity_times_the_marked_solid_angle() {
    let v = scattered();
    let position = DVec3::new(-40.0, 25.0, 60.0);
    let point = Light::point(position, Vec3::new(2.0, 1.0, 0.5)).unwrap();
    let params = PhotonParams { lights: vec![point], ..PhotonParams::default() };
    let e = PointEmission::new(position, &v);
    let power = emitted_power(&v, &params).unwrap().unwrap();
    assert!((power - Vec3::new(2.0, 1.0, 0.5) * e.solid_angle() as f32).abs().max_element() < 1e-5 * power.max_element());
    assert!(e.solid_angle() < 0.1 * 4.0 * std::f64::consts::PI, "{} sr", e.solid_angle());
}
