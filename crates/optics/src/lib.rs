//! Optics shared by every nimbus stage: the medium, the phase function, lights, the camera
//! and random numbers, each with a WGSL twin in `shaders/optics.wgsl` ([`OPTICS_WGSL`]) so
//! the CPU and GPU backends compute the same thing.
//!
//! design.md sections 3 (medium), 4 (lights and camera), 5 (radiometry) and 7
//! ("Reproducible") are the spec; this crate is where their conventions live in code:
//!
//! - **Medium** ([`Medium`]): `sigma_t = extinction * density`, `sigma_s = albedo * sigma_t`,
//!   defaults 1, 0.9, g = 0; [`Medium::validate`] refuses what is not physical.
//! - **Phase** ([`HenyeyGreenstein`]): `cos t = dot(w_in, w_out)` with `w_in` the direction
//!   light travels *before* scattering (not pbrt's "both point away" convention), so g > 0 is
//!   forward. Sampling inverts the HG CDF exactly, in a form with no cancellation, so
//!   g = +-0.999 and g = 0 need no special cases; pdf = eval.
//! - **Lights** ([`Light`]): `Sun { dir }` is the direction light *travels*; a point light's
//!   irradiance is I / r^2. [`Light::incident`] gives what single scattering needs;
//!   [`Light::emitted_power`] what the photon tracer needs.
//!   Text form `dir=X,Y,Z,irradiance=R,G,B` / `pos=X,Y,Z,intensity=R,G,B` round-trips
//!   exactly through `Display`/`FromStr` (also [`format_lights`]/[`parse_lights`]).
//! - **Camera** ([`Camera`]): pinhole, pixel (0,0) top-left, image right =
//!   cross(forward, up), continuous pixel coordinates (pixel centres at +0.5).
//!   [`Camera::default_for_bounds`] frames a box from -Y; [`Camera::project`],
//!   [`Camera::sees`] and [`Camera::sees_sphere`] serve the cache baker's culling.
//! - **Random numbers** ([`Rng`]): Philox4x32-10 keyed by (seed, item index, domain); the
//!   sequence depends on nothing else, so results do not depend on threads or device.
//!   [`Rng::next_f32`] is in [0,1), never 1.0.
//!
//! - **Emission** ([`Emission`], [`emission`]): radiance per unit length from an emission
//!   grid and/or a blackbody temperature grid, with Cycles' Principled Volume meaning.
//!
//! - **Noise** ([`noise`]): seeded Perlin gradient noise and fBm, a pure function of
//!   position and seed (density perturbation in particles2vdb, offset jitter in vdbmarch).
//!
//! Everything that parses text returns a [`ParseError`] that prints as
//! `invalid <what> '<text>' (<reason>)`; semantic checks have their own error enums.
//!
//! # GPU
//!
//! [`OPTICS_WGSL`] is plain WGSL with no bindings: a stage shader concatenates it (after
//! `nimbus_gpu`'s volume prelude, before its own code) and binds the uniforms it needs,
//! uploading [`GpuMedium`], [`GpuLight`] and [`GpuCamera`], whose layouts the shader's
//! `Medium`, `Light` and `Camera` mirror byte for byte. Its functions: `rng_new`,
//! `rng_next_u32`, `rng_next_f32`, `rng_next_vec2`, `philox4x32_10`, `hg_eval`,
//! `hg_sample`, `hg_sample_cos_theta`, `medium_sigma_t`, `medium_sigma_s`,
//! `light_incident`, `camera_ray`, `orthonormal_basis`, `sample_uniform_sphere`,
//! `sample_uniform_disk_concentric`. The rng is bit-exact with [`Rng`]; the rest agree to
//! f32 rounding (transcendentals differ by a few ulps between devices).

mod camera;
pub mod emission;
mod environment;
mod gpu;
mod light;
mod medium;
pub mod noise;
mod params;
mod phase;
mod rng;
mod sampling;

pub use emission::{blackbody_rgb, blackbody_table, Emission, EmissionError, GpuEmissionInfo};
pub use environment::{luminance, power_heuristic, Distribution1D, Environment, EnvironmentError, EnvironmentMap, EnvironmentRecord, EnvironmentSample, GPU_ENVIRONMENT_HEADER};
pub use camera::{Camera, CameraError, DEFAULT_FOV_DEG, DEFAULT_HEIGHT, DEFAULT_WIDTH, MAX_PIXELS, MAX_SIDE};
pub use gpu::{GpuCamera, GpuLight, GpuMedium, LIGHT_POINT, LIGHT_SUN};
pub use light::{format_lights, parse_lights, Incident, Light, LightError};
pub use medium::{Medium, MediumError};
pub use params::ParseError;
pub use phase::{HenyeyGreenstein, LightLobes, GUIDED_LIGHTS, HG_G_MAX};
pub use rng::{philox4x32_10, r2_point, split_u64, unit_f32, Rng, R2_STEP};
pub use sampling::{orthonormal_basis, sample_uniform_disk_concentric, sample_uniform_sphere};

/// The WGSL twins of this crate (`shaders/optics.wgsl`): plain functions and structs, no
/// bindings, for stage shaders to concatenate.
pub const OPTICS_WGSL: &str = include_str!("../../../shaders/optics.wgsl");

/// The WGSL twin of [`Environment`]'s radiance, sampling and pdf
/// (`shaders/environment.wgsl`), reading [`Environment::gpu_words`] through a stage-provided
/// `env_word(i)`; composed after [`OPTICS_WGSL`].
pub const ENVIRONMENT_WGSL: &str = include_str!("../../../shaders/environment.wgsl");
