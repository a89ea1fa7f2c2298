//! The environment (design.md section 4): light arriving from infinitely far away in every
//! direction, as Blender's World. Either a uniform sky (`--sky R,G,B`) or an equirectangular
//! HDR map (`--environment FILE.exr`) with Blender's Environment Texture mapping, scaled by a
//! strength and turned about +Z.
//!
//! Directions here are `toward`: unit vectors from a point toward the sky it sees, i.e. the
//! opposite of the direction the light travels (`w_in = -toward`).
//!
//! Blender's mapping (Cycles `direction_to_equirectangular`): u = 0.5 - atan2(y, x) / 2 pi, so
//! the image's centre column looks along +X and +Y is a quarter to its left; the top row is
//! the zenith (+Z), the bottom the nadir. The texture is read with bilinear filtering
//! (Blender's default "Linear"), wrapping in u. `--environment-rotation` is the Z rotation of a
//! Mapping node between Texture Coordinate's Generated output and the texture: the map is read
//! at `R_z(rotation) toward`.
//!
//! Sampling: [`Environment::sample`] draws `toward` in proportion to the map's luminance
//! times sin(theta) (the solid angle of a texel row), piecewise constant over texels, as
//! pbrt-v4's ImageInfiniteLight; a uniform sky draws uniformly over the sphere. Callers
//! combine it with phase-function sampling by multiple importance sampling
//! ([`power_heuristic`]); the texels' pdf covers the bilinear footprint (each texel's weight
//! is the largest luminance of its 3 x 3 neighbourhood), so either strategy alone would be
//! unbiased too.

use std::f32::consts::PI;
use std::fmt;
use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::params::{rgb_text, KeyValues, ParseError};
use crate::sampling::sample_uniform_sphere;

/// Why an environment was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EnvironmentError {
    #[error("the environment map is {width} x {height}; it needs at least 1 x 1 texels and width x height of them")]
    Size { width: u32, height: u32 },
    #[error("the environment map has a non-finite or negative texel at column {column}, row {row}")]
    Texel { column: u32, row: u32 },
    #[error("{name} must be finite and >= 0, got {value}")]
    Value { name: &'static str, value: String },
}

/// A piecewise-constant distribution over `n` equal cells of [0, 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Distribution1D {
    /// The (non-negative) weight of each cell.
    pub func: Vec<f32>,
    /// cdf[i] = sum of func[..i] / total, cdf[n] = 1.
    cdf: Vec<f32>,
    /// The sum of the weights times the cell width: the mean weight.
    pub integral: f32,
}

impl Distribution1D {
    /// All-zero weights sample uniformly (the integral stays 0).
    pub fn new(func: Vec<f32>) -> Distribution1D {
        let n = func.len().max(1);
        let mut cdf = Vec::with_capacity(n + 1);
        let mut sum = 0.0f64;
        cdf.push(0.0);
        for &f in &func {
            sum += f as f64;
            cdf.push(sum as f32);
        }
        let integral = (sum / n as f64) as f32;
        if sum > 0.0 {
            for c in &mut cdf {
                *c = (*c as f64 / sum) as f32;
            }
        } else {
            for (i, c) in cdf.iter_mut().enumerate() {
                *c = i as f32 / n as f32;
            }
        }
        *cdf.last_mut().expect("n >= 1") = 1.0;
        Distribution1D { func, cdf, integral }
    }

    pub fn len(&self) -> usize {
        self.func.len()
    }

    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    /// A point x in [0, 1) drawn from the distribution, its density, and its cell.
    pub fn sample(&self, u: f32) -> (f32, f32, usize) {
        let n = self.func.len();
        // The last cell whose cdf is <= u.
        let i = self.cdf.partition_point(|&c| c <= u).saturating_sub(1).min(n - 1);
        let (lo, hi) = (self.cdf[i], self.cdf[i + 1]);
        let frac = if hi > lo { ((u - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.5 };
        let x = ((i as f32 + frac) / n as f32).min(1.0 - f32::EPSILON / 2.0);
        (x, self.pdf_of_cell(i), i)
    }

    /// The density at a point of cell `i`.
    pub fn pdf_of_cell(&self, i: usize) -> f32 {
        if self.integral > 0.0 {
            self.func[i] / self.integral
        } else {
            1.0
        }
    }
}

/// The power heuristic (beta 2) weight of a sample drawn with density `a` against another
/// strategy of density `b` (Veach 1997).
#[inline]
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && (a2 + b2).is_finite() {
        a2 / (a2 + b2)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// Rec. 709 luminance: the weight an environment's sampling and a path's light lobes follow.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// An equirectangular radiance map, row 0 the top (the zenith), as an EXR stores it.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvironmentMap {
    width: u32,
    height: u32,
    texels: Vec<Vec3>,
    /// Over rows: each row's summed weight.
    rows: Distribution1D,
    /// Within each row, over columns.
    columns: Vec<Distribution1D>,
}

impl EnvironmentMap {
    /// The map of `width` x `height` RGB texels, row-major from the top row.
    pub fn new(width: u32, height: u32, texels: Vec<Vec3>) -> Result<EnvironmentMap, EnvironmentError> {
        if width == 0 || height == 0 || texels.len() != width as usize * height as usize {
            return Err(EnvironmentError::Size { width, height });
        }
        if let Some(bad) = texels.iter().position(|t| !t.is_finite() || t.min_element() < 0.0) {
            return Err(EnvironmentError::Texel { column: bad as u32 % width, row: bad as u32 / width });
        }
        let (w, h) = (width as usize, height as usize);
        let lum: Vec<f32> = texels.iter().map(|&t| luminance(t)).collect();
        let mut columns = Vec::with_capacity(h);
        let mut row_weight = Vec::with_capacity(h);
        for row in 0..h {
            let sin_theta = (PI * (row as f32 + 0.5) / h as f32).sin();
            let func: Vec<f32> = (0..w)
                .map(|col| {
                    // Bilinear filtering spreads a texel over its neighbours: weigh each texel
                    // by the brightest it can be read as.
                    let mut m = 0.0f32;
                    for dr in -1i64..=1 {
                        let r = (row as i64 + dr).clamp(0, h as i64 - 1) as usize;
                        for dc in -1i64..=1 {
                            let c = (col as i64 + dc).rem_euclid(w as i64) as usize;
                            m = m.max(lum[r * w + c]);
                        }
                    }
                    m * sin_theta
                })
                .collect();
            let d = Distribution1D::new(func);
            row_weight.push(d.integral);
            columns.push(d);
        }
        Ok(EnvironmentMap { width, height, texels, rows: Distribution1D::new(row_weight), columns })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    fn texel(&self, col: i64, row: i64) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        let c = col.rem_euclid(w) as usize;
        let r = row.clamp(0, h - 1) as usize;
        self.texels[r * w as usize + c]
    }

    /// Bilinear read at image coordinates `(s, t)` in [0,1]^2, t = 0 the top edge.
    pub fn lookup(&self, s: f32, t: f32) -> Vec3 {
        let x = s * self.width as f32 - 0.5;
        let y = t * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (c, r) = (x0 as i64, y0 as i64);
        let top = self.texel(c, r) * (1.0 - fx) + self.texel(c + 1, r) * fx;
        let bottom = self.texel(c, r + 1) * (1.0 - fx) + self.texel(c + 1, r + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The mean radiance over the sphere (each texel weighted by its solid angle).
    pub fn mean(&self) -> Vec3 {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut sum = glam::DVec3::ZERO;
        let mut weight = 0.0f64;
        for row in 0..h {
            // The exact solid angle of the row's band: 2 pi (cos theta0 - cos theta1) / w.
            let t0 = std::f64::consts::PI * row as f64 / h as f64;
            let t1 = std::f64::consts::PI * (row + 1) as f64 / h as f64;
            let band = t0.cos() - t1.cos();
            for col in 0..w {
                sum += self.texels[row * w + col].as_dvec3() * band;
                weight += band;
            }
        }
        (sum / weight).as_vec3()
    }
}

/// Floats of [`Environment::gpu_words`]' header.
pub const GPU_ENVIRONMENT_HEADER: usize = 8;

impl Environment {
    /// The environment as one f32 array for `shaders/environment.wgsl`: a header (kind 0 none
    /// or black, 1 uniform, 2 map; width, height, strength, cos and sin of the rotation, then
    /// for a uniform sky its RGB at 5..8), then for a map its texels (RGB, row-major from the
    /// top), the rows' cdf (height + 1) and pdfs (height), and per row the columns' cdf
    /// (width + 1) and pdfs (width): what [`Environment::sample`] and [`Environment::pdf`]
    /// read, so the shader draws what the CPU draws.
    pub fn gpu_words(environment: Option<&Environment>) -> Vec<f32> {
        let mut w = vec![0.0f32; GPU_ENVIRONMENT_HEADER];
        match environment {
            Some(e) if e.is_black() => {}
            None => {}
            Some(Environment::Uniform(c)) => {
                w[0] = 1.0;
                w[5..8].copy_from_slice(&c.to_array());
            }
            Some(Environment::Map { map, strength, rotation, .. }) => {
                let (c, s) = Self::turn(*rotation);
                w[..5].copy_from_slice(&[2.0, map.width as f32, map.height as f32, *strength, c]);
                w[5] = s;
                w.extend(map.texels.iter().flat_map(|t| t.to_array()));
                w.extend_from_slice(&map.rows.cdf);
                w.extend((0..map.rows.len()).map(|i| map.rows.pdf_of_cell(i)));
                for row in &map.columns {
                    w.extend_from_slice(&row.cdf);
                }
                for row in &map.columns {
                    w.extend((0..row.len()).map(|i| row.pdf_of_cell(i)));
                }
            }
        }
        w
    }
}

/// Image coordinates `(s, t)` (t = 0 at the top) of the map-frame direction `d`.
#[inline]
fn direction_to_image(d: Vec3) -> Vec2 {
    let s = 0.5 - d.y.atan2(d.x) / (2.0 * PI);
    let t = d.z.clamp(-1.0, 1.0).acos() / PI;
    Vec2::new(s.rem_euclid(1.0), t)
}

/// The map-frame direction at image coordinates `(s, t)`, and sin(theta).
#[inline]
fn image_to_direction(s: f32, t: f32) -> (Vec3, f32) {
    let theta = PI * t;
    let phi = PI - 2.0 * PI * s;
    let (sin_t, cos_t) = theta.sin_cos();
    (Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t), sin_t)
}

/// What lights the scene from infinitely far away.
#[derive(Debug, Clone, PartialEq)]
pub enum Environment {
    /// The same radiance from every direction (`--sky`).
    Uniform(Vec3),
    /// An equirectangular map, times `strength`, turned by `rotation` degrees about +Z.
    /// `path` is where it was read from: the pipeline records it and later tools read it again.
    Map { map: Arc<EnvironmentMap>, path: String, strength: f32, rotation: f32 },
}

/// A direction drawn from the environment: `toward` the sky, the radiance arriving from
/// there, and the solid-angle density it was drawn with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvironmentSample {
    pub toward: Vec3,
    pub radiance: Vec3,
    pub pdf: f32,
}

impl Environment {
    /// A uniform sky; refuses non-finite or negative radiance.
    pub fn uniform(radiance: Vec3) -> Result<Environment, EnvironmentError> {
        if !radiance.is_finite() || radiance.min_element() < 0.0 {
            return Err(EnvironmentError::Value { name: "sky radiance", value: rgb_text(radiance) });
        }
        Ok(Environment::Uniform(radiance))
    }

    /// A map; refuses a non-finite or negative strength and a non-finite rotation.
    pub fn map(map: EnvironmentMap, path: impl Into<String>, strength: f32, rotation: f32) -> Result<Environment, EnvironmentError> {
        if !strength.is_finite() || strength < 0.0 {
            return Err(EnvironmentError::Value { name: "environment strength", value: strength.to_string() });
        }
        if !rotation.is_finite() {
            return Err(EnvironmentError::Value { name: "environment rotation", value: rotation.to_string() });
        }
        Ok(Environment::Map { map: Arc::new(map), path: path.into(), strength, rotation })
    }

    /// Whether next-event estimation toward it pays: not for a uniform sky, whose radiance
    /// the phase function's own sampling follows as well as any draw can (the integrand is
    /// p T with L constant), so its light enters only where phase-sampled flights escape; a
    /// shadow ray per collision toward a uniform direction added the same error at 2.2x the
    /// paths' time on the bundled plume (1.33% against 1.29%, 63 against 28 CPU s).
    pub fn wants_next_event(&self) -> bool {
        matches!(self, Environment::Map { .. })
    }

    /// Whether it sends no light at all (then no stage spends anything on it).
    pub fn is_black(&self) -> bool {
        match self {
            Environment::Uniform(c) => c.max_element() <= 0.0,
            Environment::Map { map, strength, .. } => *strength <= 0.0 || map.rows.integral <= 0.0,
        }
    }

    /// The rotation as (cos, sin) of the map frame relative to the world.
    fn turn(rotation: f32) -> (f32, f32) {
        let (s, c) = rotation.to_radians().sin_cos();
        (c, s)
    }

    /// A world direction in the map's frame: `R_z(rotation) d` (a Mapping node's Z rotation).
    fn to_map_frame(rotation: f32, d: Vec3) -> Vec3 {
        let (c, s) = Self::turn(rotation);
        Vec3::new(c * d.x - s * d.y, s * d.x + c * d.y, d.z)
    }

    /// [`Environment::to_map_frame`]'s inverse.
    fn from_map_frame(rotation: f32, d: Vec3) -> Vec3 {
        let (c, s) = Self::turn(rotation);
        Vec3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z)
    }

    /// Radiance arriving at any point from direction `toward` (unit, world).
    pub fn radiance(&self, toward: Vec3) -> Vec3 {
        match self {
            Environment::Uniform(c) => *c,
            Environment::Map { map, strength, rotation, .. } => {
                let st = direction_to_image(Self::to_map_frame(*rotation, toward));
                map.lookup(st.x, st.y) * *strength
            }
        }
    }

    /// Draws a direction (see the module doc).
    pub fn sample(&self, u: Vec2) -> EnvironmentSample {
        match self {
            Environment::Uniform(c) => EnvironmentSample { toward: sample_uniform_sphere(u), radiance: *c, pdf: 1.0 / (4.0 * PI) },
            Environment::Map { map, strength, rotation, .. } => {
                let (t, pdf_row, row) = map.rows.sample(u.y);
                let (s, pdf_col, _) = map.columns[row].sample(u.x);
                let (d, _) = image_to_direction(s, t);
                // sin(theta) as pdf() finds it from the direction, so the two agree.
                let sin_theta = (1.0 - d.z * d.z).max(0.0).sqrt();
                if sin_theta <= 0.0 {
                    return EnvironmentSample { toward: Vec3::Z, radiance: Vec3::ZERO, pdf: 0.0 };
                }
                let pdf = pdf_row * pdf_col / (2.0 * PI * PI * sin_theta);
                let toward = Self::from_map_frame(*rotation, d);
                EnvironmentSample { toward, radiance: map.lookup(s, t) * *strength, pdf }
            }
        }
    }

    /// The density [`Environment::sample`] draws `toward` with.
    pub fn pdf(&self, toward: Vec3) -> f32 {
        match self {
            Environment::Uniform(_) => 1.0 / (4.0 * PI),
            Environment::Map { map, rotation, .. } => {
                let d = Self::to_map_frame(*rotation, toward);
                let st = direction_to_image(d);
                let sin_theta = (1.0 - d.z * d.z).max(0.0).sqrt();
                if sin_theta <= 0.0 {
                    return 0.0;
                }
                let row = ((st.y * map.height as f32) as usize).min(map.height as usize - 1);
                let col = ((st.x * map.width as f32) as usize).min(map.width as usize - 1);
                map.rows.pdf_of_cell(row) * map.columns[row].pdf_of_cell(col) / (2.0 * PI * PI * sin_theta)
            }
        }
    }

    /// The mean radiance over the sphere: the power it sends through a disc of area A facing
    /// any way, summed over directions, is pi A times it (what a photon tracer emits).
    pub fn mean_radiance(&self) -> Vec3 {
        match self {
            Environment::Uniform(c) => *c,
            Environment::Map { map, strength, .. } => map.mean() * *strength,
        }
    }

    /// What metadata records of it ([`Environment::parse_record`] reads it back).
    pub fn record(&self) -> EnvironmentRecord {
        match self {
            Environment::Uniform(c) => EnvironmentRecord::Uniform(*c),
            Environment::Map { path, strength, rotation, .. } => EnvironmentRecord::Map { path: path.clone(), strength: *strength, rotation: *rotation },
        }
    }

    /// The text form for metadata and `-v`: `sky=R,G,B`, or
    /// `map=PATH,strength=S,rotation=DEG`. [`Environment::parse_record`] reads it back
    /// (a map is then read again from PATH by the caller).
    pub fn describe(&self) -> String {
        self.to_string()
    }
}

impl fmt::Display for Environment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Environment::Uniform(c) => write!(f, "sky={}", rgb_text(*c)),
            Environment::Map { path, strength, rotation, .. } => write!(f, "map={path},strength={strength},rotation={rotation}"),
        }
    }
}

/// An environment as recorded in metadata, before a map is read.
#[derive(Debug, Clone, PartialEq)]
pub enum EnvironmentRecord {
    Uniform(Vec3),
    Map { path: String, strength: f32, rotation: f32 },
}

impl Environment {
    /// Reads [`Environment::describe`]'s text (`none` or empty is no environment).
    pub fn parse_record(s: &str) -> Result<Option<EnvironmentRecord>, ParseError> {
        let t = s.trim();
        if t.is_empty() || t == "none" {
            return Ok(None);
        }
        if let Some(rest) = t.strip_prefix("map=") {
            // The path may hold commas: the strength and rotation are the last two fields.
            let err = |reason: &str| ParseError { what: "environment", input: s.to_string(), reason: reason.to_string() };
            let (path, tail) = rest.rsplit_once(",strength=").ok_or_else(|| err("expected map=PATH,strength=S,rotation=DEG"))?;
            let (strength, rotation) = tail.split_once(",rotation=").ok_or_else(|| err("expected ,rotation=DEG"))?;
            let strength = strength.parse().map_err(|_| err("strength is not a number"))?;
            let rotation = rotation.parse().map_err(|_| err("rotation is not a number"))?;
            return Ok(Some(EnvironmentRecord::Map { path: path.to_string(), strength, rotation }));
        }
        let mut kv = KeyValues::parse("environment", t)?;
        let sky = kv.rgb("sky")?;
        kv.finish("sky")?;
        Ok(sky.map(EnvironmentRecord::Uniform))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng_points(n: usize) -> impl Iterator<Item = Vec2> {
        // A (2,3) Halton sequence: even coverage without a dependency.
        (1..=n).map(|i| {
            let radical = |mut i: usize, b: usize| {
                let (mut f, mut r) = (1.0f64, 0.0f64);
                while i > 0 {
                    f /= b as f64;
                    r += f * (i % b) as f64;
                    i /= b;
                }
                r as f32
            };
            Vec2::new(radical(i, 2), radical(i, 3))
        })
    }

    /// A map with a bright patch, a gradient and a black band.
    fn test_map() -> EnvironmentMap {
        let (w, h) = (16u32, 8u32);
        let texels = (0..w * h)
            .map(|i| {
                let (c, r) = (i % w, i / w);
                let base = Vec3::new(0.2 + 0.05 * c as f32, 0.1, 0.3 + 0.1 * r as f32);
                if r == 6 {
                    Vec3::ZERO
                } else if (3..5).contains(&c) && r == 2 {
                    base + Vec3::splat(40.0)
                } else {
                    base
                }
            })
            .collect();
        EnvironmentMap::new(w, h, texels).unwrap()
    }

    #[test]
    fn blenders_mapping_puts_plus_x_at_the_centre_and_the_zenith_on_top() {
        let st = direction_to_image(Vec3::X);
        assert!((st.x - 0.5).abs() < 1e-6 && (st.y - 0.5).abs() < 1e-6);
        assert!((direction_to_image(Vec3::Y).x - 0.25).abs() < 1e-6);
        assert!((direction_to_image(Vec3::NEG_Y).x - 0.75).abs() < 1e-6);
        assert!(direction_to_image(Vec3::Z).y.abs() < 1e-6);
        assert!((direction_to_image(Vec3::NEG_Z).y - 1.0).abs() < 1e-6);
        for p in rng_points(200) {
            let (d, _) = image_to_direction(p.x, p.y);
            let back = direction_to_image(d);
            assert!((back - p).abs().max_element() < 1e-4, "{p} -> {d} -> {back}");
        }
    }

    #[test]
    fn rotation_turns_the_map_as_a_mapping_node_does() {
        // A map bright only in the column looking along +X.
        let (w, h) = (64u32, 32u32);
        let texels = (0..w * h).map(|i| if i % w == w / 2 { Vec3::ONE } else { Vec3::ZERO }).collect();
        let map = EnvironmentMap::new(w, h, texels).unwrap();
        let plain = Environment::map(map.clone(), "m.exr", 1.0, 0.0).unwrap();
        let turned = Environment::map(map, "m.exr", 1.0, 90.0).unwrap();
        assert!(plain.radiance(Vec3::X).x > 0.4);
        // Read at R_z(90) toward: +X is now seen looking along -Y.
        assert!(turned.radiance(Vec3::NEG_Y).x > 0.4, "{}", turned.radiance(Vec3::NEG_Y));
        assert!(turned.radiance(Vec3::X).x < 1e-6);
        // Sampling finds the bright column at its turned place.
        let s = turned.sample(Vec2::new(0.3, 0.5));
        assert!(s.toward.dot(Vec3::NEG_Y) > 0.9, "{}", s.toward);
    }

    #[test]
    fn sampling_is_consistent_with_its_pdf_and_integrates_the_map() {
        for rotation in [0.0, 37.0] {
            let env = Environment::map(test_map(), "t.exr", 2.0, rotation).unwrap();
            let n = 200_000;
            // E[f / pdf] over sampled directions = the integral of f over the sphere, for f
            // = radiance: 4 pi mean.
            let mut sum = glam::DVec3::ZERO;
            for u in rng_points(n) {
                let s = env.sample(u);
                assert!(s.pdf > 0.0, "sampled a direction of zero density");
                let pdf = env.pdf(s.toward);
                assert!((pdf - s.pdf).abs() <= 1e-3 * s.pdf, "pdf {pdf} vs sampled {}", s.pdf);
                assert!((env.radiance(s.toward) - s.radiance).abs().max_element() <= 1e-3 * (1.0 + s.radiance.max_element()));
                sum += (s.radiance / s.pdf).as_dvec3();
            }
            let estimate = sum / n as f64;
            let exact = env.mean_radiance().as_dvec3() * 4.0 * std::f64::consts::PI;
            // The bilinear read differs from the texel mean only at the patch's edges.
            let rel = ((estimate - exact) / exact).abs().max_element();
            assert!(rel < 0.02, "rotation {rotation}: {estimate} vs {exact}");
            // The pdf integrates to one: E over uniform directions of pdf * 4 pi.
            let mut total = 0.0f64;
            for u in rng_points(n) {
                total += env.pdf(sample_uniform_sphere(u)) as f64 * 4.0 * std::f64::consts::PI;
            }
            assert!((total / n as f64 - 1.0).abs() < 0.01, "pdf integral {}", total / n as f64);
        }
    }

    #[test]
    fn a_uniform_sky_samples_the_sphere_and_records_round_trip() {
        let env = Environment::uniform(Vec3::new(0.1, 0.2, 0.5)).unwrap();
        assert_eq!(env.radiance(Vec3::X), Vec3::new(0.1, 0.2, 0.5));
        assert!((env.pdf(Vec3::Z) - 1.0 / (4.0 * PI)).abs() < 1e-9);
        assert_eq!(Environment::parse_record(&env.describe()).unwrap(), Some(EnvironmentRecord::Uniform(Vec3::new(0.1, 0.2, 0.5))));
        let map = Environment::map(test_map(), "/tmp/a,b.exr", 1.5, -20.0).unwrap();
        assert_eq!(
            Environment::parse_record(&map.describe()).unwrap(),
            Some(EnvironmentRecord::Map { path: "/tmp/a,b.exr".into(), strength: 1.5, rotation: -20.0 })
        );
        assert_eq!(Environment::parse_record("none").unwrap(), None);
        assert!(Environment::uniform(Vec3::new(f32::NAN, 0.0, 0.0)).is_err());
        assert!(Environment::uniform(Vec3::splat(-1.0)).is_err());
        assert!(EnvironmentMap::new(2, 2, vec![Vec3::ONE; 3]).is_err());
        assert!(EnvironmentMap::new(1, 1, vec![Vec3::splat(f32::INFINITY)]).is_err());
        assert!(Environment::uniform(Vec3::ZERO).unwrap().is_black());
    }

    #[test]
    fn power_heuristic_weights_sum_to_one() {
        for (a, b) in [(1.0, 1.0), (0.2, 3.0), (5.0, 0.0), (0.0, 0.0)] {
            let s = power_heuristic(a, b) + power_heuristic(b, a);
            assert!(a + b == 0.0 || (s - 1.0).abs() < 1e-6, "{a} {b}: {s}");
        }
    }
}
