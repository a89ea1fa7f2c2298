//! vdbphoton: density VDB -> the same VDB plus a `photons` points grid, by tracing photons
//! from the lights (and from the medium's emission, a fire's, issue #19) through the
//! nonhomogeneous medium. The engine is `nimbus-photon`.

use std::path::PathBuf;

use clap::Parser;
use nimbus_cli::{CommonArgs, EmissionArgs, EnvironmentArgs, Failure, LightArgs, MediumArgs, Quality, SequenceArgs, Stage, Tool, VdbOutputArgs};
use nimbus_photon::{trace_cpu_emitting, trace_gpu_emitting, DistanceSampling, PhotonError, PhotonParams};
use nimbus_vdb::PointSet;

#[derive(Parser, Debug, Clone)]
#[command(
    name = "vdbphoton",
    version,
    about = "Density VDB -> photon map (OpenVDB points) by photon tracing",
    after_help = "Example (the paper's photon-map chain):\n  particles2vdb smoke.ply --voxel-size 2 | vdbphoton --sun dir=0.5,0.3,-0.8,irradiance=4 --extinction 30 | vdbcache --gather-neighbours 64 | vdbmarch -o smoke.exr"
)]
struct Args {
    /// Input VDB with a fog volume, or - for stdin. [default: stdin when it is not a terminal]
    #[arg(help_heading = "Input")]
    input: Option<PathBuf>,
    /// The density grid. [default: what the input records, else density]
    #[arg(long, help_heading = "Input")]
    grid: Option<String>,
    #[command(flatten)]
    out: VdbOutputArgs,
    #[command(flatten)]
    medium: MediumArgs,
    #[command(flatten)]
    lights: LightArgs,
    /// The sky or environment map: photons also leave it, stored from their first interaction.
    #[command(flatten)]
    environment: EnvironmentArgs,
    /// Free-path sampling: delta (delta tracking, unbiased: 1.4-2.1x more
    /// accurate than simpson at equal time), simpson (the paper's Eq. 2) or exponential
    /// (Eq. 1, biased); the last two for comparison. [default: delta]
    #[arg(long, help_heading = "Quality")]
    distance: Option<DistanceSampling>,
    /// Simpson step (and exponential search step), as a fraction of the smallest voxel edge;
    /// delta tracking takes none.
    #[arg(long, default_value_t = 0.5, help_heading = "Quality")]
    step: f64,
    /// Photons to store. [default: the --quality preset's, else 200000]
    #[arg(long, help_heading = "Quality")]
    photons: Option<u64>,
    /// Preset: draft, preview or final (photon count and distance mode; flags override).
    #[arg(long, value_enum, help_heading = "Quality")]
    quality: Option<Quality>,
    /// Stop emitting after this many photons even if fewer were stored.
    #[arg(long, default_value_t = 50_000_000, help_heading = "Quality")]
    max_emitted: u64,
    /// Interactions after which a path ends.
    #[arg(long, default_value_t = 64, help_heading = "Quality")]
    max_interactions: u32,
    /// Random seed. [default: what the input records, else 0]
    #[arg(long, help_heading = "Quality")]
    seed: Option<u64>,
    /// The medium's emission: photons also leave the emitting voxels, stored from their first
    /// interaction on (a fire lights its own smoke through the photon gather).
    #[command(flatten)]
    emission: EmissionArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "vdbphoton", vdbphoton, input: input, outputs: [out.output]);

fn vdbphoton(args: Args) -> Result<(), Failure> {
    let mut stage = Stage::open(Args::NAME, &args.common, args.input.as_deref(), args.grid.as_deref())?;
    let log = &stage.log;
    log.verbose(nimbus_cli::describe_density(&stage.grid, &stage.density));
    let preset = args.quality.map(Quality::settings);
    let (medium, lights, environment) = stage.scene(&args.medium, &args.lights, &args.environment, None)?;
    let params = PhotonParams {
        medium,
        lights,
        environment,
        distance: match (args.distance, preset) {
            (Some(d), _) => d,
            (None, Some(q)) => q.distance.parse().map_err(Failure::usage)?,
            (None, None) => PhotonParams::default().distance,
        },
        step: args.step,
        photons: args.photons.or(preset.map(|q| q.photons)).unwrap_or(200_000),
        max_emitted: args.max_emitted,
        max_interactions: args.max_interactions,
        seed: args.seed.or(stage.meta.seed()).unwrap_or(0),
    };
    params.validate().map_err(|e| Failure::usage(e))?;
    let emission = args.emission.resolve(&stage.file, log)?;
    let device = args.common.compute_device(log)?;
    let field = emission.as_ref().map(|e| e.field());
    let traced = log.stage(
        "trace",
        || match device.gpu() {
            Some(ctx) => trace_gpu_emitting(ctx, &stage.density, &params, field.as_ref()),
            None => trace_cpu_emitting(&stage.density, &params, field.as_ref()),
        },
        |r| {
            r.as_ref()
                .map(|(_, s)| {
                    format!(
                        "emitted {}, stored {}, escaped {}, absorbed {}, cut {}, {:.2} interactions per photon",
                        s.emitted, s.stored, s.escaped, s.absorbed, s.truncated, s.mean_interactions()
                    )
                })
                .unwrap_or_default()
        },
    );
    let (map, stats) = traced.map_err(|e| match e {
        PhotonError::Param(_) => Failure::usage(e),
        PhotonError::Gpu(_) => Failure::runtime(e, "GPU photon tracer"),
    })?;
    if let Some(why) = &stats.skipped {
        log.warn(format!("no photons traced: {why}; writing an empty photon map"));
    } else if stats.stored < params.photons {
        log.warn(format!("stored {} of {} photons before --max-emitted {} was reached", stats.stored, params.photons, params.max_emitted));
    }

    // The photons replace any earlier photon map; everything else passes through.
    stage.file.remove_grid("photons");
    let points = PointSet::new(map.positions).with_vec3("power", map.power).with_vec3("dir", map.dir);
    stage.file.insert_points("photons", &points, None).map_err(|e| Failure::runtime(e, "photons grid"))?;
    let record = [
        ("distance", params.distance.name().to_string()),
        ("step", params.step.to_string()),
        ("photons", params.photons.to_string()),
        ("max_emitted", params.max_emitted.to_string()),
        ("max_interactions", params.max_interactions.to_string()),
        ("emitted", stats.emitted.to_string()),
        ("stored", stats.stored.to_string()),
        ("escaped", stats.escaped.to_string()),
        ("absorbed", stats.absorbed.to_string()),
        ("truncated", stats.truncated.to_string()),
        ("interactions", stats.interactions.to_string()),
    ];
    let scene = (&params.medium, &params.lights[..], params.environment.as_ref());
    stage.write(Args::NAME, &args.out, scene, &record, |meta| {
        meta.seed(params.seed)?
            // The emission the photons carry (vdbcache's photon gather holds it scattered).
            .emission(&match (&emission, &stats.skipped) {
                (Some(e), None) => e.params.describe(),
                _ => "none".to_string(),
            })?;
        Ok(())
    })
}
