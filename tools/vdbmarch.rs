//! vdbmarch: cache VDB -> EXR image (and PNG preview), by ray marching the density with
//! illumination-cache lookups; with `--reference`, density VDB -> EXR by an unbiased path
//! tracer (the ground truth, needing no photons or cache). The engine is `nimbus-march`;
//! the flags and their parameters are `nimbus::march`'s.

use std::path::PathBuf;

use clap::Parser;
use nimbus::march::{PreviewArgs, RenderArgs};
use nimbus_cli::{CommonArgs, Failure, Input, Output, SequenceArgs, Stage, Tool};

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
    #[command(flatten)]
    look: PreviewArgs,
    #[command(flatten)]
    render: RenderArgs,
    #[command(flatten)]
    sequence: SequenceArgs,
    #[command(flatten)]
    common: CommonArgs,
}

nimbus_cli::tool!(Args, "vdbmarch", vdbmarch, input: input, outputs: [output, look.preview]);

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
    let image = args.render.render(&stage, &args.common)?;
    let exr = image.to_exr().map_err(|e| Failure::runtime(e, output.name()))?;
    log.stage("write", || output.write(&exr), |_| String::new())?;
    args.look.write(&image)?;
    log.finish();
    Ok(())
}
