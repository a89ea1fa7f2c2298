//! Lights (design.md sections 4 and 5): a parallel sun and an isotropic point.

use std::fmt;
use std::str::FromStr;

use glam::{DVec3, Vec3};

use crate::params::{join, rgb_text, KeyValues, ParseError};

/// Why a light was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LightError {
    #[error("sun direction must be a non-zero finite vector, got {}", join(&.0.to_array()))]
    Direction(Vec3),
    #[error("point light position must be finite, got {}", join(&.0.to_array()))]
    Position(DVec3),
    #[error("{name} must be finite and >= 0 per channel, got {}", rgb_text(*value))]
    Power { name: &'static str, value: Vec3 },
    #[error("sun angle must be in [0, 180) degrees, got {0}")]
    Angle(f32),
}

/// A light source.
///
/// Text form (the CLI's `--sun`/`--point` values and the `nimbus:lights` metadata):
/// `dir=X,Y,Z,irradiance=R,G,B` for a sun, `pos=X,Y,Z,intensity=R,G,B` for a point light;
/// colours may be one number meaning grey. The keys tell the kind; an optional `sun:` or
/// `point:` prefix is accepted and checked. Missing values take defaults: sun direction
/// 0,0,-1 (light falling from above, Z up), irradiance or intensity 1. `Display` writes the
/// same syntax back, with numbers in shortest round-trip form, so `parse(format(l)) == l`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// Distant light. `dir` is the direction the light travels (unit length);
    /// `irradiance` E is RGB power per unit area perpendicular to `dir`; `angle` the sun
    /// disc's angular diameter in degrees (0: parallel light, sharp shadows; Blender's Sun
    /// default is 0.526), spread uniformly over the disc's solid angle, as Cycles does.
    Sun { dir: Vec3, irradiance: Vec3, angle: f32 },
    /// Isotropic point light with RGB `intensity` I (power per steradian).
    Point { position: DVec3, intensity: Vec3 },
}

/// What a light delivers at a point: the input to single scattering
/// (`Li_single = p(w_in, w_out) * irradiance * T_light`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Incident {
    /// Unit vector from the point toward the light. The light arrives travelling along
    /// `w_in = -to_light`.
    pub to_light: Vec3,
    /// Distance to the light (infinite for a sun): where a shadow ray stops.
    pub distance: f64,
    /// Irradiance on a surface facing the light: E for a sun, I / r^2 for a point light.
    pub irradiance: Vec3,
}

fn check_power(name: &'static str, value: Vec3) -> Result<(), LightError> {
    if value.is_finite() && value.min_element() >= 0.0 {
        Ok(())
    } else {
        Err(LightError::Power { name, value })
    }
}

impl Light {
    /// A sun travelling along `dir` (normalised here unless already unit length to within
    /// f32 rounding, so parsed text round-trips bit for bit).
    pub fn sun(dir: Vec3, irradiance: Vec3) -> Result<Light, LightError> {
        let len2 = dir.length_squared();
        if !dir.is_finite() || len2 <= 0.0 || !len2.is_finite() {
            return Err(LightError::Direction(dir));
        }
        let dir = if (len2 - 1.0).abs() <= 4.0 * f32::EPSILON { dir } else { dir / len2.sqrt() };
        check_power("irradiance", irradiance)?;
        Ok(Light::Sun { dir, irradiance, angle: 0.0 })
    }

    /// A sun whose disc spans `angle` degrees.
    pub fn sun_with_angle(dir: Vec3, irradiance: Vec3, angle: f32) -> Result<Light, LightError> {
        if !(0.0..180.0).contains(&angle) {
            return Err(LightError::Angle(angle));
        }
        match Light::sun(dir, irradiance)? {
            Light::Sun { dir, irradiance, .. } => Ok(Light::Sun { dir, irradiance, angle }),
            point => Ok(point),
        }
    }

    /// Whether the light is a sun with a disc of non-zero size (soft shadows).
    pub fn has_disc(&self) -> bool {
        matches!(*self, Light::Sun { angle, .. } if angle > 0.0)
    }

    pub fn point(position: DVec3, intensity: Vec3) -> Result<Light, LightError> {
        if !position.is_finite() {
            return Err(LightError::Position(position));
        }
        check_power("intensity", intensity)?;
        Ok(Light::Point { position, intensity })
    }

    /// The design.md default sun: straight down, irradiance 1.
    pub fn default_sun() -> Light {
        Light::Sun { dir: Vec3::NEG_Z, irradiance: Vec3::ONE, angle: 0.0 }
    }

    /// Direction, distance and irradiance of this light at `p`.
    ///
    /// A point light at distance 0 delivers zero rather than infinity: the singularity has
    /// zero measure, and an infinite sample would poison every sum it enters.
    #[inline]
    pub fn incident(&self, p: DVec3) -> Incident {
        match *self {
            Light::Sun { dir, irradiance, .. } => Incident { to_light: -dir, distance: f64::INFINITY, irradiance },
            Light::Point { position, intensity } => {
                let offset = position - p;
                let r2 = offset.length_squared();
                if r2 == 0.0 {
                    return Incident { to_light: Vec3::Z, distance: 0.0, irradiance: Vec3::ZERO };
                }
                let r = r2.sqrt();
                Incident { to_light: (offset / r).as_vec3(), distance: r, irradiance: intensity * (1.0 / r2) as f32 }
            }
        }
    }

    /// [`Light::incident`] with the direction drawn uniformly over the sun's disc (its
    /// solid angle) by `u` in [0,1)^2; the same as `incident` for every other light. The
    /// irradiance is the whole disc's, so averaging over `u` gives the soft shadow.
    #[inline]
    pub fn incident_over_disc(&self, p: DVec3, u: glam::Vec2) -> Incident {
        let mut incident = self.incident(p);
        if let Light::Sun { angle, .. } = *self {
            if angle > 0.0 {
                let cos_max = (0.5 * angle).to_radians().cos();
                let cos = 1.0 - u.x * (1.0 - cos_max);
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let phi = 2.0 * std::f32::consts::PI * u.y;
                let (t, b) = crate::orthonormal_basis(incident.to_light);
                incident.to_light = (sin * (phi.cos() * t + phi.sin() * b) + cos * incident.to_light).normalize();
            }
        }
        incident
    }

    /// Irradiance at `p` on a surface facing the light: E, or I / r^2.
    #[inline]
    pub fn irradiance_at(&self, p: DVec3) -> Vec3 {
        self.incident(p).irradiance
    }

    /// Unit vector from `p` toward the light.
    #[inline]
    pub fn direction_to_light(&self, p: DVec3) -> Vec3 {
        self.incident(p).to_light
    }

    /// Total power the photon tracer emits (design.md section 5) over `extent`, what its
    /// photons leave through (nimbus_photon's `SunEmission` and `PointEmission`): for a sun
    /// E x the area they leave from, for a point light I x the solid angle they leave into
    /// (4 pi I for every direction).
    pub fn emitted_power(&self, extent: f64) -> Vec3 {
        match *self {
            Light::Sun { irradiance, .. } => irradiance * extent as f32,
            Light::Point { intensity, .. } => intensity * extent as f32,
        }
    }

    /// The light's colour (irradiance or intensity).
    pub fn power_rgb(&self) -> Vec3 {
        match *self {
            Light::Sun { irradiance, .. } => irradiance,
            Light::Point { intensity, .. } => intensity,
        }
    }

    /// Reads a `--sun` value, `dir=X,Y,Z,irradiance=R,G,B,angle=DEG` (any key may be left
    /// out).
    pub fn parse_sun(s: &str) -> Result<Light, ParseError> {
        let mut kv = KeyValues::parse("sun", s)?;
        let dir = kv.vec3("dir")?.unwrap_or(Vec3::NEG_Z);
        let irradiance = kv.rgb("irradiance")?.unwrap_or(Vec3::ONE);
        let angle = kv.f32("angle")?.unwrap_or(0.0);
        kv.finish("dir, irradiance, angle")?;
        Light::sun_with_angle(dir, irradiance, angle).map_err(|e| kv_error("sun", s, e))
    }

    /// Reads a `--point` value, `pos=X,Y,Z,intensity=R,G,B` (`pos` required).
    pub fn parse_point(s: &str) -> Result<Light, ParseError> {
        let mut kv = KeyValues::parse("point light", s)?;
        let Some(position) = kv.dvec3("pos")? else {
            return Err(kv.error("pos=X,Y,Z is required"));
        };
        let intensity = kv.rgb("intensity")?.unwrap_or(Vec3::ONE);
        kv.finish("pos, intensity")?;
        Light::point(position, intensity).map_err(|e| kv_error("point light", s, e))
    }
}

fn kv_error(what: &'static str, input: &str, e: LightError) -> ParseError {
    ParseError { what, input: input.to_string(), reason: e.to_string() }
}

impl fmt::Display for Light {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Light::Sun { dir, irradiance, angle } => {
                write!(f, "dir={},irradiance={}", join(&dir.to_array()), rgb_text(irradiance))?;
                // Parallel suns keep the text they always had.
                if angle > 0.0 {
                    write!(f, ",angle={angle}")?;
                }
                Ok(())
            }
            Light::Point { position, intensity } => write!(f, "pos={},intensity={}", join(&position.to_array()), rgb_text(intensity)),
        }
    }
}

/// Reads either kind, told apart by `pos` (point) versus `dir`/`irradiance` (sun), or by a
/// `sun:` / `point:` prefix.
impl FromStr for Light {
    type Err = ParseError;

    fn from_str(s: &str) -> Result<Light, ParseError> {
        let t = s.trim();
        if let Some(rest) = t.strip_prefix("sun:") {
            return Light::parse_sun(rest);
        }
        if let Some(rest) = t.strip_prefix("point:") {
            return Light::parse_point(rest);
        }
        let kv = KeyValues::parse("light", s)?;
        match (kv.has("pos") || kv.has("intensity"), kv.has("dir") || kv.has("irradiance") || kv.has("angle")) {
            (true, true) => Err(kv.error("mixes a sun's dir/irradiance with a point light's pos/intensity")),
            (true, false) => Light::parse_point(s),
            (false, true) => Light::parse_sun(s),
            (false, false) => Err(kv.error("expected dir=X,Y,Z,irradiance=R,G,B or pos=X,Y,Z,intensity=R,G,B")),
        }
    }
}

/// Several lights as one metadata string, separated by `;`.
pub fn format_lights(lights: &[Light]) -> String {
    lights.iter().map(Light::to_string).collect::<Vec<_>>().join(";")
}

/// Reads [`format_lights`]' output (an empty string is no lights).
pub fn parse_lights(s: &str) -> Result<Vec<Light>, ParseError> {
    s.split(';').map(str::trim).filter(|p| !p.is_empty()).map(str::parse).collect()
}
