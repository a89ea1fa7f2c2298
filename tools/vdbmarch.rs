//! vdbmarch: cache VDB -> EXR image (and PNG preview), by ray marching the density with
//! illumination-cache lookups; with `--reference`, density VDB -> EXR by an unbiased path
//! tracer (the ground truth, needing no photons or cache). The engine is `nimbus-march`.

use std::path::PathBuf;

use clap::{Parser, ValueEnum};
use glam::Vec3;
use nimbus_cache::IlluminationCache;
use nimbus_cli::{
    parse_rgb, read_vec3_grid, CameraArgs, CommonArgs, EmissionArgs, EmissionGrids, EnvironmentArgs, Failure, Input, LightArgs, Log, MediumArgs, MotionArgs, Output,
    PipelineMeta, Quality, SequenceArgs, Stage, Tool, Velocity,
};
use nimbus_march::{render_cpu_with, render_gpu_with, render_reference_cpu_with, render_reference_gpu_with, MediumFields};
use nimbus_march::{default_spp, default_step, reference_tile_pixels, Image, MarchError, MarchParams, ReferenceParams, ViewTransform};

/// `--view`: Blender's view transforms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum View {
    /// Blender 4's default, AgX (base contrast): highlights roll off to white, saturated
    /// colours desaturate as they brighten; white at 6.5 stops above 0.18 grey.
    Agx,
    /// Blender 2.8-3.x's default, Filmic (base contrast): log encoding over 16.5 stops and
    /// a film-like curve; 0.18 grey shows as 0.5.
    Filmic,
    /// Blender's Standard: the sRGB transfer function, clipped at 1.0.
    Standard,
}

impl From<View> for ViewTransform {
    fn from(v: View) -> ViewTransform {
        match v {
            View::Agx => ViewTransform::Agx,
            View::Filmic => ViewTransform::Filmic,
            View::Standard => ViewTransform::Standard,
        }
    }
}

#[derive(Parser, Debug, Clone)]
#[command(
    name = "vdbmarch",
    version,
    about = "Cache VDB -> EXR image by ray marching with illumination-cache lookups",
    after_help = "Examples:\n  particles2vdb smoke.ply --voxel-size 2 | vdbcache | vdbmarch -o smoke.exr --preview smoke.png --exposure 0.5\n  vdbmarch --reference density.vdb --sun dir=0.5,0.3,-0.8,irradiance=4 --spp 256 -o reference.exr"
)]
struct Args {
    /// Input VDB from vdbcache, or - for stdin. [default: stdin when it is not a terminal]
    #[arg(help_heading = "Input")]
    input: Option<PathBuf>,
    /// The density grid. [default: what the input records, else density]
    #[arg(long, help_heading = "Input")]
    grid: Option<String>,
    /// Output EXR file, or - for stdout. [default: stdout when it is not a terminal]
    #[arg(short, long, value_name = "FILE.exr", help_heading = "Output")]
    output: Option<PathBuf>,
    /// Also write an 8-bit sRGB PNG preview here (RGB, over the background; no alpha).
    #[arg(long, value_name = "FILE.png", help_heading = "Output")]
    preview: Option<PathBuf>,
    /// Preview exposure in stops: the scene values are multiplied by 2^EV before the view
    /// transform, as Blender's Exposure (the EXR is not changed).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, help_heading = "Output")]
    exposure: f32,
    /// The preview's view transform, as Blender's colour management shows an image on an
    /// sRGB display (the EXR stays linear, scene-referred, and does not record it).
    #[arg(long, value_enum, default_value_t = View::Agx, help_heading = "Output")]
    view: View,
    /// Add the layers single, multiple, transmittance and depth to the EXR.
    #[arg(long, help_heading = "Output")]
    aovs: bool,
    #[command(flatten)]
    medium: MediumArgs,
    #[command(flatten)]
    camera: CameraArgs,
    /// Render the ground truth instead: an unbiased path tracer (delta tracking, next-event
    /// estimation with ratio tracking, all orders of scattering) over the density alone;
    /// the input needs no photons or cache. Slow: use --spp 64 and up.
    #[arg(long, help_heading = "Quality")]
    reference: bool,
    /// With --reference: most scattering events per path.
    #[arg(long, default_value_t = ReferenceParams::DEFAULT_MAX_DEPTH, requires = "reference", help_heading = "Quality")]
    max_depth: u32,
    /// The lights, for --reference (the march reads them from the cache).
    #[command(flatten)]
    lights: LightArgs,
    /// The sky or environment map: lights the scene with --reference; camera rays that
    /// leave the volume see it.
    #[command(flatten)]
    environment: EnvironmentArgs,
    /// March step, world units. [default: the --quality preset's multiple of the thinnest
    /// density voxel width over sqrt 3 (a third of a cubic voxel's diagonal), else that]
    #[arg(long, help_heading = "Quality")]
    step: Option<f64>,
    /// Most the step is lengthened where the density is optically thin (1 = a fixed step):
    /// in each majorant cell, by the largest whole factor keeping a step's optical depth at
    /// the cell's density bound within 1/4 (longer steps sample the cache's shadow edges too
    /// sparsely; 2 saves 15% of the march). [default: 1]
    #[arg(long, help_heading = "Quality")]
    max_step_factor: Option<u32>,
    /// Samples per pixel, stratified; paths per pixel with --reference. [default: the
    /// --quality preset's, else enough for a pixel's samples to lie half a density voxel
    /// apart at the volume, 1 to 16; 1 with --reference]
    #[arg(long, help_heading = "Quality")]
    spp: Option<u32>,
    /// Preset: draft, preview or final (march step and spp; flags override).
    #[arg(long, value_enum, help_heading = "Quality")]
    quality: Option<Quality>,
    /// Background radiance R,G,B (or one grey value) seen through the volume. [default: the
    /// environment where there is one, as Blender shows the World, else black]
    #[arg(long, value_parser = parse_rgb, value_name = "R,G,B", help_heading = "Lights")]
    background: Option<Vec3>,
    /// Amplitude of the Perlin offset noise on sample positions, world units (0 = off).
    #[arg(long, default_value_t = 0.0, help_heading = "Medium")]
    offset_noise: f64,
    /// Feature size of the offset noise, world units. [default: four density voxels]
    #[arg(long, help_heading = "Medium")]
    noise_scale: Option<f64>,
    /// Rays stop below this transmittance.
    #[arg(long, default_value_t = 1e-4, help_heading = "Quality")]
    min_transmittance: f64,
    /// Random seed. [default: what the input records, else 0]
    #[arg(long, help_heading = "Quality")]
    seed: Option<u64>,
    #[command(flatten)]
    emission: EmissionArgs,
    #[command(flatten)]
    motion: MotionArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "vdbmarch", vdbmarch, input: input, outputs: [output, preview]);

fn vdbmarch(args: Args) -> Result<(), Failure> {
    let log = args.common.log(Args::NAME);
    let input = Input::from_arg(args.input.as_deref())?;
    let output = Output::from_arg(args.output.as_deref())?;
    if let Some(ext) = output.extension() {
        if ext != "exr" {
            return Err(Failure::usage(format!("the output is an EXR image; '{}' does not end in .exr", output.name())));
        }
    }
    let stage = Stage::read(log, &input, args.grid.as_deref())?;
    let log = &stage.log;
    log.verbose(nimbus_cli::describe_density(&stage.grid, &stage.density));
    let velocity = args.motion.resolve(&stage.file, log)?;
    let (mut image, emission) =
        if args.reference { reference(&args, &stage, velocity.as_ref())? } else { march(&args, &stage, velocity.as_ref())? };
    image.metadata.push(("nimbus:motion_blur".into(), velocity.as_ref().map_or("none".into(), |v| v.describe())));
    // What emission the image holds, as the pipeline records its parameters (design.md
    // section 6): `none`, or `nimbus_optics::Emission::describe`'s text.
    image.metadata.push(("nimbus:emission".into(), emission.as_ref().map_or("none".into(), |e| e.params.describe())));
    if image.nonfinite > 0 {
        log.warn(format!("{} pixels came out non-finite and were set to zero", image.nonfinite));
    }
    let exr = image.to_exr().map_err(|e| Failure::runtime(e, output.name()))?;
    log.stage("write", || output.write(&exr), |_| String::new())?;
    if let Some(png_path) = &args.preview {
        let png = image.to_png(args.exposure, args.view.into()).map_err(|e| Failure::runtime(e, png_path.display()))?;
        Output::Path(png_path.clone()).write(&png)?;
    }
    log.finish();
    Ok(())
}

fn march_failure(e: MarchError, what: &str) -> Failure {
    match e {
        MarchError::Param(_) => Failure::usage(e),
        MarchError::Gpu(_) => Failure::runtime(e, what),
    }
}

/// The path-traced ground truth: medium, lights and camera from flags, else the file.
fn reference(args: &Args, stage: &Stage, velocity: Option<&Velocity>) -> Result<(Image, Option<EmissionGrids>), Failure> {
    let (file, density, meta, log) = (&stage.file, &stage.density, &stage.meta, &stage.log);
    let march_only = [
        (args.step.is_some(), "--step"),
        (args.max_step_factor.is_some(), "--max-step-factor"),
        (args.offset_noise != 0.0, "--offset-noise"),
        (args.noise_scale.is_some(), "--noise-scale"),
        (args.quality.is_some(), "--quality"),
    ];
    for (given, flag) in march_only {
        if given {
            log.warn(format!("{flag} is for ray marching; the reference path tracer ignores it"));
        }
    }
    let emission = args.emission.resolve(file, log)?;
    let environment = args.environment.resolve(meta, log, None)?;
    let params = ReferenceParams {
        lights: args.lights.resolve(meta, log, None, environment.is_some())?,
        environment,
        environment_visible: args.background.is_none(),
        medium: args.medium.resolve(meta, log, None)?,
        camera: args.camera.resolve(meta, density.world_bounds(), log, None)?,
        spp: args.spp.unwrap_or(1),
        max_depth: args.max_depth,
        background: args.background.unwrap_or(Vec3::ZERO),
        seed: args.seed.or(meta.seed()).unwrap_or(0),
        aovs: args.aovs,
    };
    params.validate().map_err(Failure::usage)?;
    let device = args.common.compute_device(log)?;
    let blur = velocity.map(Velocity::blur);
    let pixels = params.camera.width() as u64 * params.camera.height() as u64;
    let bar = log.progress("paths", pixels);
    let field = emission.as_ref().map(EmissionGrids::field);
    let fields = MediumFields { emission: field.as_ref(), motion: blur.as_ref() };
    let image = log.stage(
        "path trace",
        || match device.gpu() {
            Some(ctx) => render_reference_gpu_with(ctx, density, &params, fields, reference_tile_pixels(), &|n| bar.inc(n)),
            None => render_reference_cpu_with(density, &params, fields, &|n| bar.inc(n)),
        },
        |r| r.as_ref().map(|i| format!("{}x{} pixels, {} spp", i.width, i.height, params.spp)).unwrap_or_default(),
    );
    bar.finish();
    Ok((image.map_err(|e| march_failure(e, "reference path tracer"))?, emission))
}

/// The marched image from the illumination cache.
fn march(args: &Args, stage: &Stage, velocity: Option<&Velocity>) -> Result<(Image, Option<EmissionGrids>), Failure> {
    let (file, density, meta, log) = (&stage.file, &stage.density, &stage.meta, &stage.log);
    if args.lights.given().is_some() {
        log.warn("--sun/--point are for --reference; the cache's lighting is already baked");
    }
    let cache = IlluminationCache { li_single: read_vec3_grid(file, "Li_single")?, li_multiple: read_vec3_grid(file, "Li_multiple")?, ..Default::default() };
    let emission = args.emission.resolve(file, log)?;
    if cache.li_single.is_none() && cache.li_multiple.is_none() && emission.is_none() {
        log.warn("the input has no illumination cache (Li_single, Li_multiple): the volume renders black over the background (run vdbcache first)");
    }
    let voxel = density.transform().voxel_size();
    let preset = Quality::settings_or_default(args.quality);
    let camera = args.camera.resolve(meta, density.world_bounds(), log, Some("the cache was baked for"))?;
    let params = MarchParams {
        environment: args.environment.resolve(meta, log, Some("the cache was baked with"))?,
        environment_visible: args.background.is_none(),
        medium: args.medium.resolve(meta, log, Some("the cache was baked with"))?,
        spp: args.spp.or(preset.spp).unwrap_or_else(|| default_spp(&camera, density)),
        camera,
        step: args.step.unwrap_or(default_step(density.transform()) * preset.step_factor),
        max_step_factor: args.max_step_factor.unwrap_or(MarchParams::DEFAULT_MAX_STEP_FACTOR),
        background: args.background.unwrap_or(Vec3::ZERO),
        offset_noise: args.offset_noise,
        noise_scale: args.noise_scale.unwrap_or(4.0 * voxel.max_element()),
        noise_octaves: 3,
        noise_eval: Default::default(),
        min_transmittance: args.min_transmittance,
        seed: args.seed.or(meta.seed()).unwrap_or(0),
        aovs: args.aovs,
    };
    params.validate().map_err(Failure::usage)?;
    let device = args.common.compute_device(log)?;
    let blur = velocity.map(Velocity::blur);
    scattered_emission_note(meta, &cache, emission.as_ref(), &params, log);
    let field = emission.as_ref().map(EmissionGrids::field);
    let fields = MediumFields { emission: field.as_ref(), motion: blur.as_ref() };
    let image = log.stage(
        "march",
        || match device.gpu() {
            Some(ctx) => render_gpu_with(ctx, density, &cache, &params, fields, &Default::default()),
            None => render_cpu_with(density, &cache, &params, fields),
        },
        |r| r.as_ref().map(|i| format!("{}x{} pixels, {} spp", i.width, i.height, params.spp)).unwrap_or_default(),
    )
    .map_err(|e| march_failure(e, "GPU ray marcher"));
    Ok((image?, emission))
}

/// Says with -v whether the emission's light scattered by the medium is in the cache, as the
/// cache's `nimbus:emission` records it (vdbcache's paths gather it); warns where the cache
/// holds another emission's light than the march adds, which would light the smoke with one
/// fire and show another.
fn scattered_emission_note(meta: &PipelineMeta, cache: &IlluminationCache, emission: Option<&EmissionGrids>, params: &MarchParams, log: &Log) {
    let marched = emission.map_or("none".to_string(), |e| e.params.describe());
    // A file without Li_multiple (a photon map, say) has no cache to hold it, whatever it records.
    let baked = if cache.li_multiple.is_some() { meta.emission().unwrap_or("none") } else { "none" };
    if baked != "none" && baked != marched {
        log.warn(format!("the cache's light includes emission '{baked}' scattered by the medium, but the march adds '{marched}' (pass the same emission flags to vdbcache and vdbmarch)"));
    } else if emission.is_some() && params.medium.albedo.max_element() > 0.0 {
        log.verbose(if baked == marched {
            "emission: the march adds it and its attenuation; its light scattered by the medium is in the cache, as the cache records"
        } else {
            "emission: the march adds it and its attenuation; its light scattered by the medium is not in the cache (it was baked without emission; --reference includes it)"
        });
    }
}
