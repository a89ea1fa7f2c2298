//! Emission (issue #19): light the medium gives off itself, as radiance per unit length.
//!
//! The meaning is that of Cycles' Principled Volume (`svm_node_principled_volume` in
//! `intern/cycles/kernel/svm/closure.h`, read 2026-12-02):
//!
//! - `emitted(x) = strength * color * grid(x)`: an emission grid scaled by a strength and
//!   tinted by a colour (Cycles' Emission Strength / Emission Color, with the grid standing
//!   for the attribute that drives the strength);
//! - blackbody: with `T = temperature_scale * temperature(x)` (kelvin; Cycles multiplies its
//!   Temperature input, 1000 K by default, by the temperature attribute, clamped at 0),
//!   `emitted += sigma_SB * 1e-6 / pi * mix(1, T^4, B) * blackbody_rgb(T)`, B the blackbody
//!   intensity. B = 1 is Stefan-Boltzmann radiance `sigma T^4 / pi` in Cycles' scale (the
//!   1e-6 is Cycles' own: W m^-2 to W mm^-2), and `mix(1, T^4, B) = (1 - B) + B T^4` is kept
//!   as Cycles has it.
//! - [`blackbody_rgb`]: the colour of a blackbody at T as linear Rec.709 RGB normalised to
//!   luminance 1 (what Cycles' fitted `svm_math_blackbody_color_rec709` returns: its end
//!   points (0.826, 0.995, 1.566) at 12000 K and (5.41, -0.20, -0.08) at 800 K both have
//!   Rec.709 luminance 1), negative components clamped to 0 as Cycles' blackbody node
//!   does. Ours is computed, not fitted: Planck's law integrated against the CIE 1931 2-degree
//!   colour matching functions (the multi-lobe Gaussian fit of Wyman, Sloan and Shirley,
//!   JCGT 2013, within about 1% of the tables), 360-830 nm at 1 nm, XYZ to linear Rec.709,
//!   tabulated every 10 K from 500 K to 20000 K and interpolated linearly; clamped to
//!   the ends outside (Cycles clamps below 800 K and above 12000 K).
//!
//! Emitted radiance is per unit length: it is not multiplied by sigma_t, sigma_s or the
//! albedo; the medium's transmittance attenuates it along a ray.

use std::sync::OnceLock;

use glam::Vec3;

/// Stefan-Boltzmann constant, W m^-2 K^-4 (the value Cycles uses).
pub const STEFAN_BOLTZMANN: f64 = 5.670373e-8;

/// What emission a render adds: an emission grid and/or a temperature grid (grid names in
/// the input file). One parameter struct for every backend.
#[derive(Clone, Debug, PartialEq)]
pub struct Emission {
    /// The grid whose value scales `strength * color`.
    pub grid: Option<String>,
    pub strength: f32,
    pub color: Vec3,
    /// The grid whose value times `temperature_scale` is the temperature, kelvin.
    pub temperature_grid: Option<String>,
    /// Kelvin per grid unit (Cycles' Temperature input; 1000 by default there).
    pub temperature_scale: f32,
    /// Cycles' Blackbody Intensity: 1 is physically accurate radiance.
    pub blackbody_intensity: f32,
}

impl Default for Emission {
    /// No emission: Cycles' Principled Volume defaults (strength 0, colour white,
    /// temperature 1000 K, blackbody intensity 0).
    fn default() -> Self {
        Emission { grid: None, strength: 0.0, color: Vec3::ONE, temperature_grid: None, temperature_scale: 1000.0, blackbody_intensity: 0.0 }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EmissionError {
    #[error("--emission-strength must be finite and >= 0, got {0}")]
    Strength(f32),
    #[error("--emission-color must be finite and >= 0, got {0}")]
    Color(Vec3),
    #[error("--temperature-scale must be finite and >= 0, got {0}")]
    Scale(f32),
    #[error("--blackbody-intensity must be finite and >= 0, got {0}")]
    Intensity(f32),
}

impl Emission {
    /// Whether the emission grid term can add anything.
    pub fn has_grid_term(&self) -> bool {
        self.grid.is_some() && self.strength > 0.0 && self.color.max_element() > 0.0
    }

    /// Whether the blackbody term can add anything.
    pub fn has_blackbody_term(&self) -> bool {
        self.temperature_grid.is_some() && self.blackbody_intensity > 0.0
    }

    /// Whether this emits at all.
    pub fn is_active(&self) -> bool {
        self.has_grid_term() || self.has_blackbody_term()
    }

    pub fn validate(&self) -> Result<(), EmissionError> {
        if !(self.strength >= 0.0 && self.strength.is_finite()) {
            return Err(EmissionError::Strength(self.strength));
        }
        if !(self.color.is_finite() && self.color.min_element() >= 0.0) {
            return Err(EmissionError::Color(self.color));
        }
        if !(self.temperature_scale >= 0.0 && self.temperature_scale.is_finite()) {
            return Err(EmissionError::Scale(self.temperature_scale));
        }
        if !(self.blackbody_intensity >= 0.0 && self.blackbody_intensity.is_finite()) {
            return Err(EmissionError::Intensity(self.blackbody_intensity));
        }
        Ok(())
    }

    /// The emitted radiance per unit length at a point whose emission grid reads `grid` and
    /// temperature grid reads `temperature` (0 where a grid is absent).
    pub fn emitted(&self, grid: f32, temperature: f32) -> Vec3 {
        let mut e = Vec3::ZERO;
        if self.has_grid_term() {
            e += self.color * (self.strength * grid.max(0.0));
        }
        if self.has_blackbody_term() {
            let t = (self.temperature_scale as f64 * temperature.max(0.0) as f64).max(0.0);
            let b = self.blackbody_intensity as f64;
            let t4 = (t * t) * (t * t);
            let intensity = STEFAN_BOLTZMANN * 1e-6 / std::f64::consts::PI * ((1.0 - b) + b * t4);
            if intensity > 0.0 {
                e += blackbody_rgb(t) * intensity as f32;
            }
        }
        e
    }

    /// The `nimbus:emission` metadata text: `grid=NAME,strength=S,color=R,G,B` and/or
    /// `temperature=NAME,scale=K,blackbody=B`, `;`-separated; `none` when inactive.
    pub fn describe(&self) -> String {
        let mut parts = vec![];
        if let (true, Some(g)) = (self.has_grid_term(), &self.grid) {
            let c = self.color;
            parts.push(format!("grid={g},strength={},color={},{},{}", self.strength, c.x, c.y, c.z));
        }
        if let (true, Some(g)) = (self.has_blackbody_term(), &self.temperature_grid) {
            parts.push(format!("temperature={g},scale={},blackbody={}", self.temperature_scale, self.blackbody_intensity));
        }
        if parts.is_empty() {
            "none".into()
        } else {
            parts.join(";")
        }
    }
}

/// Radiance of a blackbody at `t` kelvin, `sigma T^4 / pi`, W m^-2 sr^-1 (without Cycles'
/// 1e-6).
pub fn stefan_boltzmann_radiance(t: f64) -> f64 {
    STEFAN_BOLTZMANN * t.powi(4) / std::f64::consts::PI
}

/// The CIE 1931 2-degree colour matching functions at `nm`, by Wyman, Sloan and Shirley's
/// multi-lobe fit ("Simple Analytic Approximations to the CIE XYZ Color Matching
/// Functions", JCGT 2(2), 2013).
pub fn cie_1931(nm: f64) -> [f64; 3] {
    let g = |mu: f64, s1: f64, s2: f64| {
        let s = if nm < mu { s1 } else { s2 };
        let u = (nm - mu) / s;
        (-0.5 * u * u).exp()
    };
    let x = 1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2);
    let y = 0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1);
    let z = 1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8);
    [x, y, z]
}

/// Planck's spectral radiance at wavelength `nm` and temperature `t`, up to a constant factor.
fn planck(nm: f64, t: f64) -> f64 {
    // c2 = h c / k, m K.
    const C2: f64 = 1.438_776_877e-2;
    let l = nm * 1e-9;
    1.0 / (l.powi(5) * ((C2 / (l * t)).exp_m1()))
}

/// CIE XYZ to linear Rec.709 (D65 white).
fn xyz_to_rec709([x, y, z]: [f64; 3]) -> [f64; 3] {
    [
        3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z,
        -0.969_266_0 * x + 1.876_010_8 * y + 0.041_556_0 * z,
        0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z,
    ]
}

/// The blackbody's colour at `t` kelvin, computed directly (no table): linear Rec.709, luminance 1,
/// before clamping.
pub fn blackbody_rgb_unclamped(t: f64) -> [f64; 3] {
    let mut xyz = [0.0f64; 3];
    let mut nm = 360.0;
    while nm <= 830.0 {
        let p = planck(nm, t);
        let c = cie_1931(nm);
        for k in 0..3 {
            xyz[k] += p * c[k];
        }
        nm += 1.0;
    }
    let y = xyz[1];
    xyz_to_rec709([xyz[0] / y, 1.0, xyz[2] / y])
}

const TABLE_MIN: f64 = 500.0;
const TABLE_MAX: f64 = 20000.0;
const TABLE_STEP: f64 = 10.0;

fn table() -> &'static [Vec3] {
    static TABLE: OnceLock<Vec<Vec3>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let n = ((TABLE_MAX - TABLE_MIN) / TABLE_STEP) as usize + 1;
        (0..n)
            .map(|i| {
                let [r, g, b] = blackbody_rgb_unclamped(TABLE_MIN + i as f64 * TABLE_STEP);
                Vec3::new(r as f32, g as f32, b as f32)
            })
            .collect()
    })
}

/// The table [`blackbody_rgb`] interpolates: colours at `TABLE_MIN + i TABLE_STEP` kelvin
/// (unclamped), as the GPU twin (`shaders/emission.wgsl`) reads them.
pub fn blackbody_table() -> (&'static [Vec3], f64, f64) {
    (table(), TABLE_MIN, TABLE_STEP)
}

/// WGSL `EmissionInfo` (`shaders/emission.wgsl`): what [`Emission::emitted`] reads, in f32.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuEmissionInfo {
    pub color: [f32; 3],
    pub strength: f32,
    pub temperature_scale: f32,
    pub blackbody_intensity: f32,
    /// Bit 0: the grid term; bit 1: the blackbody term (0: no emission).
    pub flags: u32,
    pub table_len: u32,
    pub table_min: f32,
    pub table_max: f32,
    pub table_inv_step: f32,
    /// `sigma_SB 1e-6 / pi`, Cycles' scale, rounded once.
    pub stefan_boltzmann: f32,
}

impl GpuEmissionInfo {
    pub const GRID_TERM: u32 = 1;
    pub const BLACKBODY_TERM: u32 = 2;

    pub fn new(emission: &Emission) -> Self {
        let flags = u32::from(emission.has_grid_term()) * Self::GRID_TERM | u32::from(emission.has_blackbody_term()) * Self::BLACKBODY_TERM;
        GpuEmissionInfo {
            color: emission.color.to_array(),
            strength: emission.strength,
            temperature_scale: emission.temperature_scale,
            blackbody_intensity: emission.blackbody_intensity,
            flags,
            table_len: table().len() as u32,
            table_min: TABLE_MIN as f32,
            table_max: TABLE_MAX as f32,
            table_inv_step: (1.0 / TABLE_STEP) as f32,
            stefan_boltzmann: (STEFAN_BOLTZMANN * 1e-6 / std::f64::consts::PI) as f32,
        }
    }

    /// No emission: what a stage binds when nothing emits.
    pub fn none() -> Self {
        GpuEmissionInfo { flags: 0, ..Self::new(&Emission::default()) }
    }
}

/// The blackbody's colour at `t` kelvin: linear Rec.709 normalised to luminance 1,
/// components clamped at 0 (see the module doc), from the 10 K table.
pub fn blackbody_rgb(t: f64) -> Vec3 {
    let table = table();
    let x = ((t.clamp(TABLE_MIN, TABLE_MAX) - TABLE_MIN) / TABLE_STEP).max(0.0);
    let i = (x.floor() as usize).min(table.len() - 2);
    let f = (x - i as f64).min(1.0) as f32;
    (table[i] * (1.0 - f) + table[i + 1] * f).max(Vec3::ZERO)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::luminance;

    #[test]
    fn the_colour_of_6500_k_is_near_white() {
        let c = blackbody_rgb(6500.0);
        eprintln!("6500 K: {c}");
        // A 6500 K blackbody lies just off D65 (x, y = 0.3135, 0.3236 against 0.3127, 0.3290):
        // within a few percent of white.
        assert!((c - Vec3::ONE).abs().max_element() < 0.08, "{c}");
        assert!((luminance(c) - 1.0).abs() < 1e-3);
        // Cycles' fit at 6500 K is within a few percent of white as well (its end point at
        // 12000 K below).
    }

    #[test]
    fn the_colour_of_1000_k_is_red_orange() {
        let c = blackbody_rgb(1000.0);
        eprintln!("1000 K: {c}");
        assert!(c.x > 2.0 * c.y && c.y > c.z && c.z < 0.05 * c.x, "{c}");
    }

    #[test]
    fn colours_run_from_red_to_blue_as_t_rises() {
        let mut last = blackbody_rgb(800.0);
        let mut t = 900.0;
        while t <= 20000.0 {
            let c = blackbody_rgb(t);
            // Blue over red rises, red over green falls.
            assert!(c.z / c.x >= last.z / last.x.max(1e-9) - 1e-6, "{t} K: {c} after {last}");
            assert!(c.x / c.y <= last.x / last.y.max(1e-9) + 1e-6, "{t} K: {c} after {last}");
            last = c;
            t += 100.0;
        }
    }

    #[test]
    fn colours_match_cycles_fit() {
        // Cycles' svm_math_blackbody_color_rec709 (intern/cycles/kernel/svm/math_util.h),
        // evaluated from its coefficient tables, and the greatest relative difference of
        // red and absolute of green and blue allowed from ours: they agree to 0.1% at 6500 K
        // and above and drift apart below 3000 K (red 1.0% at 2940 K, 1.7% at 2000 K, 6% at
        // 1000 K), where the chromaticity is set by the colour matching functions' far red
        // tail, which the Wyman fit has least right.
        let cases = [
            (1000.0, Vec3::new(4.6014, 0.0390, -0.0900), 0.07, 0.1),
            (1500.0, Vec3::new(3.2643, 0.4340, -0.0642), 0.035, 0.04),
            (2000.0, Vec3::new(2.5201, 0.6469, 0.0204), 0.025, 0.02),
            (2940.0, Vec3::new(1.8009, 0.8370, 0.2560), 0.015, 0.01),
            (6500.0, Vec3::new(1.0426, 0.9841, 1.0353), 0.003, 0.003),
            (12000.0, Vec3::new(0.8270, 0.9941, 1.5668), 0.003, 0.003),
        ];
        for (t, cycles, red, green_blue) in cases {
            let ours = Vec3::from(blackbody_rgb_unclamped(t).map(|v| v as f32));
            eprintln!("{t} K: ours {ours}, Cycles {cycles}");
            assert!(((ours.x - cycles.x) / cycles.x).abs() < red, "{t} K: {ours} vs {cycles}");
            assert!((ours.y - cycles.y).abs() < green_blue && (ours.z - cycles.z).abs() < green_blue, "{t} K: {ours} vs {cycles}");
        }
    }

    #[test]
    fn the_table_interpolates_the_direct_integral() {
        for t in [1234.5, 2940.0, 6789.0, 15555.0] {
            let direct = Vec3::from(blackbody_rgb_unclamped(t).map(|v| v as f32)).max(Vec3::ZERO);
            assert!((blackbody_rgb(t) - direct).abs().max_element() < 1e-3, "{t}");
        }
    }

    #[test]
    fn stefan_boltzmann_radiance_at_known_temperatures() {
        // sigma T^4 / pi: 1000 K gives 5.670373e4 / pi = 18049.36 W m^-2 sr^-1.
        assert!((stefan_boltzmann_radiance(1000.0) - 18049.36).abs() < 0.01);
        // The sun's photosphere, 5772 K: 6.2938e7 W m^-2 emittance, / pi.
        assert!((stefan_boltzmann_radiance(5772.0) * std::f64::consts::PI / 6.2938e7 - 1.0).abs() < 1e-3);
        // Through the Emission struct at B = 1, Cycles' 1e-6 scale, luminance = radiance.
        let e = Emission { temperature_grid: Some("temperature".into()), blackbody_intensity: 1.0, temperature_scale: 1000.0, ..Emission::default() };
        let l = luminance(e.emitted(0.0, 2.0)) as f64;
        assert!((l / (stefan_boltzmann_radiance(2000.0) * 1e-6) - 1.0).abs() < 1e-3, "{l}");
        // B = 0.5 mixes as Cycles: sigma 1e-6 / pi ((1 - B) + B T^4).
        let half = Emission { blackbody_intensity: 0.5, ..e.clone() };
        let expect = STEFAN_BOLTZMANN * 1e-6 / std::f64::consts::PI * (0.5 + 0.5 * 2000f64.powi(4));
        assert!((luminance(half.emitted(0.0, 2.0)) as f64 / expect - 1.0).abs() < 1e-3);
    }

    #[test]
    fn the_grid_term_is_strength_times_colour_times_grid() {
        let e = Emission { grid: Some("flame".into()), strength: 2.0, color: Vec3::new(1.0, 0.5, 0.25), ..Emission::default() };
        assert_eq!(e.emitted(0.5, 0.0), Vec3::new(1.0, 0.5, 0.25));
        assert_eq!(e.emitted(-1.0, 0.0), Vec3::ZERO);
        assert!(e.is_active() && !Emission::default().is_active());
        assert_eq!(e.describe(), "grid=flame,strength=2,color=1,0.5,0.25");
        assert!(Emission { strength: -1.0, ..e }.validate().is_err());
    }
}
