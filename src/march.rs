//! vdbmarch's flags: the ray marcher's (and the reference path tracer's) parameters from
//! the flags, the cache's metadata and the --quality preset, and the PNG preview's look.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use glam::Vec3;
use nimbus_cache::IlluminationCache;
use nimbus_cli::{parse_rgb, read_vec3_grid, CameraArgs, CommonArgs, EmissionArgs, EmissionGrids, EnvironmentArgs, Failure, LightArgs, Log, MediumArgs, MotionArgs, Output, PipelineMeta, Quality, Stage, Velocity};
use nimbus_march::{default_spp, default_step, step_subdivision, STEP_OPTICAL_DEPTH, reference_tile_pixels, Image, MarchError, MarchParams, ReferenceParams, ViewTransform};
use nimbus_march::{render_cpu_with, render_gpu_with, render_reference_cpu_with, render_reference_gpu_with, DirectSingle, MediumFields};
use nimbus_march::{verify_cpu, Verification, VerifyParams};

/// `--view`: Blender's view transforms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum View {
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

/// `--single`: where the march takes single scattering from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SingleSource {
    /// Shadow rays where vdbcache found no Li_single lattice would do (it records
    /// `single_direct=true`), else the cache.
    Auto,
    /// The cache's Li_single, read by trilinear interpolation.
    Cache,
    /// A Simpson shadow ray toward each light at every sample (the CPU march).
    Direct,
}

/// The PNG preview's flags.
#[derive(Args, Debug, Clone)]
pub struct PreviewArgs {
    /// Also write an 8-bit sRGB PNG preview here (RGB, over the background; no alpha).
    #[arg(long, value_name = "FILE.png", help_heading = "Output")]
    pub preview: Option<PathBuf>,
    /// Preview exposure in stops: the scene values are multiplied by 2^EV before the view
    /// transform, as Blender's Exposure (the EXR is not changed).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, help_heading = "Output")]
    exposure: f32,
    /// The preview's view transform, as Blender's colour management shows an image on an
    /// sRGB display (the EXR stays linear, scene-referred, and does not record it).
    #[arg(long, value_enum, default_value_t = View::Agx, help_heading = "Output")]
    view: View,
}

impl PreviewArgs {
    /// Writes the preview of `image`, where one is asked for.
    pub fn write(&self, image: &Image) -> Result<(), Failure> {
        if let Some(png_path) = &self.preview {
            let png = image.to_png(self.exposure, self.view.into()).map_err(|e| Failure::runtime(e, png_path.display()))?;
            Output::Path(png_path.clone()).write(&png)?;
        }
        Ok(())
    }
}

/// vdbmarch's flags for the image itself, between the preview's and the sequence's.
#[derive(Args, Debug, Clone)]
pub struct RenderArgs {
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
    /// After the march, path-trace a sample of the image's 2x2 blocks with the reference
    /// tracer (the same scene, the truth's own noise traced under a third of --verify-target
    /// and taken out) and report the image's relative RMSE over the covered blocks and its
    /// mean ratio, with ~95% intervals: on stderr and as the EXR header's nimbus:verify. On
    /// the CPU whatever --device; costs about a reference of the sampled blocks at a few
    /// thousand paths a pixel.
    #[arg(long, help_heading = "Quality")]
    verify: bool,
    /// With --verify: how many 2x2 blocks (pixels with --verify-block 1) to path-trace, drawn
    /// uniformly from those the volume covers (all of them where there are fewer).
    #[arg(long, value_name = "N", default_value_t = VerifyParams::DEFAULT_SAMPLES, requires = "verify", help_heading = "Quality")]
    verify_pixels: u32,
    /// With --verify: the side of the blocks scored, 2 (as nimbus-compare scores) or 1.
    #[arg(long, value_name = "PIXELS", default_value_t = VerifyParams::DEFAULT_BLOCK, requires = "verify", help_heading = "Quality")]
    verify_block: u32,
    /// With --verify: the relative RMSE to resolve; each block's truth is traced until its
    /// noise is under a third of it (relative to the covered blocks' mean).
    #[arg(long, value_name = "FRACTION", default_value_t = VerifyParams::DEFAULT_TARGET, requires = "verify", help_heading = "Quality")]
    verify_target: f64,
    /// With --verify: most paths per pixel the truth takes.
    #[arg(long, value_name = "N", default_value_t = VerifyParams::DEFAULT_MAX_SPP, requires = "verify", help_heading = "Quality")]
    verify_max_spp: u32,
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
    /// --quality preset's, else enough for a pixel's samples to lie a quarter of a density
    /// voxel apart at the volume, 1 to 64 (8 x 8); 1 with --reference]
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
    /// Where single scattering comes from: the cache's Li_single, or shadow rays toward the
    /// lights at every sample (exact, a shadow ray per sample and light; the CPU march), or
    /// auto: shadow rays where vdbcache found that no Li_single lattice would do (a thin rim
    /// lit from behind), else the cache.
    #[arg(long, value_enum, default_value_t = SingleSource::Auto, help_heading = "Quality")]
    single: SingleSource,
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
}

impl RenderArgs {
    /// The image of `stage`'s volume: marched from its cache, or with --reference path
    /// traced; its metadata says what motion blur and emission it holds.
    pub fn render(&self, stage: &Stage, common: &CommonArgs) -> Result<Image, Failure> {
        let log = &stage.log;
        if self.verify && self.reference {
            return Err(Failure::usage("--verify checks the marched image against the reference tracer; it cannot be used with --reference"));
        }
        let velocity = self.motion.resolve(&stage.file, log)?;
        let (mut image, emission) =
            if self.reference { self.reference(stage, common, velocity.as_ref())? } else { self.march(stage, common, velocity.as_ref())? };
        if self.verify {
            let v = self.verify(&image, stage, velocity.as_ref(), emission.as_ref())?;
            image.metadata.push(("nimbus:verify".into(), v.attribute()));
            log.note(format!("verify: {}", v.summary()));
        }
        image.metadata.push(("nimbus:motion_blur".into(), velocity.as_ref().map_or("none".into(), |v| v.describe())));
        // What emission the image holds, as the pipeline records its parameters (design.md
        // section 6): `none`, or `nimbus_optics::Emission::describe`'s text.
        image.metadata.push(("nimbus:emission".into(), emission.as_ref().map_or("none".into(), |e| e.params.describe())));
        if image.nonfinite > 0 {
            log.warn(format!("{} pixels came out non-finite and were set to zero", image.nonfinite));
        }
        Ok(image)
    }

    /// The path-traced ground truth: medium, lights and camera from flags, else the file.
    fn reference(&self, stage: &Stage, common: &CommonArgs, velocity: Option<&Velocity>) -> Result<(Image, Option<EmissionGrids>), Failure> {
        let (file, density, meta, log) = (&stage.file, &stage.density, &stage.meta, &stage.log);
        let march_only = [
            (self.step.is_some(), "--step"),
            (self.max_step_factor.is_some(), "--max-step-factor"),
            (self.offset_noise != 0.0, "--offset-noise"),
            (self.noise_scale.is_some(), "--noise-scale"),
            (self.quality.is_some(), "--quality"),
        ];
        for (given, flag) in march_only {
            if given {
                log.warn(format!("{flag} is for ray marching; the reference path tracer ignores it"));
            }
        }
        let (emission, _) = self.emission.resolve_over(file, meta, log)?;
        let params = ReferenceParams { spp: self.spp.unwrap_or(1), max_depth: self.max_depth, aovs: self.aovs, ..self.reference_scene(stage)? };
        params.validate().map_err(Failure::usage)?;
        let device = common.compute_device(log)?;
        let blur = velocity.map(Velocity::blur);
        let pixels = params.camera.width() as u64 * params.camera.height() as u64;
        let bar = log.progress("paths", pixels);
        let field = emission.as_ref().map(EmissionGrids::field);
        let fields = MediumFields { emission: field.as_ref(), motion: blur.as_ref(), ..MediumFields::default() };
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

    /// The scene the reference tracer renders, `--reference`'s and `--verify`'s truth: medium,
    /// lights, environment and camera from the flags over the file's record; one path a
    /// pixel, the default depth, no layers.
    fn reference_scene(&self, stage: &Stage) -> Result<ReferenceParams, Failure> {
        let (density, meta, log) = (&stage.density, &stage.meta, &stage.log);
        let environment = self.environment.resolve(meta, log, None)?;
        Ok(ReferenceParams {
            lights: self.lights.resolve(meta, log, None, environment.is_some())?,
            environment,
            environment_visible: self.background.is_none(),
            medium: self.medium.resolve(meta, log, None)?,
            camera: self.camera.resolve(meta, density.world_bounds(), log, None)?,
            spp: 1,
            max_depth: ReferenceParams::DEFAULT_MAX_DEPTH,
            background: self.background.unwrap_or(Vec3::ZERO),
            seed: self.seed.or(meta.seed()).unwrap_or(0),
            aovs: false,
        })
    }

    /// `--verify`: `image`'s error against the reference tracer over a sample of its blocks
    /// (nimbus_march::verify_cpu), the scene as the march and `--reference` resolve it.
    fn verify(&self, image: &Image, stage: &Stage, velocity: Option<&Velocity>, emission: Option<&EmissionGrids>) -> Result<Verification, Failure> {
        let (density, log) = (&stage.density, &stage.log);
        if self.offset_noise != 0.0 {
            log.warn("--offset-noise moves the medium the march reads; --verify's truth is the density as it is, so its error includes what the noise changes");
        }
        let params = self.reference_scene(stage)?;
        let opts = VerifyParams { samples: self.verify_pixels, block: self.verify_block, target: self.verify_target, max_spp: self.verify_max_spp, ..VerifyParams::default() };
        opts.validate().map_err(Failure::usage)?;
        let blur = velocity.map(Velocity::blur);
        let field = emission.map(EmissionGrids::field);
        let fields = MediumFields { emission: field.as_ref(), motion: blur.as_ref(), ..MediumFields::default() };
        // The GPU's reference renders whole images in pixel ranges; a sample of blocks is
        // traced on the CPU whatever --device (design.md section 5).
        let v = log.stage("verify", || verify_cpu(image, density, &params, fields, &opts), |r| match r {
            Ok(v) => format!(
                "{} blocks of {}x{} (on the CPU), {} paths, {}-{} a pixel{}; the truth's own noise {:.2}%",
                v.drawn,
                v.block,
                v.block,
                v.paths,
                v.spp_range.0,
                v.spp_range.1,
                if v.capped > 0 { format!(", {} blocks stopped at --verify-max-spp", v.capped) } else { String::new() },
                v.estimate.map_or(f64::NAN, |e| 100.0 * e.truth_noise)
            ),
            Err(_) => String::new(),
        });
        v.map_err(|e| march_failure(e, "verification"))
    }

    /// The marched image from the illumination cache.
    fn march(&self, stage: &Stage, common: &CommonArgs, velocity: Option<&Velocity>) -> Result<(Image, Option<EmissionGrids>), Failure> {
        let (file, density, meta, log) = (&stage.file, &stage.density, &stage.meta, &stage.log);
        if self.lights.given().is_some() {
            log.warn("--sun/--point are for --reference; the cache's lighting is already baked");
        }
        let cache = IlluminationCache { li_single: read_vec3_grid(file, "Li_single")?, li_multiple: read_vec3_grid(file, "Li_multiple")?, ..Default::default() };
        let (emission, _) = self.emission.resolve_over(file, meta, log)?;
        if cache.li_single.is_none() && cache.li_multiple.is_none() && emission.is_none() {
            log.warn("the input has no illumination cache (Li_single, Li_multiple): the volume renders black over the background (run vdbcache first)");
        }
        let voxel = density.transform().voxel_size();
        let preset = Quality::settings_or_default(self.quality);
        let camera = self.camera.resolve(meta, density.world_bounds(), log, Some("the cache was baked for"))?;
        let medium = self.medium.resolve(meta, log, Some("the cache was baked with"))?;
        // The default step, cut where the medium is dense (nimbus_march::step_subdivision);
        // an explicit --step is marched as given.
        let step = self.step.unwrap_or(default_step(density.transform()) * preset.step_factor);
        let subdivision = match self.step {
            Some(_) => 1,
            None => step_subdivision(step, medium.extinction, density.peak().max(0.0)),
        };
        if subdivision > 1 {
            log.verbose(format!("march step: {:.6}, a {subdivision}th of the default {step:.6}: the densest medium holds optical depth {STEP_OPTICAL_DEPTH} a step", step / subdivision as f64));
        }
        let params = MarchParams {
            environment: self.environment.resolve(meta, log, Some("the cache was baked with"))?,
            environment_visible: self.background.is_none(),
            medium,
            spp: self.spp.or(preset.spp).unwrap_or_else(|| default_spp(&camera, density)),
            camera,
            step: step / subdivision as f64,
            max_step_factor: self.max_step_factor.unwrap_or(MarchParams::DEFAULT_MAX_STEP_FACTOR),
            background: self.background.unwrap_or(Vec3::ZERO),
            offset_noise: self.offset_noise,
            noise_scale: self.noise_scale.unwrap_or(4.0 * voxel.max_element()),
            noise_octaves: 3,
            noise_eval: Default::default(),
            min_transmittance: self.min_transmittance,
            seed: self.seed.or(meta.seed()).unwrap_or(0),
            aovs: self.aovs,
        };
        params.validate().map_err(Failure::usage)?;
        let device = common.compute_device(log)?;
        let blur = velocity.map(Velocity::blur);
        scattered_emission_note(meta, &cache, emission.as_ref(), &params, log);
        let field = emission.as_ref().map(EmissionGrids::field);
        let lights = match self.single {
            SingleSource::Cache => None,
            SingleSource::Auto if meta.tool_value("vdbcache", "single_direct").as_deref() != Some("true") => None,
            // The lights the cache was baked with (a --sun here is the reference's).
            _ => Some(meta.lights()?.unwrap_or_default()),
        };
        let direct = lights.as_ref().map(|lights| DirectSingle::new(density, lights));
        if direct.is_some() {
            log.verbose(format!(
                "single scattering: shadow rays toward the lights at every sample ({})",
                if self.single == SingleSource::Direct { "--single direct" } else { "the cache records that no Li_single lattice would do" }
            ));
        }
        let fields = MediumFields { emission: field.as_ref(), motion: blur.as_ref(), direct_single: direct.as_ref() };
        let gpu = device.gpu().filter(|_| {
            if direct.is_some() {
                log.note("single scattering by shadow rays at every sample runs on the CPU march: the march takes the CPU");
            }
            direct.is_none()
        });
        let image = log
            .stage(
                "march",
                || match gpu {
                    Some(ctx) => render_gpu_with(ctx, density, &cache, &params, fields, &Default::default()),
                    None => render_cpu_with(density, &cache, &params, fields),
                },
                |r| r.as_ref().map(|i| format!("{}x{} pixels, {} spp", i.width, i.height, params.spp)).unwrap_or_default(),
            )
            .map_err(|e| march_failure(e, "GPU ray marcher"));
        Ok((image?, emission))
    }
}

fn march_failure(e: MarchError, what: &str) -> Failure {
    match e {
        MarchError::Param(_) => Failure::usage(e),
        MarchError::Gpu(_) => Failure::runtime(e, what),
    }
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
