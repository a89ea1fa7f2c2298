//! The participating medium (design.md section 3): coefficients proportional to density.

use std::fmt;
use std::str::FromStr;

use glam::Vec3;

use crate::params::{rgb_text, KeyValues, ParseError};
use crate::phase::HenyeyGreenstein;

/// Why a [`Medium`] was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MediumError {
    #[error("extinction must be finite and >= 0, got {0}")]
    Extinction(f32),
    #[error("albedo must be in [0,1] per channel, got {}", rgb_text(*.0))]
    Albedo(Vec3),
    #[error("phase asymmetry g must be in (-1,1), got {0}")]
    G(f32),
}

/// A medium whose coefficients scale with the density grid:
/// `sigma_t(x) = extinction * density(x)`, `sigma_s(x) = albedo * sigma_t(x)`,
/// scattering by Henyey-Greenstein with asymmetry `g`.
///
/// The fields are public for struct literals; [`Medium::new`] or [`Medium::validate`] is
/// where bad values are caught, and every stage validates what it is handed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Medium {
    /// Extinction cross-section per unit density (world units^-1 at density 1).
    pub extinction: f32,
    /// Single-scattering albedo sigma_s / sigma_t per RGB channel.
    pub albedo: Vec3,
    /// Henyey-Greenstein mean cosine; > 0 scatters forward.
    pub g: f32,
}

impl Default for Medium {
    /// design.md section 3: extinction 1, albedo 0.9 (grey), isotropic.
    fn default() -> Self {
        Medium { extinction: 1.0, albedo: Vec3::splat(0.9), g: 0.0 }
    }
}

impl Medium {
    /// A validated medium.
    pub fn new(extinction: f32, albedo: Vec3, g: f32) -> Result<Self, MediumError> {
        let medium = Medium { extinction, albedo, g };
        medium.validate()?;
        Ok(medium)
    }

    /// Checks extinction >= 0 and finite, albedo in [0,1] per channel, g in (-1,1).
    /// (NaN fails every check, as it should.)
    pub fn validate(&self) -> Result<(), MediumError> {
        if !(self.extinction.is_finite() && self.extinction >= 0.0) {
            return Err(MediumError::Extinction(self.extinction));
        }
        if !self.albedo.to_array().iter().all(|a| (0.0..=1.0).contains(a)) {
            return Err(MediumError::Albedo(self.albedo));
        }
        // |g| = 1 is a delta distribution, not a density: refuse it rather than clamp silently.
        if !(self.g > -1.0 && self.g < 1.0) {
            return Err(MediumError::G(self.g));
        }
        Ok(())
    }

    /// Extinction coefficient at a point of the given density.
    #[inline]
    pub fn sigma_t(&self, density: f32) -> f32 {
        self.extinction * density
    }

    /// Scattering coefficient (RGB) at a point of the given density.
    #[inline]
    pub fn sigma_s(&self, density: f32) -> Vec3 {
        self.albedo * self.sigma_t(density)
    }

    /// Mean albedo over the channels: the photon tracer's Russian-roulette survival
    /// probability (design.md section 5), the surviving power scaled by albedo / mean.
    #[inline]
    pub fn albedo_mean(&self) -> f32 {
        (self.albedo.x + self.albedo.y + self.albedo.z) / 3.0
    }

    /// The medium's phase function.
    #[inline]
    pub fn phase(&self) -> HenyeyGreenstein {
        HenyeyGreenstein::new(self.g)
    }

    /// True when nothing scatters (albedo 0 or extinction 0): stages skip scattering work.
    pub fn is_non_scattering(&self) -> bool {
        self.extinction == 0.0 || self.albedo == Vec3::ZERO
    }
}

/// `extinction=1,albedo=0.9,g=0` (albedo as one grey number or three).
impl fmt::Display for Medium {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "extinction={},albedo={},g={}", self.extinction, rgb_text(self.albedo), self.g)
    }
}

/// Reads `extinction=E,albedo=A|R,G,B,g=G`; any key may be left out and takes its default.
impl FromStr for Medium {
    type Err = ParseError;

    fn from_str(s: &str) -> Result<Self, ParseError> {
        let mut kv = KeyValues::parse("medium", s)?;
        let default = Medium::default();
        let medium = Medium {
            extinction: kv.f32("extinction")?.unwrap_or(default.extinction),
            albedo: kv.rgb("albedo")?.unwrap_or(default.albedo),
            g: kv.f32("g")?.unwrap_or(default.g),
        };
        kv.finish("extinction, albedo, g")?;
        medium.validate().map_err(|e| ParseError { what: "medium", input: s.to_string(), reason: e.to_string() })?;
        Ok(medium)
    }
}
