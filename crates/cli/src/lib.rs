//! What the four nimbus tools share as command-line programs (design.md sections 6 and 7).
//!
//! - [`Input`] / [`Output`]: a path or `-`, defaulting to stdin/stdout when they are not
//!   terminals, so the tools pipe into each other. Outputs to a path are written to a temporary
//!   name beside the target and renamed when complete: a failed run leaves no partial file.
//! - [`Failure`]: the one-line `error: <what> (<where>)` and the exit code, 2 for bad usage or
//!   bad input, 1 for failures while running. [`run`] turns a tool's result into the process
//!   exit code and never lets a panic message be the last word.
//! - [`Log`]: `-q` / `-v`, warnings, per-stage timings and counts, and progress bars that
//!   appear only when stderr is a terminal.
//! - Shared flags ([`CommonArgs`], [`MediumArgs`], [`LightArgs`], [`CameraArgs`],
//!   [`VdbOutputArgs`]) and the pipeline's metadata ([`PipelineMeta`], [`MetaWriter`]): what
//!   one tool records, the next takes as its defaults; a flag overrides, with a warning
//!   where that makes earlier work inconsistent.
//! - [`EmissionArgs`]: the emission flags and the recognition of fire grids, the same in
//!   vdbphoton, vdbcache and vdbmarch.
//! - [`MotionArgs`]: vdbmarch's motion blur flags and the velocity grid they find.
//! - [`SequenceArgs`] and [`for_each_frame`] ([`frames`]): frame patterns (`####`, `%04d`,
//!   `$F4`), `--frames` sets, and the per-frame loop every tool runs over a sequence.
//! - [`Tool`], [`main`] and [`Stage`]: the runner: a tool's `main`, its frames, and a stage's
//!   read of the chain's VDB, its scene ([`SceneArgs`] over what the chain recorded) and
//!   write of what it added with its record.

mod args;
mod environment;
mod emission;
mod failure;
pub mod frames;
mod io;
mod log;
pub mod meta;
mod motion;
mod runner;
mod vdbio;

pub use args::{command, fit_view, given_flags, parse_args, parse_args_from, parse_direction, parse_dvec3, parse_rgb, setting_source, CameraArgs, CommonArgs, LightArgs, MediumArgs, Quality, QualitySettings, VdbOutputArgs};
pub use environment::{read_environment_map, EnvironmentArgs};
pub use emission::{EmissionArgs, EmissionGrids};
pub use failure::{run, Failure, ResultExt};
pub use frames::{for_each_frame, FramePattern, FrameSet, SequenceArgs};
pub use io::{write_atomic, Input, Output};
pub use log::{Log, Progress, StageTimes, Verbosity};
pub use meta::{MetaWriter, PipelineMeta};
pub use motion::{MotionArgs, Velocity, VELOCITY_GRIDS};
pub use runner::{main, SceneArgs, Stage, Tool};
pub use vdbio::{describe_density, read_density, UPSTREAM_FAILED, read_vdb, read_vec3_grid, write_vdb};
