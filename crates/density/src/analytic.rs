//! Analytic test densities: particles sampled from a known density, and that density's exact
//! value anywhere, for accuracy measurements and tests.
//!
//! A density is a weighted sum of components with closed-form (or 1D-integrated)
//! normalisation: anisotropic Gaussians (knots, envelopes, cloud puffs, plume segments) and
//! Gaussian-profile spherical shells. `true_density(x) = total_mass * pdf(x)`; each of the n
//! sampled particles carries total_mass / n, so an estimator's output is directly comparable.
//!
//! Sampling is reproducible and parallel: particle i draws from a generator keyed by
//! (seed, i) (counter-based, as design.md section 7 asks), so results do not depend on the
//! thread count.

use std::f64::consts::PI;

use glam::{DVec3, IVec3};
use nimbus_volume::Volume;
use rayon::prelude::*;

use crate::{voxel_world, Grid, ParticleSet};

/// SplitMix64 (Steele et al.): a tiny generator, seeded per particle by hashing (seed, index).
#[derive(Clone, Copy, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64, stream: u64) -> Rng {
        let mut r = Rng(seed ^ 0x9E37_79B9_7F4A_7C15);
        let k = r.next_u64();
        Rng(k ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u = 1.0 - self.uniform(); // (0, 1]
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (2.0 * PI * v).cos()
    }

    pub fn unit_vector(&mut self) -> DVec3 {
        let z = 2.0 * self.uniform() - 1.0;
        let phi = 2.0 * PI * self.uniform();
        let s = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z)
    }
}

/// Shells are truncated at this many widths from their radius (pdf and sampler agree).
const SHELL_CUT: f64 = 6.0;

#[derive(Clone, Debug, PartialEq)]
pub enum Component {
    /// Axis-aligned anisotropic Gaussian.
    Gaussian { centre: DVec3, sigma: DVec3 },
    /// Spherical shell with a Gaussian radial profile exp(-(r-radius)^2 / (2 width^2)),
    /// truncated at |r - radius| = 6 width; empty (a cavity) inside.
    Shell { centre: DVec3, radius: f64, width: f64 },
    /// Uniform density in an axis-aligned ellipsoid, cut off below the plane z = `floor` (a
    /// cumulus puff at its condensation level: the flat base).
    Puff { centre: DVec3, radii: DVec3, floor: f64 },
}

impl Component {
    /// Normalised pdf.
    pub fn pdf(&self, p: DVec3) -> f64 {
        match *self {
            Component::Gaussian { centre, sigma } => {
                let d = (p - centre) / sigma;
                (-0.5 * d.length_squared()).exp() / ((2.0 * PI).powf(1.5) * sigma.element_product())
            }
            Component::Shell { centre, radius, width } => {
                let t = ((p - centre).length() - radius) / width;
                if t.abs() > SHELL_CUT {
                    0.0
                } else {
                    (-0.5 * t * t).exp() / shell_norm(radius, width)
                }
            }
            Component::Puff { centre, radii, floor } => {
                if p.z < floor || ((p - centre) / radii).length_squared() > 1.0 {
                    0.0
                } else {
                    1.0 / puff_volume(radii, (floor - centre.z) / radii.z)
                }
            }
        }
    }

    pub fn sample(&self, rng: &mut Rng) -> DVec3 {
        match *self {
            Component::Gaussian { centre, sigma } => {
                centre + sigma * DVec3::new(rng.normal(), rng.normal(), rng.normal())
            }
            Component::Shell { centre, radius, width } => {
                // Radial pdf ~ r^2 g(r): propose r from the Gaussian g, accept with
                // probability (r / r_max)^2 (rejection sampling).
                let r_max = radius + SHELL_CUT * width;
                let r = loop {
                    let t = rng.normal();
                    let r = radius + width * t;
                    if t.abs() <= SHELL_CUT && r >= 0.0 && rng.uniform() * r_max * r_max < r * r {
                        break r;
                    }
                };
                centre + r * rng.unit_vector()
            }
            Component::Puff { centre, radii, floor } => loop {
                // Rejection from the bounding box: a puff's centre is above its floor, so
                // at least a quarter of the draws are kept.
                let u = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0 - 1.0;
                let p = centre + radii * u;
                if u.length_squared() <= 1.0 && p.z >= floor {
                    break p;
                }
            },
        }
    }
}

/// Volume of the ellipsoid of `radii` above the plane at `t` of its z radius from its centre
/// (t <= -1: all of it): abc times the unit ball's volume above z = t, pi (2/3 - t + t^3/3).
fn puff_volume(radii: DVec3, t: f64) -> f64 {
    let t = t.clamp(-1.0, 1.0);
    radii.element_product() * PI * (2.0 / 3.0 - t + t * t * t / 3.0)
}

/// integral over space of exp(-(r-R)^2/(2w^2)) on |r-R| <= 6w, r >= 0 (Simpson in r).
fn shell_norm(radius: f64, width: f64) -> f64 {
    let a = (radius - SHELL_CUT * width).max(0.0);
    let b = radius + SHELL_CUT * width;
    let n = 4000;
    let h = (b - a) / n as f64;
    let f = |r: f64| 4.0 * PI * r * r * (-0.5 * ((r - radius) / width).powi(2)).exp();
    let mut sum = f(a) + f(b);
    for i in 1..n {
        sum += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

/// A weighted sum of components, normalised by the weights' sum.
#[derive(Clone, Debug, PartialEq)]
pub struct Analytic {
    pub components: Vec<(f64, Component)>,
}

impl Analytic {
    pub fn pdf(&self, p: DVec3) -> f64 {
        let total: f64 = self.components.iter().map(|c| c.0).sum();
        self.components.iter().map(|(w, c)| w * c.pdf(p)).sum::<f64>() / total
    }

    /// `n` positions, particle i drawn with the generator keyed by (seed, i).
    pub fn sample(&self, n: usize, seed: u64) -> Vec<DVec3> {
        let total: f64 = self.components.iter().map(|c| c.0).sum();
        let cumulative: Vec<f64> = self
            .components
            .iter()
            .scan(0.0, |acc, c| {
                *acc += c.0 / total;
                Some(*acc)
            })
            .collect();
        (0..n)
            .into_par_iter()
            .map(|i| {
                let mut rng = Rng::new(seed, i as u64);
                let u = rng.uniform();
                let k = cumulative.partition_point(|&c| c <= u).min(self.components.len() - 1);
                self.components[k].1.sample(&mut rng)
            })
            .collect()
    }
}

/// A named test scene: a density, its total mass and particle count, and the grid it is meant
/// for.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: &'static str,
    pub density: Analytic,
    pub total_mass: f64,
    pub particles: usize,
    /// Suggested voxel size.
    pub voxel_size: f64,
    /// Suggested explicit bounds (None: the estimator's padded particle bounds).
    pub bounds: Option<(DVec3, DVec3)>,
}

impl Scene {
    /// The particles, each carrying total_mass / n (as the masses attribute).
    pub fn particles(&self, seed: u64) -> ParticleSet {
        let positions = self.density.sample(self.particles, seed);
        let m = (self.total_mass / self.particles as f64) as f32;
        ParticleSet { masses: Some(vec![m; positions.len()]), positions, ..Default::default() }
    }

    pub fn true_density(&self, p: DVec3) -> f64 {
        self.total_mass * self.density.pdf(p)
    }

    /// Same scene with `n` particles.
    pub fn with_particles(mut self, n: usize) -> Scene {
        self.particles = n;
        self
    }

    /// Dense knots (contrast ~1000) inside a thin, wide envelope.
    pub fn knots() -> Scene {
        let mut rng = Rng::new(11, 0);
        let mut components = vec![(0.35, Component::Gaussian { centre: DVec3::ZERO, sigma: DVec3::new(24.0, 16.0, 6.0) })];
        for _ in 0..16 {
            let centre = DVec3::new(24.0, 16.0, 5.0) * DVec3::new(rng.normal(), rng.normal(), rng.normal()) * 0.8;
            let s = 0.8 + 1.6 * rng.uniform();
            components.push((0.65 / 16.0 * (0.5 + rng.uniform()), Component::Gaussian { centre, sigma: DVec3::splat(s) }));
        }
        Scene {
            name: "knots",
            density: Analytic { components },
            total_mass: 1000.0,
            particles: 150_000,
            voxel_size: 0.6,
            bounds: None,
        }
    }

    /// A thin dense shell around an empty cavity, in a faint wide halo.
    pub fn shell() -> Scene {
        let components = vec![
            (0.8, Component::Shell { centre: DVec3::ZERO, radius: 20.0, width: 0.7 }),
            (0.2, Component::Gaussian { centre: DVec3::ZERO, sigma: DVec3::splat(18.0) }),
        ];
        Scene {
            name: "shell",
            density: Analytic { components },
            total_mass: 1000.0,
            particles: 150_000,
            voxel_size: 0.5,
            bounds: None,
        }
    }

    /// Cloud1-class: 500k particles over a flat wide box of ~339 x 42 x 361 unit voxels, made
    /// of flattened puffs of widely varying density.
    pub fn cloud1() -> Scene {
        let size = DVec3::new(339.0, 42.0, 361.0);
        let mut rng = Rng::new(21, 0);
        let mut components = Vec::new();
        for _ in 0..240 {
            let sigma = DVec3::new(6.0 + 22.0 * rng.uniform(), 2.0 + 3.0 * rng.uniform(), 6.0 + 22.0 * rng.uniform());
            let margin = DVec3::new(2.0 * sigma.x, 3.0 * sigma.y, 2.0 * sigma.z);
            let u = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let centre = margin + u * (size - 2.0 * margin);
            // Log-uniform weights over two decades: steep contrasts between puffs.
            let weight = 10f64.powf(2.0 * rng.uniform());
            components.push((weight, Component::Gaussian { centre, sigma }));
        }
        Scene {
            name: "cloud1",
            density: Analytic { components },
            total_mass: 5000.0,
            particles: 500_000,
            voxel_size: 1.0,
            bounds: Some((DVec3::ZERO, size)),
        }
    }

    /// Smoke-like plume: a rising, widening, wavering column of puffs, denser at the source.
    pub fn plume() -> Scene {
        Scene {
            name: "plume",
            density: plume_puffs(150.0, DVec3::ZERO),
            total_mass: 1000.0,
            particles: 330_000,
            voxel_size: 0.9,
            bounds: None,
        }
    }

    /// The smoke-like benchmark scene of the issue (330k particles, grid 280 x 255 x 233): the
    /// plume blown sideways by a wind, so it fills a near-cubic simulation box, which is given
    /// as explicit bounds the way a smoke solver's domain would be.
    pub fn smoke() -> Scene {
        let voxel = 0.8;
        let lo = DVec3::new(-30.0, -30.0, -8.0);
        Scene {
            name: "smoke",
            density: plume_puffs(120.0, DVec3::new(120.0, 95.0, 0.0)),
            total_mass: 1000.0,
            particles: 330_000,
            voxel_size: voxel,
            bounds: Some((lo, lo + DVec3::new(280.0, 255.0, 233.0) * voxel)),
        }
    }

    /// A cumulus (the demo's first picture): a cauliflower of overlapping puffs of uniform
    /// density on a flat base at z = 0, about 300 wide (x), 200 deep (y) and 200 tall, Z up.
    /// A few large puffs make the body (a wide foot and a tower leaning to +x), and each puff
    /// buds smaller ones over its upper and outer surface, three generations down; every puff
    /// is cut at the base (`Component::Puff`'s floor). Weights are the puffs' volumes: one
    /// density everywhere, more where puffs overlap.
    pub fn cumulus() -> Scene {
        let mut rng = Rng::new(41, 0);
        let floor = 0.0;
        let mut puffs: Vec<(DVec3, f64)> = Vec::new();
        // The foot: wide puffs along the base, their lower parts cut off.
        for i in 0..6 {
            let t = i as f64 / 5.0 - 0.5;
            let r = 42.0 + 10.0 * rng.uniform();
            puffs.push((DVec3::new(200.0 * t + 8.0 * rng.normal(), 25.0 * rng.normal(), 0.45 * r), r));
        }
        // The tower: rising and narrowing, leaning to +x.
        let axis = |z: f64| DVec3::new(-10.0 + 30.0 * ((z - 30.0) / 120.0).clamp(0.0, 1.0), 0.0, z);
        for i in 0..5 {
            let t = (i + 1) as f64 / 5.0;
            let r = 52.0 - 16.0 * t + 6.0 * rng.uniform();
            let z = 30.0 + 120.0 * t;
            puffs.push((axis(z) + DVec3::new(10.0 * rng.normal(), 8.0 * rng.normal(), 0.0), r));
        }
        // Buds: three generations, each on its parent's upper or outer surface.
        let mut generation: Vec<(DVec3, f64)> = puffs.clone();
        for count in [6, 4, 3] {
            let mut next = Vec::new();
            for &(centre, r) in &generation {
                let outward = (centre - axis(centre.z)).normalize_or_zero();
                for _ in 0..count {
                    let dir = (rng.unit_vector() + 0.6 * outward + DVec3::new(0.0, 0.0, 0.5)).normalize();
                    let child_r = r * (0.4 + 0.15 * rng.uniform());
                    let child = centre + dir * r * (0.75 + 0.2 * rng.uniform());
                    // Above the base by its own radius: the base stays flat.
                    if child.z > floor + child_r {
                        next.push((child, child_r));
                    }
                }
            }
            puffs.extend(next.iter().copied());
            generation = next;
        }
        let components = puffs
            .iter()
            .map(|&(centre, r)| {
                let c = Component::Puff { centre, radii: DVec3::new(r, r, 0.9 * r), floor };
                (1.0 / c.pdf(centre.max(DVec3::new(f64::MIN, f64::MIN, floor))), c)
            })
            .collect();
        Scene {
            name: "cumulus",
            density: Analytic { components },
            total_mass: 1.0e6,
            particles: 120_000,
            voxel_size: 2.0,
            bounds: None,
        }
    }

    pub fn by_name(name: &str) -> Option<Scene> {
        match name {
            "knots" => Some(Scene::knots()),
            "shell" => Some(Scene::shell()),
            "cloud1" => Some(Scene::cloud1()),
            "plume" => Some(Scene::plume()),
            "smoke" => Some(Scene::smoke()),
            "cumulus" => Some(Scene::cumulus()),
            _ => None,
        }
    }
}

/// 80 puffs rising `height` from the origin, widening from sigma 2 to 16 and drifting by
/// `wind` at the top (quadratically: the column bends over), each with a small dense eddy.
fn plume_puffs(height: f64, wind: DVec3) -> Analytic {
    let mut rng = Rng::new(31, 0);
    let mut components = Vec::new();
    let n = 80;
    for i in 0..n {
        let t = i as f64 / (n - 1) as f64;
        let z = height * t;
        let centre = DVec3::new(12.0 * (z / 25.0).sin() * t, 8.0 * (z / 35.0).cos() * t, z) + wind * t * t;
        let s = 2.0 + 14.0 * t;
        let jitter = DVec3::new(rng.normal(), rng.normal(), rng.normal()) * 0.4 * s;
        let weight = 1.0 - 0.6 * t;
        components.push((weight, Component::Gaussian { centre: centre + jitter, sigma: DVec3::splat(s) }));
        // Small dense eddies riding on the column.
        components.push((0.15 * weight, Component::Gaussian { centre: centre - jitter, sigma: DVec3::splat(0.3 * s + 0.5) }));
    }
    Analytic { components }
}

/// A scene's true density at every point of a grid, to score estimates against.
pub struct TrueGrid {
    pub grid: Grid,
    /// x fastest, then y, then z.
    pub values: Vec<f64>,
    /// sum of values^2.
    pub norm2: f64,
}

impl TrueGrid {
    pub fn new(scene: &Scene, grid: Grid) -> TrueGrid {
        let values: Vec<f64> = (0..grid.voxel_count() as usize).into_par_iter().map(|n| scene.true_density(voxel_world(&grid, index_of(&grid, n)))).collect();
        let norm2 = values.iter().map(|v| v * v).sum();
        TrueGrid { grid, values, norm2 }
    }

    /// Relative L2 error of an estimate on the same grid: sqrt(sum (rho - rho_true)^2 / sum
    /// rho_true^2), over every grid point (inactive voxels count as 0).
    pub fn rel_l2(&self, density: &Volume<f32>) -> f64 {
        let err2: f64 = (0..self.values.len())
            .into_par_iter()
            .map(|n| {
                let e = density.get(index_of(&self.grid, n)) as f64 - self.values[n];
                e * e
            })
            .sum();
        (err2 / self.norm2).sqrt()
    }

    /// The same over the rim only: the grid points whose true density is below `fraction` of
    /// the true maximum (where particles are sparse and a narrow kernel leaves separate
    /// blobs), normalised by the true density there.
    pub fn rim_rel_l2(&self, density: &Volume<f32>, fraction: f64) -> f64 {
        let max = self.values.iter().cloned().fold(0.0f64, f64::max);
        let limit = fraction * max;
        let (err2, norm2) = (0..self.values.len())
            .into_par_iter()
            .filter(|&n| self.values[n] < limit)
            .map(|n| {
                let e = density.get(index_of(&self.grid, n)) as f64 - self.values[n];
                (e * e, self.values[n] * self.values[n])
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        (err2 / norm2).sqrt()
    }
}

fn index_of(grid: &Grid, n: usize) -> IVec3 {
    let d = grid.dims.as_i64vec3();
    let n = n as i64;
    IVec3::new((n % d.x) as i32, ((n / d.x) % d.y) as i32, (n / (d.x * d.y)) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_pdf_integrates_to_one() {
        let c = Component::Shell { centre: DVec3::ZERO, radius: 5.0, width: 0.5 };
        // Radial integral of the pdf, by Simpson on the radius.
        let (a, b, n) = (2.0, 8.0, 2000);
        let h = (b - a) / n as f64;
        let f = |r: f64| 4.0 * PI * r * r * c.pdf(DVec3::new(r, 0.0, 0.0));
        let mut s = f(a) + f(b);
        for i in 1..n {
            s += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        assert!((s * h / 3.0 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_cut_puff_integrates_to_one_and_its_samples_stay_above_the_floor() {
        let c = Component::Puff { centre: DVec3::new(0.0, 0.0, 1.0), radii: DVec3::new(2.0, 3.0, 1.5), floor: 0.0 };
        // Midpoint rule over the bounding box [-2, 2] x [-3, 3] x [0, 2.5].
        let n = 160;
        let h = DVec3::new(4.0, 6.0, 2.5) / n as f64;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = DVec3::new(-2.0, -3.0, 0.0) + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * h;
                    sum += c.pdf(p);
                }
            }
        }
        assert!((sum * h.element_product() - 1.0).abs() < 0.01, "{}", sum * h.element_product());
        assert_eq!(c.pdf(DVec3::new(0.0, 0.0, -0.01)), 0.0);
        let mut rng = Rng::new(3, 0);
        assert!((0..10_000).map(|_| c.sample(&mut rng)).all(|p| p.z >= 0.0 && c.pdf(p) > 0.0));
    }

    #[test]
    fn sampling_is_reproducible_and_matches_the_mean() {
        let a = Analytic { components: vec![(1.0, Component::Gaussian { centre: DVec3::new(1.0, 2.0, 3.0), sigma: DVec3::ONE })] };
        let s = a.sample(20_000, 5);
        assert_eq!(s, a.sample(20_000, 5));
        let mean = s.iter().copied().sum::<DVec3>() / s.len() as f64;
        assert!((mean - DVec3::new(1.0, 2.0, 3.0)).length() < 0.05);
    }
}
