//! Flags several tools share, as clap groups, and how each resolves against what earlier
//! tools recorded in the file (design.md section 6: metadata gives the defaults, a flag
//! overrides, and a warning says so where that makes earlier work inconsistent).

use std::path::PathBuf;

use clap::Args;
use glam::{DVec3, Vec3};
use nimbus_gpu::{ComputeDevice, DeviceChoice};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_vdb::{Compression, WriteOptions};

use crate::{Failure, Log, PipelineMeta, Verbosity};

/// `-q`, `-v`, `--device`.
#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "General")]
pub struct CommonArgs {
    /// Print nothing but errors.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Print each stage's time and counts, and the density grid's world bounds and values.
    #[arg(short, long, global = true)]
    pub verbose: bool,
    /// Compute backend: auto uses a hardware GPU when there is one, else the CPU;
    /// gpu also accepts a software adapter.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
}

impl CommonArgs {
    pub fn log(&self, tool: &'static str) -> Log {
        Log::new(tool, Verbosity::from_flags(self.quiet, self.verbose))
    }

    /// The compute device, reported with -v.
    pub fn compute_device(&self, log: &Log) -> Result<ComputeDevice, Failure> {
        let device = self.device.resolve().map_err(|e| Failure::runtime(e, "--device"))?;
        log.verbose(format!("device: {device}"));
        Ok(device)
    }
}

/// Where a VDB goes and how it is written.
#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "Output")]
pub struct VdbOutputArgs {
    /// Output VDB file, or - for stdout. [default: stdout when it is not a terminal]
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// VDB compression: blosc (what Blender and Houdini write, and much faster than zip; the
    /// default where this OpenVDB build has it, else zip), zip (every OpenVDB build reads it)
    /// or none.
    #[arg(long, default_value = default_compression(), value_parser = ["zip", "blosc", "none"])]
    pub compression: String,
    /// Store float grids as 16-bit halves.
    #[arg(long)]
    pub half: bool,
}

/// `--compression`'s default (design.md section 6, issue #18): blosc, unless this OpenVDB
/// build cannot write it.
fn default_compression() -> &'static str {
    if nimbus_vdb::has_blosc() {
        "blosc"
    } else {
        "zip"
    }
}

impl VdbOutputArgs {
    pub fn write_options(&self) -> Result<WriteOptions, Failure> {
        let compression = match self.compression.as_str() {
            "zip" => Compression::Zip,
            "blosc" if nimbus_vdb::has_blosc() => Compression::Blosc,
            "blosc" => return Err(Failure::usage("this OpenVDB build cannot write blosc (use --compression zip)")),
            _ => Compression::None,
        };
        Ok(WriteOptions { compression, half: self.half })
    }
}

/// `--extinction --albedo --g`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Medium")]
pub struct MediumArgs {
    /// Extinction per unit density. [default: what the input records, else 1]
    #[arg(long, allow_negative_numbers = true)]
    pub extinction: Option<f32>,
    /// Single-scattering albedo, one grey value or R,G,B. [default: what the input records,
    /// else 0.9]
    #[arg(long, value_parser = parse_rgb, value_name = "R,G,B", allow_hyphen_values = true)]
    pub albedo: Option<Vec3>,
    /// Henyey-Greenstein asymmetry in (-1,1), > 0 forward. [default: what the input records,
    /// else 0]
    #[arg(long, allow_negative_numbers = true)]
    pub g: Option<f32>,
}

impl MediumArgs {
    /// The medium: recorded values as defaults, flags over them. `consistency` names what the
    /// recorded medium was used for; a differing flag then draws a warning.
    pub fn resolve(&self, meta: &PipelineMeta, log: &Log, consistency: Option<&str>) -> Result<Medium, Failure> {
        let recorded = meta.medium()?;
        let base = recorded.unwrap_or_default();
        let medium = Medium {
            extinction: self.extinction.unwrap_or(base.extinction),
            albedo: self.albedo.unwrap_or(base.albedo),
            g: self.g.unwrap_or(base.g),
        };
        medium.validate().map_err(|e| Failure::usage(format!("{e} (medium flags)")))?;
        let given = self.extinction.is_some() || self.albedo.is_some() || self.g.is_some();
        log.verbose(format!("medium: {medium} ({})", setting_source(given, recorded.is_some())));
        if let (Some(recorded), Some(what)) = (recorded, consistency) {
            if recorded != medium {
                log.warn(format!("medium {medium} differs from the one {what} ({recorded})"));
            }
        }
        Ok(medium)
    }
}

/// `--sun` and `--point`, repeatable.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Lights")]
pub struct LightArgs {
    /// A sun: dir=X,Y,Z,irradiance=R,G,B[,angle=DEG] (dir is where the light travels, angle
    /// the disc's diameter; repeatable). [default: what the input records, else one sun from
    /// above, dir=0,0,-1, where no --sky or --environment lights the scene]
    #[arg(long, value_name = "SPEC", value_parser = Light::parse_sun)]
    pub sun: Vec<Light>,
    /// A point light: pos=X,Y,Z,intensity=R,G,B (repeatable).
    #[arg(long, value_name = "SPEC", value_parser = Light::parse_point)]
    pub point: Vec<Light>,
}

impl LightArgs {
    pub fn given(&self) -> Option<Vec<Light>> {
        let lights: Vec<Light> = self.sun.iter().chain(&self.point).copied().collect();
        (!lights.is_empty()).then_some(lights)
    }

    /// Flags, else what the file records, else one sun from above, unless an environment
    /// lights the scene (`lit_otherwise`): then no lights, as a Blender scene lit by its World
    /// alone.
    pub fn resolve(&self, meta: &PipelineMeta, log: &Log, consistency: Option<&str>, lit_otherwise: bool) -> Result<Vec<Light>, Failure> {
        let recorded = meta.lights()?;
        let fallback = if lit_otherwise { Vec::new() } else { vec![Light::default_sun()] };
        let lights = self.given().or_else(|| recorded.clone()).unwrap_or(fallback);
        let given = self.given().is_some();
        log.verbose(format!("lights: {} ({})", nimbus_optics::format_lights(&lights), if given { "flags" } else { setting_source(false, recorded.is_some()) }));
        if let (Some(recorded), Some(what)) = (recorded, consistency) {
            if recorded != lights {
                log.warn(format!("lights differ from the ones {what}"));
            }
        }
        Ok(lights)
    }
}

/// `--eye --look-at --up --view-dir --fov --width --height`. The X,Y,Z flags take hyphen
/// values: clap's allow_negative_numbers only knows single numbers, so it refused
/// `--eye -5,0,1`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Camera")]
pub struct CameraArgs {
    /// Camera position X,Y,Z. [default: what the input records, else framing the volume's
    /// bounding box from -Y]
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_dvec3, allow_hyphen_values = true)]
    pub eye: Option<DVec3>,
    /// Point the camera looks at, X,Y,Z. [default: what the input records, else the volume's
    /// centre]
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_dvec3, allow_hyphen_values = true)]
    pub look_at: Option<DVec3>,
    /// Look at the volume's centre along X,Y,Z (where the camera looks: 0,1,0 views from
    /// -Y), from the distance that fits the volume's bounding sphere in the field of view;
    /// instead of --eye and --look-at.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_direction, allow_hyphen_values = true, conflicts_with_all = ["eye", "look_at"])]
    pub view_dir: Option<DVec3>,
    /// Up direction X,Y,Z. [default: what the input records, else 0,0,1]
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_dvec3, allow_hyphen_values = true)]
    pub up: Option<DVec3>,
    /// Horizontal field of view in degrees. [default: what the input records, else 40]
    #[arg(long, value_name = "DEG")]
    pub fov: Option<f64>,
    /// Image width in pixels. [default: what the input records, else 960]
    #[arg(long, value_name = "PIXELS")]
    pub width: Option<u32>,
    /// Image height in pixels. [default: what the input records, else 540]
    #[arg(long, value_name = "PIXELS")]
    pub height: Option<u32>,
}

impl CameraArgs {
    fn any(&self) -> bool {
        self.eye.is_some() || self.look_at.is_some() || self.view_dir.is_some() || self.up.is_some() || self.fov.is_some() || self.width.is_some() || self.height.is_some()
    }

    /// Flags over the recorded camera over the default camera for `bounds`.
    pub fn resolve(&self, meta: &PipelineMeta, bounds: Option<(DVec3, DVec3)>, log: &Log, consistency: Option<&str>) -> Result<Camera, Failure> {
        let recorded = meta.camera()?;
        let base = match (&recorded, bounds) {
            (Some(c), _) => c.clone(),
            (None, Some((lo, hi))) => Camera::default_for_bounds(lo, hi).map_err(|e| Failure::runtime(e, "default camera"))?,
            (None, None) => Camera::default_for_bounds(DVec3::splat(-1.0), DVec3::ONE).expect("unit box camera"),
        };
        if !self.any() {
            log.verbose(format!("camera: {base} ({})", setting_source(false, recorded.is_some())));
            return Ok(base);
        }
        let (fov, width, height) = (self.fov.unwrap_or(base.fov_deg()), self.width.unwrap_or(base.width()), self.height.unwrap_or(base.height()));
        let (eye, look_at, up) = match self.view_dir {
            Some(dir) => {
                let (lo, hi) = bounds.unwrap_or((DVec3::splat(-1.0), DVec3::ONE));
                let up = self.up.unwrap_or(DVec3::Z);
                let (eye, centre) = fit_view(lo, hi, dir, fov, width, height);
                // Looking straight along the up vector leaves no image up: take +Y then.
                let up = if dir.normalize().cross(up.normalize()).length() < 1e-6 { DVec3::Y } else { up };
                log.verbose(format!("camera: eye {:.6},{:.6},{:.6} looking along {dir} at the centre {:.6},{:.6},{:.6}", eye.x, eye.y, eye.z, centre.x, centre.y, centre.z));
                (eye, centre, up)
            }
            None => (self.eye.unwrap_or(base.eye()), self.look_at.unwrap_or(base.look_at()), self.up.unwrap_or(base.up())),
        };
        let camera = Camera::new(eye, look_at, up, fov, width, height).map_err(|e| Failure::usage(format!("{e} (camera flags)")))?;
        log.verbose(format!("camera: {camera} ({})", setting_source(true, recorded.is_some())));
        if let (Some(recorded), Some(what)) = (recorded, consistency) {
            // Resolution alone does not change what the cache holds.
            let moved = recorded.eye() != camera.eye() || recorded.look_at() != camera.look_at() || recorded.fov_deg() != camera.fov_deg() || recorded.up() != camera.up();
            if moved {
                log.warn(format!("camera differs from the one {what}: view-dependent lighting and culling were computed for {recorded}"));
            }
        }
        Ok(camera)
    }
}

/// Where a setting came from, for `-v` (issue #47): the flags, the input's record (what an
/// earlier tool was given or chose), both (flags over the record), or the default.
pub fn setting_source(given: bool, recorded: bool) -> &'static str {
    match (given, recorded) {
        (true, true) => "flags over the input's record",
        (true, false) => "flags",
        (false, true) => "the input's record",
        (false, false) => "default",
    }
}

/// The eye that sees the box `lo..hi` along `dir` from the distance that fits its bounding
/// sphere in the field of view (`fov` degrees across `width`, so the narrower of the two
/// angles binds), and the box's centre it looks at (design.md section 4, `--view-dir`).
pub fn fit_view(lo: DVec3, hi: DVec3, dir: DVec3, fov: f64, width: u32, height: u32) -> (DVec3, DVec3) {
    let centre = 0.5 * (lo + hi);
    let radius = (0.5 * (hi - lo)).length();
    let tan_x = (0.5 * fov).to_radians().tan();
    let tan_y = tan_x * height as f64 / width.max(1) as f64;
    let half_angle = tan_x.min(tan_y).atan();
    let distance = if radius > 0.0 { radius / half_angle.sin() } else { 1.0 };
    (centre - dir.normalize() * distance, centre)
}

/// `X,Y,Z`, not zero.
pub fn parse_direction(s: &str) -> Result<DVec3, String> {
    let v = parse_dvec3(s)?;
    if v.length() < 1e-12 {
        return Err(format!("'{s}': a direction cannot be zero"));
    }
    Ok(v)
}

/// `R,G,B` or one grey value.
pub fn parse_rgb(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s.split(',').map(|p| p.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| format!("'{s}': {e}"))?;
    match v[..] {
        [g] => Ok(Vec3::splat(g)),
        [r, g, b] => Ok(Vec3::new(r, g, b)),
        _ => Err(format!("'{s}': expected one value or R,G,B")),
    }
}

/// `X,Y,Z`.
pub fn parse_dvec3(s: &str) -> Result<DVec3, String> {
    let v: Vec<f64> = s.split(',').map(|p| p.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| format!("'{s}': {e}"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(DVec3::new(x, y, z)),
        _ => Err(format!("'{s}': expected three finite numbers X,Y,Z")),
    }
}

/// `--quality`: presets over the settings that trade run time for error, chosen from
/// `make bench`'s Pareto front (README, "Quality presets"). Explicit flags override them; with
/// no `--quality` each tool keeps its own defaults (design.md).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// Fast look-development renders.
    Draft,
    /// The everyday setting.
    Preview,
    /// Finished frames.
    Final,
}

/// What a [`Quality`] sets, tool by tool; [`QualitySettings::DEFAULT`] is what the tools do
/// without one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QualitySettings {
    /// vdbcache `--paths`: multiple scattering traced from the cache voxels, which beats the
    /// photon gather at every budget on the bundled scenes (README); an explicit
    /// `--gather-neighbours` or `--radius` gathers photons instead.
    pub paths: u32,
    /// vdbphoton `--photons`, for the chain that gathers photons.
    pub photons: u64,
    /// vdbphoton `--distance`: delta on every preset, as without one (the same photon
    /// distribution as simpson, measured, at a fraction of the time).
    pub distance: &'static str,
    /// vdbcache `--gather-neighbours`, where photons are gathered.
    pub gather_neighbours: u32,
    /// vdbcache `--cache-scale`: Li_single's lattice, in density voxels.
    pub cache_scale: f64,
    /// vdbcache `--multiple-scale`: Li_multiple's lattice, in density voxels.
    pub multiple_scale: f64,
    /// vdbcache refines Li_single's lattice per axis to its interpolation tolerance
    /// (nimbus_cache::choose_single_lattice) unless `--cache-scale` is given.
    pub refine_single: bool,
    /// vdbcache tops the paths up until their predicted noise in the image is within this
    /// multiple of nimbus_cache::PATH_TOLERANCE (2%), unless `--paths` or `--path-tolerance`
    /// is given; None traces the preset's paths once. A preset's error on a scene it was not
    /// measured on is then bounded by its noise, not by how many pixels read each voxel.
    pub path_noise: Option<f64>,
    /// vdbcache refines Li_multiple's lattice to nimbus_cache::MULTIPLE_LATTICE_TOLERANCE
    /// unless `--multiple-scale`, `--multiple-tolerance` or `--paths` is given.
    pub refine_multiple: bool,
    /// vdbmarch `--step` as a multiple of its default (nimbus_march::default_step).
    pub step_factor: f64,
    /// vdbmarch `--spp`; None: enough for the pixel's samples to lie a quarter of a
    /// density voxel apart at the volume (`nimbus_march::default_spp`).
    pub spp: Option<u32>,
}

impl QualitySettings {
    /// The tools without `--quality`: the chain within 2% of the path-traced reference on
    /// the bundled scenes (README, `make bench`). Li_single at the density's resolution
    /// (its shadows are as sharp as the density; tabled transmittance makes it cheap),
    /// finer along the axes where its interpolation would miss (flat voxels, thin dense
    /// layers, grazing suns: nimbus_cache::choose_single_lattice),
    /// Li_multiple on a lattice two voxels wide (the best of 1 to 8 at equal time on the
    /// cloud, the plume and a twenty-times thinner plume: multiple scattering follows the
    /// medium's wisps, not only its transport mean free path) with 64 paths a voxel (the
    /// cloud's noise sets it: 32 give 2.4%, 64 1.9-2.0%), and the march's samples per pixel
    /// by the image's footprint (the plume's sub-pixel wisps: 2.2% at one sample, 1.3% at 16).
    pub const DEFAULT: QualitySettings =
        QualitySettings { paths: 64, photons: 200_000, distance: "delta", gather_neighbours: 64, cache_scale: 1.0, multiple_scale: 2.0, refine_single: true, path_noise: Some(1.0), refine_multiple: true, step_factor: 1.0, spp: None };
}

impl Quality {
    pub const ALL: [Quality; 3] = [Quality::Draft, Quality::Preview, Quality::Final];

    pub fn name(self) -> &'static str {
        match self {
            Quality::Draft => "draft",
            Quality::Preview => "preview",
            Quality::Final => "final",
        }
    }

    pub fn settings(self) -> QualitySettings {
        let default = QualitySettings::DEFAULT;
        match self {
            // Look development: a coarse lattice, not refined, and few paths topped up to 10%
            // noise (its blur and noise are the error), one sample per pixel and a long march
            // step. Without the top-up the Cloud1-class scene (unit voxels at 1024 x 576, each
            // voxel read by few pixels) came out 25% off its reference, the bundled cloud 9.8%.
            Quality::Draft => QualitySettings { paths: 4, photons: 50_000, gather_neighbours: 32, cache_scale: 2.0, multiple_scale: 4.0, refine_single: false, path_noise: Some(5.0), refine_multiple: false, step_factor: 2.0, spp: Some(1), ..default },
            // The default lattices at a quarter of the paths, topped up to 4% noise.
            Quality::Preview => QualitySettings { paths: 16, path_noise: Some(2.0), refine_multiple: false, ..default },
            // Four times the default's paths (half its noise) and 16 stratified samples per
            // pixel, which average sub-pixel wisps as the reference does.
            Quality::Final => QualitySettings { paths: 256, photons: 3_200_000, gather_neighbours: 128, spp: Some(16), ..default },
        }
    }
    /// The settings of `quality`, or the defaults without one.
    pub fn settings_or_default(quality: Option<Quality>) -> QualitySettings {
        quality.map_or(QualitySettings::DEFAULT, Quality::settings)
    }
}

/// A tool's command line as every tool parses it: numeric flags take negative numbers as
/// values (`--voxel-size -1` reaches the tool's own check, "must be positive", instead of
/// clap's tip about `-- -1`), and clap's errors and `--help` exit as clap does.
pub fn parse_args_from<T: clap::Parser>(args: impl IntoIterator<Item = impl Into<std::ffi::OsString> + Clone>) -> (T, clap::ArgMatches) {
    let matches = command::<T>().get_matches_from(args);
    let parsed = T::from_arg_matches(&matches).unwrap_or_else(|e| e.format(&mut command::<T>()).exit());
    (parsed, matches)
}

/// [`parse_args_from`] over the process's arguments. With the environment variable
/// `NIMBUS_PARSE_ONLY` set, the tool exits 0 once its flags parsed, running nothing: how
/// `tests/help.rs` checks that the examples in `--help` are accepted.
pub fn parse_args<T: clap::Parser>() -> (T, clap::ArgMatches) {
    let parsed = parse_args_from::<T>(std::env::args_os());
    if std::env::var_os("NIMBUS_PARSE_ONLY").is_some() {
        std::process::exit(0);
    }
    parsed
}

/// `T`'s command with every value-taking flag allowing negative numbers.
pub fn command<T: clap::CommandFactory>() -> clap::Command {
    T::command().mut_args(|a| if a.get_action().takes_values() { a.allow_negative_numbers(true) } else { a })
}

/// The flags of the group `A` (one of the shared Args structs) given on the command line, as
/// they were given (`--sun SPEC`, `--no-environment`): what nimbus-render passes on to a
/// tool, unchanged, after its own parser checked them.
pub fn given_flags<A: clap::Args>(matches: &clap::ArgMatches) -> Vec<std::ffi::OsString> {
    let group = A::augment_args(clap::Command::new("group"));
    let mut flags = Vec::new();
    for arg in group.get_arguments() {
        let id = arg.get_id().as_str();
        let (Some(long), Some(clap::parser::ValueSource::CommandLine)) = (arg.get_long(), matches.value_source(id)) else { continue };
        if !arg.get_action().takes_values() {
            flags.push(format!("--{long}").into());
            continue;
        }
        for value in matches.get_raw(id).into_iter().flatten() {
            flags.push(format!("--{long}").into());
            flags.push(value.to_os_string());
        }
    }
    flags
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--view-dir`: the bounding sphere touches the narrower field of view, whatever the
    /// direction and aspect.
    #[test]
    fn fit_view_fits_the_bounding_sphere() {
        let (lo, hi) = (DVec3::new(-1.0, 0.0, 2.0), DVec3::new(3.0, 1.0, 4.0));
        let radius = (0.5 * (hi - lo)).length();
        for (dir, width, height) in [(DVec3::Y, 960, 540), (DVec3::new(1.0, -2.0, 0.5), 100, 300), (-DVec3::Z, 64, 64)] {
            let (eye, centre) = fit_view(lo, hi, dir, 40.0, width, height);
            assert_eq!(centre, DVec3::new(1.0, 0.5, 3.0));
            assert!(((centre - eye).normalize() - dir.normalize()).length() < 1e-12);
            let tan_x = 20f64.to_radians().tan();
            let half = tan_x.min(tan_x * height as f64 / width as f64).atan();
            assert!(((eye - centre).length() * half.sin() - radius).abs() < 1e-9);
        }
    }

    #[derive(clap::Parser, Debug)]
    struct Both {
        #[command(flatten)]
        lights: LightArgs,
        #[command(flatten)]
        camera: CameraArgs,
        #[command(flatten)]
        environment: crate::EnvironmentArgs,
    }

    /// What nimbus-render passes on is what was written, group by group, checked by the
    /// typed parser first.
    #[test]
    fn given_flags_are_the_flags_as_written() {
        let argv = ["t", "--sun", "dir=0,0,-1,irradiance=2", "--eye=-5,0,1", "--sun", "dir=1,0,0,irradiance=1", "--no-environment", "--fov", "30"];
        let (both, matches) = parse_args_from::<Both>(argv);
        assert_eq!(both.lights.sun.len(), 2);
        let text = |f: Vec<std::ffi::OsString>| f.iter().map(|s| s.to_string_lossy().into_owned()).collect::<Vec<_>>().join(" ");
        assert_eq!(text(given_flags::<LightArgs>(&matches)), "--sun dir=0,0,-1,irradiance=2 --sun dir=1,0,0,irradiance=1");
        assert_eq!(text(given_flags::<CameraArgs>(&matches)), "--eye -5,0,1 --fov 30");
        assert_eq!(text(given_flags::<crate::EnvironmentArgs>(&matches)), "--no-environment");
        assert!(command::<Both>().try_get_matches_from(["t", "--fov", "-40"]).is_ok(), "negative numbers are values");
    }
}
