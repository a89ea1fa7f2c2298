//! vdbcache: photon VDB -> the same VDB plus `Li_single` and `Li_multiple` grids, the
//! illumination cache baked for the camera. The engine is `nimbus-cache`; the flags, the
//! photons read and the grids and record written are `nimbus::cache`'s.

use std::path::PathBuf;

use clap::Parser;
use nimbus::cache::{self, BakeArgs};
use nimbus_cli::{CommonArgs, Failure, SequenceArgs, Stage, Tool, VdbOutputArgs};

#[derive(Parser, Debug, Clone)]
#[command(
    name = "vdbcache",
    version,
    about = "Density (or photon) VDB -> illumination cache grids (single + multiple scattering) baked for a camera",
    after_help = "Example:\n  particles2vdb smoke.ply --voxel-size 2 | vdbcache --extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4 --sky 0.15,0.25,0.45 --view-dir 0,1,-0.3 | vdbmarch -o smoke.exr --preview smoke.png"
)]
struct Args {
    /// Input VDB: any fog volume (or vdbphoton's output), or - for stdin. [default: stdin
    /// when it is not a terminal]
    #[arg(help_heading = "Input")]
    input: Option<PathBuf>,
    /// The density grid. [default: what the input records, else density]
    #[arg(long, help_heading = "Input")]
    grid: Option<String>,
    #[command(flatten)]
    out: VdbOutputArgs,
    #[command(flatten)]
    bake: BakeArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "vdbcache", vdbcache, input: input, outputs: [out.output]);

fn vdbcache(args: Args) -> Result<(), Failure> {
    let mut stage = Stage::open(Args::NAME, &args.common, args.input.as_deref(), args.grid.as_deref())?;
    let photons = cache::read_photons(&stage.file)?;
    stage.log.verbose(format!("{}; {} photons", nimbus_cli::describe_density(&stage.grid, &stage.density), photons.len()));
    let params = args.bake.params(&stage, &photons)?;
    let (emission, emission_flags) = args.bake.emission(&stage, &params)?;
    let device = args.common.compute_device(&stage.log)?;
    let (baked, stats) = cache::bake(&stage, &device, &photons, &params, emission.as_ref())?;
    cache::store(&mut stage.file, &baked, params.lights.len(), args.bake.keep_photons)?;
    let record = cache::record(&params, &stats, &baked);
    let scattered = cache::scattered_emission(&stage, &params, &baked, emission.as_ref());
    let scene = (&params.medium, &params.lights[..], params.environment.as_ref());
    stage.write(Args::NAME, &args.out, scene, &record, |meta| {
        meta.camera(&params.camera)?.seed(params.seed)?.emission(&scattered)?.emission_flags(&emission_flags)?;
        Ok(())
    })
}
