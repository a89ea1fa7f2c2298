//! nimbus-render: the whole chain over a frame sequence in one command, for a shell or a
//! render-farm task (issue #20):
//!
//!     nimbus-render 'smoke.$F4.ply' -o 'frames/smoke.$F4.exr' --frames 1-240
//!
//! Each frame runs `particles2vdb | vdbcache | vdbmarch` (with `--photons`,
//! `particles2vdb | vdbphoton | vdbcache | vdbmarch`; a density `.vdb` input skips
//! particles2vdb) as the sibling binaries beside this executable, piped stage to stage, so no
//! intermediate file is written; with `--keep-intermediates DIR` the stages run one after
//! another through `DIR/<output stem>.density.vdb` (`.photons.vdb`, `.cache.vdb`) instead.
//! The flags several tools take are given once here and passed to the first tool that uses
//! them; the tools record them in the file's metadata for the next (design.md section 6):
//! lights, sky, environment and medium to vdbphoton or else vdbcache, the camera to
//! vdbcache, the seed to the first tool (and to vdbmarch after a vdbcache that starts the
//! chain, as vdbcache does not record it); `--quality`, `--device`, `-q`, `-v` to every tool
//! that takes them. Anything else goes through `--<tool> 'ARGS'`.
//!
//! The flags and the chain are `nimbus::render`'s.
//!
//! Exit code 0 when every frame was done (or skipped with `--skip-existing`), 1 when any
//! frame failed (listed on the last line), 2 for bad usage.

use std::process::ExitCode;

use nimbus::render::{with_shared_flags, Args, Chain};
use nimbus_cli::{for_each_frame, run, Failure};

fn main() -> ExitCode {
    let args = with_shared_flags(nimbus_cli::parse_args::<Args>());
    run(move || nimbus_render(args))
}

fn nimbus_render(args: Args) -> Result<(), Failure> {
    let log = args.common.log("nimbus-render");
    if let (Some(size), Some(frames)) = (args.print_chunks, &args.sequence.frames) {
        if size == 0 {
            return Err(Failure::usage("--print-chunks takes a chunk size >= 1"));
        }
        for chunk in frames.chunks(size) {
            println!("{chunk}");
        }
        return Ok(());
    }
    let chain = Chain::new(&args)?;
    let verbosity = log.verbosity();
    drop(log);
    for_each_frame("nimbus-render", &args.sequence, verbosity, Some(&args.input), &chain.outputs(&args), |input, outputs| {
        chain.frame(&args, input, outputs, verbosity)
    })
}
