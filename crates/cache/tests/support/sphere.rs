//! Multiple scattering in an optically thick homogeneous sphere lit by a sun, two ways: the
//! baked `Li_multiple` (photons from `nimbus_photon::trace_cpu`, gathered by `bake_cpu`) and an
//! independent Monte Carlo reference that knows nothing of grids or photons.
//!
//! Shared by `tests/multiple.rs` (asserts) and `examples/multiple_sanity.rs` (prints the table).

#![allow(dead_code)]

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, CacheParams, Gather, MultipleEstimator, ShadowMode, LightLattice};
use nimbus_optics::{sample_uniform_sphere, Camera, Light, Medium, Rng};
use nimbus_photon::{trace_cpu, PhotonParams};
use nimbus_volume::{Transform, Volume};
use rayon::prelude::*;

/// Sphere of `radius` (world units) around the origin, sigma_t constant inside, isotropic
/// phase (g = 0), lit by a sun travelling along -Z with irradiance 1.
#[derive(Clone, Copy, Debug)]
pub struct Sphere {
    pub radius: f64,
    pub sigma_t: f64,
    pub albedo: f64,
}

/// The scene of the sanity check: optical radius 4 (diameter 8), albedo 0.99.
pub const THICK: Sphere = Sphere { radius: 1.0, sigma_t: 4.0, albedo: 0.99 };

/// Points the estimates are compared at: centre, lit and shadowed halves, side, near the top.
pub const POINTS: [[f64; 3]; 5] = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, -0.5], [0.5, 0.0, 0.0], [0.0, 0.3, 0.75]];

impl Sphere {
    /// A bake of Li_multiple alone over `density` (this sphere voxelized), the sun above, the
    /// default camera.
    fn multiple_only(&self, density: &Volume<f32>, cache_scale: f64, gather: Gather, estimator: MultipleEstimator, seed: u64) -> CacheParams {
        let (lo, hi) = density.world_bounds().unwrap();
        CacheParams {
            environment: None,
            medium: self.medium(),
            lights: vec![Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap()],
            camera: Camera::default_for_bounds(lo, hi).unwrap(),
            step: 0.5,
            cache_scale,
            single_tolerance: None,
            path_tolerance: None,
            multiple_scale: None,
            multiple_tolerance: None,
            single: false,
            multiple: true,
            gather,
            estimator,
            seed,
            min_transmittance: 1e-4,
            shadows: ShadowMode::Table(LightLattice::default()),
            path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
        }
    }

    /// Distance from `p` (inside) along unit `d` to the surface.
    fn exit(&self, p: DVec3, d: DVec3) -> f64 {
        let b = p.dot(d);
        let c = p.length_squared() - self.radius * self.radius;
        -b + (b * b - c).max(0.0).sqrt()
    }

    /// The density grid: 1 inside, with a one-voxel linear ramp centred on the surface so the
    /// trilinear density has its half-value at `radius` and the same optical depth as the
    /// exact sphere to first order.
    pub fn voxelized(&self, voxel: f64) -> Volume<f32> {
        let mut v = Volume::new(Transform::uniform(voxel, DVec3::ZERO), 0.0);
        let n = (self.radius / voxel).ceil() as i32 + 1;
        for x in -n..=n {
            for y in -n..=n {
                for z in -n..=n {
                    let c = IVec3::new(x, y, z);
                    let r = c.as_dvec3().length() * voxel;
                    let d = ((self.radius - r) / voxel + 0.5).clamp(0.0, 1.0);
                    if d > 0.0 {
                        v.set(c, d as f32);
                    }
                }
            }
        }
        v
    }

    pub fn medium(&self) -> Medium {
        Medium { extinction: self.sigma_t as f32, albedo: Vec3::splat(self.albedo as f32), g: 0.0 }
    }

    /// In-scattered radiance at `x` from light scattered at least once before (Li_multiple for
    /// g = 0): the mean over `paths` of a path traced from x backward through the exact sphere
    /// (analytic free paths exp(-sigma_t t), uniform directions), with next-event estimation
    /// to the sun at every vertex, weighted by albedo^k. Returns the mean and its standard error.
    pub fn reference(&self, x: DVec3, paths: u64, seed: u64) -> (f64, f64) {
        let sun = DVec3::Z; // toward the sun
        let inv_4pi = 1.0 / (4.0 * std::f64::consts::PI);
        let (sum, sum2) = (0..paths)
            .into_par_iter()
            .map(|i| {
                let mut rng = Rng::with_domain(seed, i, 0x5245_4653);
                let (mut p, mut beta, mut value) = (x, 1.0, 0.0);
                for _ in 0..5000 {
                    let w = sample_uniform_sphere(rng.next_vec2()).as_dvec3();
                    let s = -(1.0 - rng.next_f64()).ln() / self.sigma_t;
                    if s >= self.exit(p, w) {
                        break; // left the sphere: nothing but the sun out there
                    }
                    p += w * s;
                    beta *= self.albedo;
                    // Sun light scattered at p toward the previous vertex (isotropic phase).
                    value += beta * (-self.sigma_t * self.exit(p, sun)).exp() * inv_4pi;
                    if beta < 1e-4 {
                        break;
                    }
                }
                (value, value * value)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        let n = paths as f64;
        let mean = sum / n;
        (mean, ((sum2 / n - mean * mean).max(0.0) / n).sqrt())
    }

    /// Li_multiple baked from `photons` stored photons gathered `k` at a time, read at `points`
    /// (red channel; the scene is grey).
    pub fn baked(&self, voxel: f64, photons: u64, k: u32, seed: u64, points: &[DVec3]) -> Vec<f64> {
        let density = self.voxelized(voxel);
        let light = Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap();
        let trace = PhotonParams {
            medium: self.medium(),
            lights: vec![light],
            photons,
            max_interactions: 5000,
            seed,
            ..PhotonParams::default()
        };
        let (map, _) = trace_cpu(&density, &trace).unwrap();
        let params = self.multiple_only(&density, 1.0, Gather::Neighbours { k, max_radius: 0.5 * self.radius }, MultipleEstimator::Photons, 0);
        let (cache, _) = bake_cpu(&density, &map, &params).unwrap();
        let li = cache.li_multiple.expect("photons were stored");
        points.iter().map(|&p| li.sample_world(p).x as f64).collect()
    }
}

impl Sphere {
    /// Li_multiple at `points` by [`nimbus_cache::li_multiple_paths`] straight (no cache
    /// lattice): `paths` paths each, through the voxelized sphere. Returns (mean, standard
    /// error) per point from 8 independent batches.
    pub fn path_traced(&self, voxel: f64, paths: u32, seed: u64, points: &[DVec3]) -> Vec<(f64, f64)> {
        use nimbus_tracking::DensityMedium;
        use nimbus_volume::MajorantGrid;
        let density = self.voxelized(voxel);
        let optics = self.medium();
        let majorant = MajorantGrid::for_tracking(&density, optics.extinction);
        let medium = DensityMedium { motion: None, density: &density, majorant: &majorant, extinction: optics.extinction };
        let lights = [Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap()];
        points
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                let batches: Vec<f64> = (0..8u64)
                    .into_par_iter()
                    .map(|b| {
                        let mut rng = Rng::new(seed, i as u64 * 8 + b);
                        // w_out = +X: the eye lies along +X from p.
                        nimbus_cache::li_multiple_paths(medium, &optics, &lights, &nimbus_tracking::LightDepths::default(), Default::default(), &[p], &[], paths / 8, nimbus_cache::PATH_MAX_DEPTH, p + DVec3::X, &mut rng).mean.x as f64
                    })
                    .collect();
                let mean = batches.iter().sum::<f64>() / 8.0;
                let var = batches.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / 7.0;
                (mean, (var / 8.0).sqrt())
            })
            .collect()
    }

    /// Li_multiple baked by paths (`per_voxel` where the default camera, looking from -Y, sees
    /// a voxel through clear air; fewer behind the medium), read at `points`.
    pub fn baked_paths(&self, voxel: f64, cache_scale: f64, per_voxel: u32, seed: u64, points: &[DVec3]) -> Vec<f64> {
        let density = self.voxelized(voxel);
        let params = self.multiple_only(&density, cache_scale, Gather::Neighbours { k: 1, max_radius: 1.0 }, MultipleEstimator::Paths { per_voxel }, seed);
        let (cache, stats) = bake_cpu(&density, &nimbus_photon::PhotonMap::default(), &params).unwrap();
        assert!(stats.paths >= stats.baked && stats.paths <= stats.baked * per_voxel as u64, "{stats:?}");
        let li = cache.li_multiple.expect("paths need no photons");
        points.iter().map(|&p| li.sample_world(p).x as f64).collect()
    }
}
