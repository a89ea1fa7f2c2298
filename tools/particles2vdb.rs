//! particles2vdb: particles (PLY, CSV/TSV, OpenVDB points) -> a `density` fog volume, by SPH
//! density estimation with adaptive smoothing lengths. The engine is `nimbus-density`; the
//! flags, the particles read and the grids and record written are `nimbus::particles`'s.

use std::path::PathBuf;

use clap::Parser;
use nimbus::particles::{EstimateArgs, ParticleArgs};
use nimbus_cli::{CommonArgs, Failure, Input, MetaWriter, SequenceArgs, Tool, VdbOutputArgs};

#[derive(Parser, Debug, Clone)]
#[command(
    name = "particles2vdb",
    version,
    about = "Particles -> OpenVDB density grid by adaptive SPH density estimation",
    after_help = "Examples:\n  particles2vdb smoke.ply --voxel-size 2 | vdbcache --sun dir=0.5,0.3,-0.8,irradiance=4 | vdbmarch -o smoke.exr --preview smoke.png\n  particles2vdb 'smoke.$F4.ply' --frames 1-240 --voxel-size 2 -o 'density/smoke.$F4.vdb'"
)]
struct Args {
    /// Particle file (.ply, .csv, .tsv, .vdb with points), or - for stdin. [default: stdin
    /// when it is not a terminal]
    #[arg(help_heading = "Input")]
    input: Option<PathBuf>,
    #[command(flatten)]
    particles: ParticleArgs,
    #[command(flatten)]
    out: VdbOutputArgs,
    #[command(flatten)]
    estimate: EstimateArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "particles2vdb", particles2vdb, input: input, outputs: [out.output]);

fn particles2vdb(args: Args) -> Result<(), Failure> {
    let log = args.common.log(Args::NAME);
    let input = Input::from_arg(args.input.as_deref())?;
    let format = args.particles.format(&input)?;
    let estimate = args.estimate.params(args.particles.mass)?;
    // auto picks a hardware GPU only; --device gpu also takes a software one (lavapipe).
    let device = args.common.compute_device(&log)?;
    let particles = args.particles.read(&log, &input, format, &estimate.params)?;
    let output = estimate.run(&log, &device, &particles, &input, args.estimate.stats)?;
    let mut file = estimate.grids(&output)?;
    let record = estimate.record(&output);
    MetaWriter::new(&mut file).density_grid("density")?.seed(args.estimate.seed)?.tool(Args::NAME, &record, &log.times())?;
    log.stage("write", || nimbus_cli::write_vdb(&file, &args.out), |_| String::new())?;
    log.finish();
    Ok(())
}
