//! vdbphoton: density VDB -> the same VDB plus a `photons` points grid, by tracing photons
//! from the lights (and from the medium's emission, a fire's, issue #19) through the
//! nonhomogeneous medium. The engine is `nimbus-photon`; the flags and the record are
//! `nimbus::photon`'s.

use std::path::PathBuf;

use clap::Parser;
use nimbus::photon::{self, TraceArgs};
use nimbus_cli::{CommonArgs, Failure, SequenceArgs, Stage, Tool, VdbOutputArgs};

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
    trace: TraceArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "vdbphoton", vdbphoton, input: input, outputs: [out.output]);

fn vdbphoton(args: Args) -> Result<(), Failure> {
    let mut stage = Stage::open(Args::NAME, &args.common, args.input.as_deref(), args.grid.as_deref())?;
    stage.log.verbose(nimbus_cli::describe_density(&stage.grid, &stage.density));
    let params = args.trace.params(&stage)?;
    let (emission, emission_flags) = args.trace.emission(&stage)?;
    let device = args.common.compute_device(&stage.log)?;
    let (map, stats) = photon::trace(&stage, &device, &params, emission.as_ref())?;
    // The photons replace any earlier photon map; everything else passes through.
    photon::store(&mut stage.file, map)?;
    let carried = photon::carried_emission(emission.as_ref(), &stats);
    let scene = (&params.medium, &params.lights[..], params.environment.as_ref());
    stage.write(Args::NAME, &args.out, scene, &photon::record(&params, &stats), |meta| {
        meta.seed(params.seed)?.emission(&carried)?.emission_flags(&emission_flags)?;
        Ok(())
    })
}
