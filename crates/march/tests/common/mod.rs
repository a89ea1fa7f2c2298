//! Shared by the GPU agreement tests and the bench: a device (or a loud skip), a cloud, a
//! varying illumination cache and a camera.
#![allow(dead_code)]

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::IlluminationCache;
use nimbus_gpu::GpuContext;
use nimbus_march::MarchParams;
use nimbus_optics::{Camera, Light, Medium};
use nimbus_volume::{Transform, Volume};

/// The process-wide test device (see [`nimbus_gpu::test_context`]).
pub fn gpu() -> Option<&'static GpuContext> {
    nimbus_gpu::test_context()
}

pub const VOXEL: f64 = 0.1;

/// A lumpy cloud in a cube of `n`^3 voxels around `centre`: a ball whose density falls off
/// toward its edge, times a ripple, with a hole, so rays see gradients, empty majorant
/// cells inside the bounds and edges.
pub fn cloud(n: i32, peak: f32, centre: DVec3) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(VOXEL, centre + DVec3::new(0.013, -0.021, 0.007)), 0.0);
    let r = n as f32 / 2.0;
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                let p = IVec3::new(x, y, z).as_vec3() - (r - 0.5);
                let q = p.length() / r;
                let hole = (p - Vec3::new(r * 0.4, 0.0, r * 0.3)).length() < r * 0.3;
                if q < 1.0 && !hole {
                    let ripple = 1.0 + 0.4 * (p.x * 0.7).sin() * (p.y * 0.5).cos() * (p.z * 0.3 + 1.0).sin();
                    v.set(IVec3::new(x, y, z) - IVec3::splat(n / 2), peak * (1.0 - q * q) * ripple);
                }
            }
        }
    }
    v
}

/// Unit density at the voxels of edge `voxel` (origin at index 0) within [lo, hi] where
/// `inside` holds: slabs, cubes and balls with closed-form optics.
pub fn filled(voxel: f64, lo: IVec3, hi: IVec3, inside: impl Fn(IVec3) -> bool) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(voxel, DVec3::ZERO), 0.0);
    for x in lo.x..=hi.x {
        for y in lo.y..=hi.y {
            for z in lo.z..=hi.z {
                let c = IVec3::new(x, y, z);
                if inside(c) {
                    v.set(c, 1.0);
                }
            }
        }
    }
    v
}

/// A soft ball of radius 14 voxels of edge `voxel` around the origin, with a denser lobe
/// off-centre: smooth enough that cache interpolation error stays small.
pub fn soft_ball(voxel: f64) -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(voxel, DVec3::ZERO), 0.0);
    let r = 14;
    for x in -r..=r {
        for y in -r..=r {
            for z in -r..=r {
                let p = IVec3::new(x, y, z).as_dvec3() * voxel;
                let ball = (1.0 - p.length() / (r as f64 * voxel)).max(0.0);
                let lobe = (-(p - DVec3::new(0.2, 0.0, 0.15)).length_squared() / 0.02).exp();
                let d = 3.0 * ball + 6.0 * lobe * ball.min(1.0);
                if d > 0.0 {
                    v.set(IVec3::new(x, y, z), d as f32);
                }
            }
        }
    }
    v
}

/// A smoothly varying cache: Li_single on a lattice of the density's voxel size offset
/// by half a voxel, Li_multiple on a lattice twice as coarse and offset again, both
/// covering the density and a margin: lattices that do not share the density's points.
pub fn cache_for(density: &Volume<f32>) -> IlluminationCache {
    let (lo, _) = density.world_bounds().unwrap();
    let single = Transform::uniform(VOXEL, lo);
    let multiple = Transform::uniform(2.0 * VOXEL, lo + DVec3::splat(0.037));
    IlluminationCache { li_single: Some(cache_grid(density, single, &li_single)), li_multiple: Some(cache_grid(density, multiple, &li_multiple)), ..Default::default() }
}

/// The same fields on vdbcache's lattices: the density's, coarsened by whole factors on its
/// own points (`--cache-scale`, `--multiple-scale`).
pub fn cache_on_density_lattice(density: &Volume<f32>, single_scale: f64, multiple_scale: f64) -> IlluminationCache {
    let on = |scale: f64| Transform::new(density.transform().index_to_world() * glam::DAffine3::from_scale(DVec3::splat(scale))).unwrap();
    IlluminationCache {
        li_single: Some(cache_grid(density, on(single_scale), &li_single)),
        li_multiple: Some(cache_grid(density, on(multiple_scale), &li_multiple)),
        ..Default::default()
    }
}

fn li_single(p: DVec3) -> Vec3 {
    let s = (1.5 + (p.z * 2.0).sin() + 0.5 * (p.x * 3.0).cos()) as f32;
    Vec3::new(2.0 * s, 1.6 * s, 1.2 * s)
}

fn li_multiple(p: DVec3) -> Vec3 {
    let s = (0.6 + 0.3 * (p.y * 2.5).sin() * (p.z * 1.5).cos()) as f32;
    Vec3::new(0.3 * s, 0.35 * s, 0.5 * s)
}

/// `f` (of the position relative to the density's lower world corner) at every point of the
/// lattice `t` over the density's world bounds and two points beyond.
fn cache_grid(density: &Volume<f32>, t: Transform, f: &dyn Fn(DVec3) -> Vec3) -> Volume<Vec3> {
    let (lo, hi) = density.world_bounds().unwrap();
    let (a, b) = (t.to_index(lo).floor().as_ivec3() - 2, t.to_index(hi).ceil().as_ivec3() + 2);
    let mut v = Volume::new(t, Vec3::ZERO);
    for x in a.x..=b.x {
        for y in a.y..=b.y {
            for z in a.z..=b.z {
                let c = IVec3::new(x, y, z);
                v.set(c, f(t.to_world(c.as_dvec3()) - lo));
            }
        }
    }
    v
}

/// The cached chain's single scattering as its two checks run it (against the reference
/// path tracer, and against a brute-force render): Li_single alone, baked on the density
/// lattice for `medium` lit by `sun` with tabled shadows, and the march over it at `step`,
/// one sample per pixel on the plain lattice, no noise.
pub fn single_scattering_chain(density: &Volume<f32>, medium: Medium, sun: Light, camera: &Camera, step: f64) -> (IlluminationCache, MarchParams) {
    use nimbus_cache::{bake_cpu, CacheParams, Gather, LightLattice, MultipleEstimator, ShadowMode};
    let cache_params = CacheParams {
        environment: None,
        medium,
        lights: vec![sun],
        camera: camera.clone(),
        step: 0.5,
        cache_scale: 1.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        single: true,
        multiple: false,
        gather: Gather::Neighbours { k: 8, max_radius: 1.0 },
        estimator: MultipleEstimator::Photons,
        seed: 0,
        min_transmittance: 0.0,
        shadows: ShadowMode::Table(LightLattice::default()),
        path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
    };
    let (cache, _) = bake_cpu(density, &nimbus_photon::PhotonMap::default(), &cache_params).unwrap();
    let march = MarchParams { step, max_step_factor: 1, noise_scale: 1.0, noise_octaves: 1, min_transmittance: 0.0, seed: 3, ..MarchParams::new(medium, camera.clone(), density.transform()) };
    (cache, march)
}

/// Looks at `centre` from -Y and a little above, the cloud filling most of the frame.
pub fn camera(centre: DVec3, width: u32, height: u32) -> Camera {
    Camera::new(centre + DVec3::new(0.4, -5.0, 1.2), centre, DVec3::Z, 45.0, width, height).unwrap()
}

pub fn params(camera: Camera) -> MarchParams {
    MarchParams {
        environment: None,
        environment_visible: false,
        medium: Medium { extinction: 1.0, albedo: Vec3::new(0.9, 0.8, 0.7), g: 0.0 },
        camera,
        step: 0.5 * VOXEL,
        max_step_factor: MarchParams::DEFAULT_MAX_STEP_FACTOR,
        spp: 1,
        background: Vec3::new(0.05, 0.1, 0.2),
        offset_noise: 0.0,
        noise_scale: 0.5,
        noise_octaves: 3,
        noise_eval: Default::default(),
        min_transmittance: 0.0,
        seed: 7,
        aovs: true,
    }
}

/// A fire for the emission tests: an emission grid (a smaller cloud on its own lattice,
/// shifted and of another voxel size, so the GPU looks it up in its own index space) and a
/// temperature grid (the cloud's shape, 0.8 to 3 units at 1000 K a unit), both terms on.
pub fn fire(centre: DVec3) -> (Volume<f32>, Volume<f32>, nimbus_optics::Emission) {
    let mut flame = Volume::new(Transform::uniform(0.07, centre + DVec3::new(-0.11, 0.05, -0.2)), 0.0);
    let mut temperature = Volume::new(Transform::uniform(VOXEL, centre + DVec3::new(0.013, -0.021, 0.007)), 0.0);
    for x in -16..16 {
        for y in -16..16 {
            for z in -16..16 {
                let c = IVec3::new(x, y, z);
                let q = c.as_vec3().length() / 16.0;
                if q < 1.0 {
                    flame.set(c, 1.5 * (1.0 - q));
                    temperature.set(c, 0.8 + 2.2 * (1.0 - q * q));
                }
            }
        }
    }
    let params = nimbus_optics::Emission {
        grid: Some("flame".into()),
        strength: 0.7,
        color: Vec3::new(1.0, 0.6, 0.3),
        temperature_grid: Some("temperature".into()),
        temperature_scale: 1000.0,
        blackbody_intensity: 0.4,
    };
    (flame, temperature, params)
}
