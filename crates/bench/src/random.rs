//! Unseen scenes drawn at random (issue #47): `nimbus-scene --random SEED OUT.vdb` writes one,
//! `scripts/bench_random.sh` runs many through the chain against the path-traced reference.
//! Three hand-made scenes ([`crate::scenes`]) do not sample the space of scenes users have;
//! this draws from a wide one, each property on its own so the space is covered rather than a
//! few corners of it:
//!
//! - **shape** (in the index box's normalised coordinates u in [-1,1]^3): fBm lumps in an
//!   ellipsoid, a spherical shell, a warped layer (an anvil, a sheet), particle-like clumps
//!   (sums of small blobs), or two of these combined;
//! - **lattice**: voxel edges with ratios up to 1:2.5, axis-aligned, rotated, sheared or both;
//!   the index box anywhere from well below zero to above it (negative indices); the world
//!   offset 0 or up to 1e6 per axis; 20k to 250k active voxels, so a scene bakes in seconds;
//! - **medium**: optical depth per voxel, extinction x mean active density x the voxel's
//!   geometric-mean edge, log-uniform in 0.005..20; g uniform in -0.5..0.95; albedo per channel
//!   0.3..0.999 (1 - albedo log-uniform, so high albedos, where multiple scattering rules, are
//!   as common as low);
//! - **lights**: a key light (a sun overhead, grazing, behind the camera, behind the volume
//!   toward the camera (a backlit rim), a point light, or the sky alone), perhaps a second,
//!   perhaps a sky, perhaps emission from a grid `emission` written beside the density;
//! - **camera**: a direction from any azimuth and -30..60 degrees of elevation, and a pixel
//!   footprint of 0.25..4 voxels at the look-at point (log-uniform): the image's size and field
//!   of view are chosen to hit it within a pixel budget, so at small footprints the camera sees
//!   part of the volume.
//!
//! Every property takes its numbers from its own counter-based stream (`nimbus_optics::Rng`,
//! Philox keyed by the seed, the stream's index the property's), so a scene is a pure function
//! of its seed, and adding a property later leaves the others' draws as they were.

use std::f64::consts::PI;
use std::fmt::Write as _;

use glam::{DAffine3, DMat3, DQuat, DVec3, IVec3};
use nimbus_optics::noise::Fbm;
use nimbus_optics::Rng;
use nimbus_volume::{Transform, Volume};

use crate::scenes::Scene;

/// The ranges the draws keep to (the tests check them).
pub const OPTICAL_DEPTH_PER_VOXEL: (f64, f64) = (0.005, 20.0);
pub const G: (f64, f64) = (-0.5, 0.95);
pub const ALBEDO: (f64, f64) = (0.3, 0.999);
pub const FOOTPRINT_VOXELS: (f64, f64) = (0.25, 4.0);
/// Largest ratio of two voxel edges (before the shear).
pub const ANISOTROPY: f64 = 2.5;
pub const WORLD_OFFSET_MAX: f64 = 1.0e6;
/// The active voxels the shape's box is sized for (the shape's fill of its box is estimated
/// by sampling, so the count lands near, not exactly on, the draw).
pub const ACTIVE_VOXELS: (f64, f64) = (20_000.0, 250_000.0);
/// The default most pixels an image has (width x height).
pub const MAX_PIXELS: u32 = 40_000;
/// Smallest image side: 2x2-block scores need a few blocks across.
const MIN_SIDE: u32 = 16;
/// The grid the emission is written to, beside `density`.
pub const EMISSION_GRID: &str = "emission";

/// A random scene: the density and flags of a [`Scene`], the emission grid where the draw
/// has one (its flags are in `scene.medium`), and what was drawn.
pub struct RandomScene {
    pub scene: Scene,
    pub emission: Option<Volume<f32>>,
    pub draw: Draw,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ShapeKind {
    Lumps,
    Shell,
    Layer,
    Clumps,
}

impl ShapeKind {
    const ALL: [ShapeKind; 4] = [ShapeKind::Lumps, ShapeKind::Shell, ShapeKind::Layer, ShapeKind::Clumps];
    fn name(self) -> &'static str {
        match self {
            ShapeKind::Lumps => "lumps",
            ShapeKind::Shell => "shell",
            ShapeKind::Layer => "layer",
            ShapeKind::Clumps => "clumps",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LightKind {
    Overhead,
    Grazing,
    BehindCamera,
    Backlit,
    Point,
}

impl LightKind {
    fn name(self) -> &'static str {
        match self {
            LightKind::Overhead => "sun overhead",
            LightKind::Grazing => "sun grazing",
            LightKind::BehindCamera => "sun behind camera",
            LightKind::Backlit => "sun backlit",
            LightKind::Point => "point",
        }
    }
}

/// What a seed drew, for the description and the tests.
#[derive(Clone, Debug)]
pub struct Draw {
    pub seed: u64,
    pub shapes: Vec<ShapeKind>,
    /// Voxel edges before rotation and shear.
    pub voxel_edges: DVec3,
    pub rotated: bool,
    pub sheared: bool,
    pub index_lo: IVec3,
    pub index_hi: IVec3,
    pub world_offset: DVec3,
    pub active_voxels: u64,
    pub optical_depth_per_voxel: f64,
    pub extinction: f64,
    pub g: f64,
    pub albedo: DVec3,
    pub lights: Vec<LightKind>,
    pub sky: Option<DVec3>,
    /// Emission strength and colour.
    pub emission: Option<(f64, DVec3)>,
    pub footprint_voxels: f64,
    /// The footprint the camera as printed gives at the look-at point, in voxels.
    pub footprint_achieved: f64,
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    /// Whether the image frames the whole volume (else a part of it, zoomed in).
    pub whole: bool,
}

impl Draw {
    /// One line a person reads to understand a failing seed.
    pub fn describe(&self) -> String {
        let mut s = format!("seed {}: ", self.seed);
        let shapes: Vec<&str> = self.shapes.iter().map(|k| k.name()).collect();
        let e = self.voxel_edges;
        let lattice = match (self.rotated, self.sheared) {
            (false, false) => "axis-aligned",
            (true, false) => "rotated",
            (false, true) => "sheared",
            (true, true) => "rotated+sheared",
        };
        let _ = write!(
            s,
            "{} ({}k voxels); voxels {:.3}x{:.3}x{:.3} (1:{:.2}) {lattice}, indices from {},{},{}, offset {:.0e}; tau/voxel {:.3}, g {:.2}, albedo {:.3},{:.3},{:.3}; ",
            shapes.join("+"),
            (self.active_voxels as f64 / 1000.0).round(),
            e.x,
            e.y,
            e.z,
            e.max_element() / e.min_element(),
            self.index_lo.x,
            self.index_lo.y,
            self.index_lo.z,
            self.world_offset.abs().max_element(),
            self.optical_depth_per_voxel,
            self.g,
            self.albedo.x,
            self.albedo.y,
            self.albedo.z,
        );
        let mut lights: Vec<String> = self.lights.iter().map(|k| k.name().to_string()).collect();
        if let Some(sky) = self.sky {
            lights.push(format!("sky {:.2}", sky.element_sum() / 3.0));
        }
        if let Some((strength, _)) = self.emission {
            lights.push(format!("emission {strength:.3}"));
        }
        let _ = write!(
            s,
            "{}; footprint {:.2} voxels, {}x{} fov {:.1}{}",
            lights.join(" + "),
            self.footprint_voxels,
            self.width,
            self.height,
            self.fov_deg,
            if self.whole { "" } else { " (part)" }
        );
        s
    }
}

/// The streams: one per property, so that each is drawn independently of the others.
#[derive(Clone, Copy)]
#[repr(u64)]
enum Stream {
    Shape = 1,
    ShapeParams,
    Voxels,
    Transform,
    Indices,
    Offset,
    Size,
    Medium,
    Albedo,
    Lights,
    Sky,
    Emission,
    Camera,
    Footprint,
    Noise,
}

/// Draws of one property.
struct Draws(Rng);

impl Draws {
    fn new(seed: u64, stream: Stream) -> Draws {
        // The domain keeps these streams apart from any other use of the same seed.
        Draws(Rng::with_domain(seed, stream as u64, 0x5ce9e))
    }
    fn unit(&mut self) -> f64 {
        self.0.next_f64()
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
    fn index(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n - 1)
    }
    fn unit_vector(&mut self) -> DVec3 {
        let z = self.uniform(-1.0, 1.0);
        let phi = self.uniform(0.0, 2.0 * PI);
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
    fn in_ball(&mut self, radius: f64) -> DVec3 {
        self.unit_vector() * radius * self.unit().cbrt()
    }
    /// `dir` turned by `angle` radians toward a random perpendicular.
    fn jitter(&mut self, dir: DVec3, angle: f64) -> DVec3 {
        let (a, b) = dir.any_orthonormal_pair();
        let phi = self.uniform(0.0, 2.0 * PI);
        (dir * angle.cos() + (a * phi.cos() + b * phi.sin()) * angle.sin()).normalize()
    }
}

/// One shape's density in the box's normalised coordinates, about 0..1 inside it.
#[derive(Clone)]
enum Shape {
    Lumps { radii: DVec3, frequency: f64, amplitude: f64, fbm: Fbm },
    Shell { radius: f64, thickness: f64, frequency: f64, fbm: Fbm },
    Layer { tilt: f64, wave: f64, wave_frequency: f64, half: f64, frequency: f64, fbm: Fbm },
    Clumps { blobs: Vec<(DVec3, f64, f64)> },
}

impl Shape {
    fn draw(kind: ShapeKind, d: &mut Draws, noise_seed: u32) -> Shape {
        let fbm = Fbm::new(2 + d.index(3) as u32, noise_seed);
        match kind {
            ShapeKind::Lumps => Shape::Lumps {
                radii: DVec3::new(d.uniform(0.6, 1.0), d.uniform(0.6, 1.0), d.uniform(0.6, 1.0)),
                frequency: d.uniform(1.5, 5.0),
                amplitude: d.uniform(0.3, 0.9),
                fbm,
            },
            ShapeKind::Shell => Shape::Shell { radius: d.uniform(0.45, 0.8), thickness: d.log_uniform(0.04, 0.2), frequency: d.uniform(1.5, 5.0), fbm },
            ShapeKind::Layer => Shape::Layer {
                tilt: d.uniform(-0.3, 0.3),
                wave: d.uniform(0.0, 0.15),
                wave_frequency: d.uniform(1.0, 5.0),
                half: d.log_uniform(0.06, 0.4),
                frequency: d.uniform(2.0, 6.0),
                fbm,
            },
            ShapeKind::Clumps => {
                let n = 8 + d.index(120);
                let blobs = (0..n).map(|_| (d.in_ball(0.8), d.log_uniform(0.04, 0.25), d.uniform(0.3, 1.0))).collect();
                Shape::Clumps { blobs }
            }
        }
    }

    fn eval(&self, u: DVec3) -> f64 {
        match self {
            Shape::Lumps { radii, frequency, amplitude, fbm } => {
                let e = 1.0 - (u / *radii).length_squared();
                if e < -amplitude {
                    return 0.0;
                }
                (e + amplitude * fbm.eval(u * *frequency) as f64).max(0.0)
            }
            Shape::Shell { radius, thickness, frequency, fbm } => {
                let s = (u.length() - radius) / thickness;
                if s.abs() >= 1.0 {
                    return 0.0;
                }
                (1.0 - s * s) * (1.0 + 0.6 * fbm.eval(u * *frequency) as f64).max(0.0)
            }
            Shape::Layer { tilt, wave, wave_frequency, half, frequency, fbm } => {
                let mid = tilt * u.x + wave * (wave_frequency * u.y).sin();
                let s = (u.z - mid) / half;
                // Thinning toward the edges, as an anvil or a sheet does.
                let edge = (1.0 - u.x.powi(4)).max(0.0) * (1.0 - u.y.powi(4)).max(0.0);
                if s.abs() >= 1.0 || edge <= 0.0 {
                    return 0.0;
                }
                (1.0 - s * s) * edge * (1.0 + 0.6 * fbm.eval(u * *frequency) as f64).max(0.0)
            }
            Shape::Clumps { blobs } => blobs
                .iter()
                .map(|&(c, r, w)| {
                    let q = (u - c).length_squared() / (r * r);
                    if q >= 1.0 {
                        0.0
                    } else {
                        w * (1.0 - q) * (1.0 - q)
                    }
                })
                .sum(),
        }
    }
}

/// The scene's density: one shape, or two summed.
fn density_at(shapes: &[Shape], u: DVec3) -> f64 {
    if u.abs().max_element() > 1.0 {
        return 0.0;
    }
    shapes.iter().map(|s| s.eval(u)).sum()
}

/// Options that do not change what is drawn, only how big it is made.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Most pixels in the image (width x height).
    pub max_pixels: u32,
    /// Scales the voxel count (1 = as drawn; the tests build many scenes at a fraction).
    pub voxel_scale: f64,
}

impl Default for Options {
    fn default() -> Options {
        Options { max_pixels: MAX_PIXELS, voxel_scale: 1.0 }
    }
}

/// The scene of `seed`.
pub fn scene(seed: u64, options: Options) -> anyhow::Result<RandomScene> {
    // Shape: one of four, or (a third of the time) two different ones summed.
    let mut d = Draws::new(seed, Stream::Shape);
    let first = ShapeKind::ALL[d.index(4)];
    let mut kinds = vec![first];
    if d.chance(1.0 / 3.0) {
        let second = ShapeKind::ALL[(first as usize + 1 + d.index(3)) % 4];
        kinds.push(second);
    }
    let mut d = Draws::new(seed, Stream::ShapeParams);
    let noise_seed = Draws::new(seed, Stream::Noise).0.next_u32();
    let shapes: Vec<Shape> = kinds.iter().enumerate().map(|(i, &k)| Shape::draw(k, &mut d, noise_seed.wrapping_add(17 * i as u32))).collect();

    // The shape's fill of its box, by sampling, to size the box for the drawn voxel count.
    let mut d = Draws::new(seed, Stream::Size);
    let target = d.log_uniform(ACTIVE_VOXELS.0, ACTIVE_VOXELS.1) * options.voxel_scale;
    let samples = 2000;
    let filled = (0..samples).filter(|_| density_at(&shapes, DVec3::new(d.uniform(-1.0, 1.0), d.uniform(-1.0, 1.0), d.uniform(-1.0, 1.0))) > 0.0).count();
    let fill_fraction = (filled.max(4) as f64 / samples as f64).max(0.02);
    // Box voxels, capped so a sparse shape's box stays quick to fill.
    let box_voxels = (target / fill_fraction).min(2.0e6 * options.voxel_scale.max(0.01));
    let aspect = DVec3::new(d.uniform(-0.6, 0.6).exp2(), d.uniform(-0.6, 0.6).exp2(), d.uniform(-0.6, 0.6).exp2());
    let side = (box_voxels / aspect.element_product()).cbrt();
    let dims = (aspect * side).round().max(DVec3::splat(8.0)).as_ivec3();

    // Voxel edges: a scale, then each axis up to 2.5 times it; a third of scenes cubic.
    let mut d = Draws::new(seed, Stream::Voxels);
    let base = d.log_uniform(0.005, 0.2);
    let edges = if d.chance(1.0 / 3.0) {
        DVec3::splat(base)
    } else {
        DVec3::new(d.log_uniform(1.0, ANISOTROPY), d.log_uniform(1.0, ANISOTROPY), d.log_uniform(1.0, ANISOTROPY)) * base
    };

    // Transform: axis-aligned, rotated, sheared, or both.
    let mut d = Draws::new(seed, Stream::Transform);
    let kind = d.index(4);
    let (rotated, sheared) = (kind & 1 == 1, kind & 2 == 2);
    let rotation = if rotated { DQuat::from_axis_angle(d.unit_vector(), d.uniform(0.2, PI)) } else { DQuat::IDENTITY };
    let shear = if sheared {
        // Upper triangular: x' = x + a y + b z, y' = y + c z.
        let (a, b, c) = (d.uniform(-0.4, 0.4), d.uniform(-0.4, 0.4), d.uniform(-0.4, 0.4));
        DMat3::from_cols(DVec3::X, DVec3::new(a, 1.0, 0.0), DVec3::new(b, c, 1.0))
    } else {
        DMat3::IDENTITY
    };
    let linear = DMat3::from_quat(rotation) * shear * DMat3::from_diagonal(edges);

    // The index box: from 1.5 boxes below zero to half a box above.
    let mut d = Draws::new(seed, Stream::Indices);
    let lo = IVec3::new(
        (d.uniform(-1.5, 0.5) * dims.x as f64).round() as i32,
        (d.uniform(-1.5, 0.5) * dims.y as f64).round() as i32,
        (d.uniform(-1.5, 0.5) * dims.z as f64).round() as i32,
    );
    let hi = lo + dims - IVec3::ONE;
    let centre_index = (lo + hi).as_dvec3() * 0.5;
    let half_dims = (hi - lo).as_dvec3() * 0.5;

    // World offset of the box's centre: none a quarter of the time, else up to 1e6 per axis.
    let mut d = Draws::new(seed, Stream::Offset);
    let offset = if d.chance(0.25) {
        DVec3::ZERO
    } else {
        let mut axis = || {
            let sign = if d.chance(0.5) { -1.0 } else { 1.0 };
            sign * d.log_uniform(1.0, WORLD_OFFSET_MAX)
        };
        DVec3::new(axis(), axis(), axis())
    };
    let affine = DAffine3::from_mat3_translation(linear, offset - linear * centre_index);
    // A rotation, a bounded shear and positive edges make no singular matrix; the error is
    // for a change that breaks that.
    let transform = Transform::new(affine).map_err(|e| anyhow::anyhow!("seed {seed}: {e}"))?;

    let normalised = |ijk: IVec3| (ijk.as_dvec3() - centre_index) / half_dims.max(DVec3::ONE);
    let density = fill(transform, lo, hi, |ijk| density_at(&shapes, normalised(ijk)));
    let (mut sum, mut count) = (0.0f64, 0u64);
    for brick in density.bricks() {
        for (i, &v) in brick.values.iter().enumerate() {
            if brick.is_active(i) {
                sum += v as f64;
                count += 1;
            }
        }
    }
    let mean_density = if count > 0 { sum / count as f64 } else { 1.0 };

    // Medium.
    let mut d = Draws::new(seed, Stream::Medium);
    let tau = d.log_uniform(OPTICAL_DEPTH_PER_VOXEL.0, OPTICAL_DEPTH_PER_VOXEL.1);
    let voxel_edge = transform.voxel_volume().cbrt();
    let extinction = tau / (mean_density * voxel_edge);
    let g = d.uniform(G.0, G.1);
    let mut d = Draws::new(seed, Stream::Albedo);
    // A third of the albedos grey, the rest coloured.
    let grey = d.chance(0.3);
    let mut albedo_channel = || 1.0 - d.log_uniform(1.0 - ALBEDO.1, 1.0 - ALBEDO.0);
    let channels = [albedo_channel(), albedo_channel(), albedo_channel()];
    let albedo = if grey { DVec3::splat(channels[0]) } else { DVec3::from_array(channels) };

    // Where the camera looks: the active voxel nearest the box's centre among the denser
    // half, so that even a hollow shell or sparse clumps put the volume in a zoomed-in view.
    let look_ijk = nearest_dense(&density, centre_index, mean_density).unwrap_or(centre_index.round().as_ivec3());
    let target = transform.to_world(look_ijk.as_dvec3());
    let corners: Vec<DVec3> = (0..8).map(|c| IVec3::new(if c & 1 == 0 { lo.x } else { hi.x + 1 }, if c & 2 == 0 { lo.y } else { hi.y + 1 }, if c & 4 == 0 { lo.z } else { hi.z + 1 })).map(|c| transform.to_world(c.as_dvec3())).collect();
    let box_centre = transform.to_world(centre_index);
    let radius = corners.iter().map(|c| (*c - box_centre).length()).fold(0.0, f64::max);
    let reach = corners.iter().map(|c| (*c - target).length()).fold(0.0, f64::max);

    let mut d = Draws::new(seed, Stream::Camera);
    let azimuth = d.uniform(0.0, 2.0 * PI);
    let elevation = d.uniform(-30.0, 60.0).to_radians();
    // The direction the camera looks (eye to target).
    let view = DVec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), -elevation.sin());
    let distance = reach * d.uniform(1.5, 5.0);
    let eye = target - view * distance;
    let aspects = [1.0, 4.0 / 3.0, 1.5, 16.0 / 9.0, 0.75];
    let aspect = aspects[d.index(aspects.len())];

    let mut d = Draws::new(seed, Stream::Footprint);
    let footprint_voxels = d.log_uniform(FOOTPRINT_VOXELS.0, FOOTPRINT_VOXELS.1);
    let footprint = footprint_voxels * voxel_edge;
    // Pixels across the volume's bounding sphere and a margin; fewer where the budget says,
    // then the camera sees a part of it.
    let needed = (2.2 * radius / footprint).ceil();
    let budget = (options.max_pixels.max(MIN_SIDE * MIN_SIDE) as f64 * aspect).sqrt().floor();
    let width = needed.min(budget).max(MIN_SIDE as f64) as u32;
    let height = ((width as f64 / aspect).round() as u32).max(MIN_SIDE).min((options.max_pixels.max(MIN_SIDE * MIN_SIDE) / width).max(MIN_SIDE));
    let fov = 2.0 * (0.5 * width as f64 * footprint / distance).atan().to_degrees();
    let footprint_achieved = 2.0 * distance * (0.5 * fov.to_radians()).tan() / width as f64 / voxel_edge;
    let whole = needed <= budget;

    // Lights: a key light, perhaps a second, perhaps the sky.
    let mut d = Draws::new(seed, Stream::Lights);
    let kinds_all = [LightKind::Overhead, LightKind::Grazing, LightKind::BehindCamera, LightKind::Backlit, LightKind::Point];
    // Six keys: the five lights and the sky alone.
    let key = d.index(6);
    let mut light_kinds = Vec::new();
    if key < 5 {
        light_kinds.push(kinds_all[key]);
    }
    if d.chance(0.4) {
        light_kinds.push(kinds_all[d.index(5)]);
    }
    let mut light_flags = Vec::new();
    for &k in &light_kinds {
        let level = d.uniform(1.0, 4.0);
        let tint = DVec3::new(d.uniform(0.85, 1.15), d.uniform(0.85, 1.15), d.uniform(0.85, 1.15)) * level;
        let sun = |dir: DVec3| format!("--sun dir={},{},{},irradiance={}", fmt(dir.x), fmt(dir.y), fmt(dir.z), rgb(tint));
        light_flags.push(match k {
            LightKind::Overhead => {
                let angle = d.uniform(0.0, 20.0).to_radians();
                sun(d.jitter(DVec3::NEG_Z, angle))
            }
            LightKind::Grazing => {
                let (el, az) = (d.uniform(2.0, 12.0).to_radians(), d.uniform(0.0, 2.0 * PI));
                sun(DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin()))
            }
            LightKind::BehindCamera => {
                let angle = d.uniform(0.0, 40.0).to_radians();
                sun(d.jitter(view, angle))
            }
            // Travelling toward the camera, a little off the line of sight: a rim.
            LightKind::Backlit => {
                let angle = d.uniform(5.0, 35.0).to_radians();
                sun(d.jitter(-view, angle))
            }
            LightKind::Point => {
                let r = radius * d.uniform(1.2, 3.0);
                let pos = box_centre + d.unit_vector() * r;
                format!("--point pos={},{},{},intensity={}", fmt(pos.x), fmt(pos.y), fmt(pos.z), rgb(tint * r * r))
            }
        });
    }
    let mut d = Draws::new(seed, Stream::Sky);
    let sky = (key == 5 || d.chance(0.3)).then(|| DVec3::new(d.uniform(0.15, 1.0), d.uniform(0.15, 1.0), d.uniform(0.15, 1.0)));

    // Emission: a hot blob about the look-at point, inside the density.
    let mut d = Draws::new(seed, Stream::Emission);
    let emission_draw = d.chance(0.25).then(|| {
        let strength = d.log_uniform(0.03, 0.3) * extinction * mean_density;
        let color = DVec3::new(1.0, d.uniform(0.3, 1.0), d.uniform(0.05, 0.6));
        let centre = normalised(look_ijk);
        let r = d.uniform(0.2, 0.6);
        (strength, color, centre, r)
    });
    let emission = emission_draw.map(|(_, _, centre, r)| {
        let fbm = Fbm::new(3, noise_seed.wrapping_add(101));
        fill(transform, lo, hi, |ijk| {
            let u = normalised(ijk);
            if density_at(&shapes, u) <= 0.0 {
                return 0.0;
            }
            let q = (u - centre).length_squared() / (r * r);
            // The look-at voxel is in the density and at the blob's centre, so it is never empty.
            (1.0 - q).max(0.0) * (0.6 + 0.4 * fbm.eval(u * 4.0) as f64).max(0.05)
        })
    });

    let mut medium = format!("--extinction {} --g {} --albedo {}", fmt(extinction), fmt(g), rgb(albedo));
    for l in &light_flags {
        medium += " ";
        medium += l;
    }
    if let Some(sky) = sky {
        medium += &format!(" --sky {}", rgb(sky));
    }
    if let Some((strength, color, _, _)) = emission_draw {
        medium += &format!(" --emission-grid {EMISSION_GRID} --emission-strength {} --emission-color {}", fmt(strength), rgb(color));
    }
    let camera = format!(
        "--eye {},{},{} --look-at {},{},{} --up 0,0,1 --fov {} --width {width} --height {height}",
        fmt(eye.x),
        fmt(eye.y),
        fmt(eye.z),
        fmt(target.x),
        fmt(target.y),
        fmt(target.z),
        fmt(fov)
    );
    let draw = Draw {
        seed,
        shapes: kinds,
        voxel_edges: edges,
        rotated,
        sheared,
        index_lo: lo,
        index_hi: hi,
        world_offset: offset,
        active_voxels: density.active_voxel_count(),
        optical_depth_per_voxel: tau,
        extinction,
        g,
        albedo,
        lights: light_kinds,
        sky,
        emission: emission_draw.map(|(s, c, _, _)| (s, c)),
        footprint_voxels,
        footprint_achieved,
        width,
        height,
        fov_deg: fov,
        whole,
    };
    Ok(RandomScene { scene: Scene { density, medium: words(&medium), camera: words(&camera) }, emission, draw })
}

fn words(s: &str) -> Vec<String> {
    s.split_whitespace().map(String::from).collect()
}

/// A number as the flags take it: enough digits to mean the same scene, no more.
fn fmt(x: f64) -> String {
    let s = format!("{x:.9}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

fn rgb(c: DVec3) -> String {
    format!("{},{},{}", fmt(c.x), fmt(c.y), fmt(c.z))
}

/// The active voxel nearest `centre` (index space) whose density is at least `level`.
fn nearest_dense(density: &Volume<f32>, centre: DVec3, level: f64) -> Option<IVec3> {
    let mut best: Option<(f64, IVec3)> = None;
    for brick in density.bricks() {
        for (i, &v) in brick.values.iter().enumerate() {
            if brick.is_active(i) && v as f64 >= level {
                let ijk = brick.origin + nimbus_volume::brick_local(i);
                let d = (ijk.as_dvec3() - centre).length_squared();
                if best.is_none_or(|(b, _)| d < b) {
                    best = Some((d, ijk));
                }
            }
        }
    }
    best.map(|(_, ijk)| ijk)
}

/// The volume over index box `lo..=hi` with `f(ijk)` where positive and finite.
pub(crate) fn fill(transform: Transform, lo: IVec3, hi: IVec3, f: impl Fn(IVec3) -> f64 + Sync) -> Volume<f32> {
    let b0 = lo.div_euclid(IVec3::splat(8)) * 8;
    let mut origins = Vec::new();
    for z in (b0.z..=hi.z).step_by(8) {
        for y in (b0.y..=hi.y).step_by(8) {
            for x in (b0.x..=hi.x).step_by(8) {
                origins.push(IVec3::new(x, y, z));
            }
        }
    }
    Volume::from_brick_fn(transform, 0.0, &origins, |origin, values| {
        let mut mask: nimbus_volume::BrickMask = [0; 8];
        for (i, v) in values.iter_mut().enumerate() {
            let ijk = origin + nimbus_volume::brick_local(i);
            if ijk.cmplt(lo).any() || ijk.cmpgt(hi).any() {
                continue;
            }
            let d = f(ijk);
            if d > 0.0 && d.is_finite() {
                *v = d as f32;
                mask[i >> 6] |= 1 << (i & 63);
            }
        }
        mask
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn in_range(x: f64, (lo, hi): (f64, f64)) -> bool {
        x >= lo * (1.0 - 1e-9) && x <= hi * (1.0 + 1e-9)
    }

    /// Every seed gives a valid, non-empty scene with its properties in their ranges. Built at
    /// a tenth of the voxels so 200 seeds take seconds (the draws do not depend on the scale).
    #[test]
    fn many_seeds_give_valid_scenes_in_range() {
        let options = Options { voxel_scale: 0.1, ..Options::default() };
        let mut seen_shapes = std::collections::HashSet::new();
        let mut seen_lights = std::collections::HashSet::new();
        let (mut skies, mut emissions, mut parts, mut wholes) = (0, 0, 0, 0);
        let (mut tau_lo, mut tau_hi, mut fp_lo, mut fp_hi) = (false, false, false, false);
        for seed in 0..200u64 {
            let r = scene(seed * 7919 + 3, options).unwrap();
            let d = &r.draw;
            let what = d.describe();
            assert!(r.scene.density.active_voxel_count() > 0, "{what}: empty");
            for brick in r.scene.density.bricks() {
                assert!(brick.values.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}: a non-finite or negative density");
            }
            assert!(in_range(d.optical_depth_per_voxel, OPTICAL_DEPTH_PER_VOXEL), "{what}");
            assert!(d.extinction.is_finite() && d.extinction > 0.0, "{what}");
            assert!(in_range(d.g, G), "{what}");
            assert!(d.albedo.to_array().iter().all(|&a| in_range(a, ALBEDO)), "{what}");
            assert!(in_range(d.footprint_voxels, FOOTPRINT_VOXELS), "{what}");
            assert!((d.footprint_achieved / d.footprint_voxels - 1.0).abs() < 1e-6, "{what}: the camera's footprint {}", d.footprint_achieved);
            assert!(d.voxel_edges.max_element() / d.voxel_edges.min_element() <= ANISOTROPY * (1.0 + 1e-9), "{what}");
            assert!(d.world_offset.abs().max_element() <= WORLD_OFFSET_MAX, "{what}");
            assert!(d.width >= MIN_SIDE && d.height >= MIN_SIDE && d.width * d.height <= options.max_pixels, "{what}");
            assert!(d.fov_deg > 0.0 && d.fov_deg < 120.0, "{what}");
            assert!(!d.lights.is_empty() || d.sky.is_some(), "{what}: no light");
            if d.emission.is_some() {
                let e = r.emission.as_ref().expect("an emission grid with the emission flags");
                assert!(e.active_voxel_count() > 0, "{what}: an empty emission grid");
                emissions += 1;
            }
            // The flags parse as the tools' own parsers read them.
            let medium = r.scene.medium.join(" ");
            for spec in medium.split("--sun ").skip(1).map(|s| s.split_whitespace().next().unwrap_or("")) {
                nimbus_optics::Light::parse_sun(spec).unwrap_or_else(|e| panic!("{what}: {e}"));
            }
            for spec in medium.split("--point ").skip(1).map(|s| s.split_whitespace().next().unwrap_or("")) {
                nimbus_optics::Light::parse_point(spec).unwrap_or_else(|e| panic!("{what}: {e}"));
            }
            let cam = &r.scene.camera;
            let value = |flag: &str| cam.iter().position(|w| w == flag).map(|i| cam[i + 1].clone()).unwrap_or_else(|| panic!("{what}: no {flag}"));
            let v3 = |s: String| -> DVec3 {
                let p: Vec<f64> = s.split(',').map(|x| x.parse().unwrap()).collect();
                DVec3::new(p[0], p[1], p[2])
            };
            let camera = nimbus_optics::Camera::new(v3(value("--eye")), v3(value("--look-at")), DVec3::Z, value("--fov").parse().unwrap(), d.width, d.height);
            assert!(camera.is_ok(), "{what}: {:?}", camera.err());
            seen_shapes.extend(d.shapes.iter().copied());
            seen_lights.extend(d.lights.iter().copied());
            skies += d.sky.is_some() as u32;
            parts += (!d.whole) as u32;
            wholes += d.whole as u32;
            tau_lo |= d.optical_depth_per_voxel < 0.02;
            tau_hi |= d.optical_depth_per_voxel > 5.0;
            fp_lo |= d.footprint_voxels < 0.4;
            fp_hi |= d.footprint_voxels > 2.5;
        }
        // The space is covered: every kind drawn, both ends of the wide ranges reached.
        assert_eq!(seen_shapes.len(), 4);
        assert_eq!(seen_lights.len(), 5);
        assert!(skies > 20 && emissions > 20 && parts > 10 && wholes > 10, "skies {skies}, emissions {emissions}, parts {parts}, wholes {wholes}");
        assert!(tau_lo && tau_hi && fp_lo && fp_hi);
    }

    /// At full size the voxel counts are what a quick bake needs.
    #[test]
    fn full_size_scenes_have_the_drawn_voxel_counts() {
        for seed in [1u64, 2, 3, 4] {
            let r = scene(seed, Options::default()).unwrap();
            let n = r.scene.density.active_voxel_count() as f64;
            assert!(n > 0.3 * ACTIVE_VOXELS.0 && n < 2.0 * ACTIVE_VOXELS.1, "{}: {n} voxels", r.draw.describe());
        }
    }

    #[test]
    fn a_seed_is_a_pure_function() {
        let (a, b) = (scene(42, Options::default()).unwrap(), scene(42, Options::default()).unwrap());
        assert_eq!(a.scene.medium, b.scene.medium);
        assert_eq!(a.scene.camera, b.scene.camera);
        assert_eq!(a.draw.describe(), b.draw.describe());
        assert_eq!(a.scene.density.active_voxel_count(), b.scene.density.active_voxel_count());
        let c = scene(43, Options::default()).unwrap();
        assert_ne!(a.scene.medium, c.scene.medium);
    }
}
