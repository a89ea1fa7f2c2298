//! The runner the tools share: parse the flags, run once or over a sequence's frames, and,
//! for the stages between VDBs, read the density and metadata the chain passed on and write
//! back what the stage added with its record. A tool keeps only its flags and its stage.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use nimbus_optics::{Environment, Light, Medium};
use nimbus_vdb::VdbFile;
use nimbus_volume::Volume;

use crate::{
    for_each_frame, parse_args, read_density, read_vdb, run, write_vdb, CommonArgs, EnvironmentArgs, Failure, Input, LightArgs, Log, MediumArgs,
    MetaWriter, PipelineMeta, SequenceArgs, VdbOutputArgs, Verbosity,
};

/// A tool's flags, as the runner needs them.
pub trait Tool: clap::Parser + Clone + std::panic::UnwindSafe {
    /// The name in messages and metadata.
    const NAME: &'static str;
    fn shared(&self) -> (&CommonArgs, &SequenceArgs);
    /// The input and the outputs, the main one first, then any others (a preview): a
    /// sequence sets each to its frame's name.
    fn names(&mut self) -> (&mut Option<PathBuf>, Vec<&mut Option<PathBuf>>);
    /// One run (one frame).
    fn run(self) -> Result<(), Failure>;
}

/// A tool's `main`: its flags, then its run on each frame, as an exit code.
pub fn main<T: Tool>() -> ExitCode {
    let (mut args, _) = parse_args::<T>();
    let (input, outputs) = args.names();
    let input = input.clone();
    let outputs: Vec<Option<PathBuf>> = outputs.into_iter().map(|o| o.clone()).collect();
    run(move || {
        let (common, sequence) = args.shared();
        let verbosity = Verbosity::from_flags(common.quiet, common.verbose);
        let given: Vec<Option<&Path>> = outputs.iter().map(Option::as_deref).collect();
        for_each_frame(T::NAME, sequence, verbosity, input.as_deref(), &given, |input, outputs| {
            let mut frame = args.clone();
            let (frame_input, frame_outputs) = frame.names();
            *frame_input = input;
            for (name, output) in frame_outputs.into_iter().zip(outputs) {
                *name = output;
            }
            frame.run()
        })
    })
}

/// A tool's `main` and its [`Tool`] impl, from where its flags keep the input and the
/// outputs (field paths; `common` and `sequence` are the shared flags' fields), e.g.
/// `tool!(Args, "vdbmarch", vdbmarch, input: input, outputs: [output, preview])`.
#[macro_export]
macro_rules! tool {
    ($args:ident, $name:literal, $run:path, input: $input:ident, outputs: [$($($out:ident).+),+ $(,)?]) => {
        fn main() -> ::std::process::ExitCode {
            $crate::main::<$args>()
        }

        impl $crate::Tool for $args {
            const NAME: &'static str = $name;
            fn shared(&self) -> (&$crate::CommonArgs, &$crate::SequenceArgs) {
                (&self.common, &self.sequence)
            }
            fn names(&mut self) -> (&mut Option<::std::path::PathBuf>, Vec<&mut Option<::std::path::PathBuf>>) {
                (&mut self.$input, vec![$(&mut self.$($out).+),+])
            }
            fn run(self) -> Result<(), $crate::Failure> {
                $run(self)
            }
        }
    };
}

/// The scene's flags, as the stages that light the volume take them (vdbphoton, vdbcache):
/// the medium, the lights, the sky or environment map.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct SceneArgs {
    #[command(flatten)]
    pub medium: MediumArgs,
    #[command(flatten)]
    pub lights: LightArgs,
    #[command(flatten)]
    pub environment: EnvironmentArgs,
}

/// What a stage between VDBs reads first: the input file, its density grid and what the
/// tools before it recorded.
pub struct Stage {
    pub log: Log,
    pub file: VdbFile,
    /// The density grid's name.
    pub grid: String,
    pub density: Volume<f32>,
    pub meta: PipelineMeta,
}

impl Stage {
    /// Reads `input` (timed as the stage `read`) and its density grid (`--grid`).
    pub fn read(log: Log, input: &Input, grid: Option<&str>) -> Result<Stage, Failure> {
        let file = log.stage("read", || read_vdb(input), |_| String::new())?;
        let (grid, density) = read_density(&file, grid)?;
        let meta = PipelineMeta::of(&file);
        Ok(Stage { log, file, grid, density, meta })
    }

    /// [`Stage::read`] of the input flag, with the tool's log.
    pub fn open(tool: &'static str, common: &CommonArgs, input: Option<&Path>, grid: Option<&str>) -> Result<Stage, Failure> {
        let log = common.log(tool);
        let input = Input::from_arg(input)?;
        Stage::read(log, &input, grid)
    }

    /// The scene flags over what the file records: `consistency` names what earlier work used
    /// the recorded scene for, so that a differing flag draws a warning. The environment comes
    /// first: where it lights the scene, no default sun is added.
    pub fn scene(&self, scene: &SceneArgs, consistency: Option<&str>) -> Result<(Medium, Vec<Light>, Option<Environment>), Failure> {
        let environment = scene.environment.resolve(&self.meta, &self.log, consistency)?;
        let medium = scene.medium.resolve(&self.meta, &self.log, consistency)?;
        let lights = scene.lights.resolve(&self.meta, &self.log, consistency, environment.is_some())?;
        Ok((medium, lights, environment))
    }

    /// Records the scene the stage used, what `own` adds, and the stage's `record` and times
    /// (`nimbus:<tool>`), then writes the file to `out` (timed as the stage `write`).
    pub fn write(
        mut self,
        tool: &str,
        out: &VdbOutputArgs,
        scene: (&Medium, &[Light], Option<&Environment>),
        record: &[(&str, String)],
        own: impl FnOnce(&mut MetaWriter) -> Result<(), Failure>,
    ) -> Result<(), Failure> {
        let (medium, lights, environment) = scene;
        let mut meta = MetaWriter::new(&mut self.file);
        meta.density_grid(&self.grid)?.medium(medium)?.lights(lights)?.environment(environment)?;
        own(&mut meta)?;
        meta.tool(tool, record, &self.log.times())?;
        self.log.stage("write", || write_vdb(&self.file, out), |_| String::new())?;
        self.log.finish();
        Ok(())
    }
}
