//! nimbus-render's flags and its chain: which tools a frame runs, with which flags, piped
//! or through kept intermediate files (issue #20; the binary's docs say what it does).

use std::collections::HashMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};

use clap::{Parser, ValueEnum};
use nimbus_cli::{given_flags, CameraArgs, CommonArgs, EnvironmentArgs, Failure, FramePattern, LightArgs, Log, MediumArgs, Quality, SequenceArgs, Verbosity};
use nimbus_vdb::{GridKind, VdbFile};

#[derive(Parser, Debug, Clone)]
#[command(
    name = "nimbus-render",
    version,
    about = "Particles (or a density VDB) -> EXR through the whole nimbus chain, frame by frame over a sequence",
    after_help = "Example:\n  nimbus-render 'smoke.$F4.ply' -o 'frames/smoke.$F4.exr' --preview 'frames/smoke.$F4.png' --frames 1-240 --sun dir=0.5,0.3,-0.8,irradiance=4 --sky 0.15,0.24,0.42 --extinction 30 --albedo 0.95 --view-dir 0,1,-0.3 --quality preview --particles2vdb '--voxel-size 2'"
)]
pub struct Args {
    /// Particle file (.ply, .csv, .tsv, .vdb points) or density .vdb; with a frame pattern
    /// (####, %04d, $F4) for a sequence.
    #[arg(help_heading = "Input")]
    pub input: PathBuf,
    /// Output EXR, with a frame pattern for a sequence.
    #[arg(short, long, value_name = "FILE.exr", help_heading = "Output")]
    pub output: PathBuf,
    /// Also write vdbmarch's PNG preview here, with a frame pattern for a sequence (expanded
    /// as the output's is).
    #[arg(long, value_name = "FILE.png", help_heading = "Output")]
    pub preview: Option<PathBuf>,
    #[command(flatten)]
    pub sequence: SequenceArgs,
    /// Keep each frame's intermediate VDBs in DIR, named by the output's frame
    /// (DIR/smoke.0001.density.vdb, .photons.vdb, .cache.vdb); without it they are piped.
    #[arg(long, value_name = "DIR", help_heading = "Output")]
    pub keep_intermediates: Option<PathBuf>,
    /// Print the frames in chunks of N frames, one frame set a line, and exit (what a farm's
    /// array tasks each render: scripts/farm/slurm-submit.sh).
    #[arg(long, value_name = "N", requires = "frames", help_heading = "Sequence")]
    pub print_chunks: Option<usize>,
    /// Trace a photon map (vdbphoton) and gather it in vdbcache, instead of vdbcache's paths.
    #[arg(long, help_heading = "Quality")]
    pub photons: bool,
    /// Extra flags for particles2vdb, as one shell-quoted string ('--voxel-size 2'); in a
    /// sequence, frame patterns in them are expanded per frame.
    #[arg(long = "particles2vdb", value_name = "ARGS", allow_hyphen_values = true, help_heading = "Tools")]
    pub particles2vdb_args: Option<String>,
    /// Extra flags for vdbphoton (with --photons).
    #[arg(long = "vdbphoton", value_name = "ARGS", allow_hyphen_values = true, help_heading = "Tools")]
    pub vdbphoton_args: Option<String>,
    /// Extra flags for vdbcache.
    #[arg(long = "vdbcache", value_name = "ARGS", allow_hyphen_values = true, help_heading = "Tools")]
    pub vdbcache_args: Option<String>,
    /// Extra flags for vdbmarch.
    #[arg(long = "vdbmarch", value_name = "ARGS", allow_hyphen_values = true, help_heading = "Tools")]
    pub vdbmarch_args: Option<String>,
    /// Lights, sky and environment: to the lighting tool (vdbphoton, else vdbcache).
    #[command(flatten)]
    pub lights: LightArgs,
    #[command(flatten)]
    pub environment: EnvironmentArgs,
    /// The medium: to the lighting tool.
    #[command(flatten)]
    pub medium: MediumArgs,
    /// The camera: to vdbcache, which records it for vdbmarch.
    #[command(flatten)]
    pub camera: CameraArgs,
    /// The lights', environment's and medium's flags as given, passed on unchanged.
    #[arg(skip)]
    pub lighting_flags: Vec<OsString>,
    /// The camera's flags as given.
    #[arg(skip)]
    pub camera_flags: Vec<OsString>,
    /// Random seed, the same for every frame (noise does not crawl between frames). [default:
    /// 0]
    #[arg(long, help_heading = "Quality")]
    pub seed: Option<u64>,
    /// Preset for vdbphoton, vdbcache and vdbmarch: draft, preview or final.
    #[arg(long, value_enum, help_heading = "Quality")]
    pub quality: Option<Quality>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// The parsed command line, with the shared flags kept as given for the tools they go to.
pub fn with_shared_flags((mut args, matches): (Args, clap::ArgMatches)) -> Args {
    args.lighting_flags = [given_flags::<LightArgs>(&matches), given_flags::<EnvironmentArgs>(&matches), given_flags::<MediumArgs>(&matches)].concat();
    args.camera_flags = given_flags::<CameraArgs>(&matches);
    args
}

/// The tools of the chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Tool {
    Particles2vdb,
    Vdbphoton,
    Vdbcache,
    Vdbmarch,
}

impl Tool {
    pub fn name(self) -> &'static str {
        match self {
            Tool::Particles2vdb => "particles2vdb",
            Tool::Vdbphoton => "vdbphoton",
            Tool::Vdbcache => "vdbcache",
            Tool::Vdbmarch => "vdbmarch",
        }
    }

    /// The intermediate file's suffix with --keep-intermediates.
    fn product(self) -> &'static str {
        match self {
            Tool::Particles2vdb => "density",
            Tool::Vdbphoton => "photons",
            Tool::Vdbcache => "cache",
            Tool::Vdbmarch => "image",
        }
    }
}

/// Splits a shell-quoted string into words: blanks separate, '...' is literal, "..." keeps
/// blanks and takes \" \\ \$ \` escapes, a backslash outside quotes escapes the next character.
pub fn shell_words(text: &str) -> Result<Vec<String>, String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        match c {
            c if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            '\'' => {
                in_word = true;
                loop {
                    match chars.next() {
                        Some('\'') => break,
                        Some(c) => word.push(c),
                        None => return Err(format!("unterminated ' in '{text}'")),
                    }
                }
            }
            '"' => {
                in_word = true;
                loop {
                    match chars.next() {
                        Some('"') => break,
                        Some('\\') => match chars.next() {
                            Some(c @ ('"' | '\\' | '$' | '`')) => word.push(c),
                            Some(c) => {
                                word.push('\\');
                                word.push(c);
                            }
                            None => return Err(format!("unterminated \" in '{text}'")),
                        },
                        Some(c) => word.push(c),
                        None => return Err(format!("unterminated \" in '{text}'")),
                    }
                }
            }
            '\\' => {
                in_word = true;
                match chars.next() {
                    Some(c) => word.push(c),
                    None => return Err(format!("trailing backslash in '{text}'")),
                }
            }
            c => {
                in_word = true;
                word.push(c);
            }
        }
    }
    if in_word {
        words.push(word);
    }
    Ok(words)
}

/// One stage of a frame's chain: the tool and its flags (without input and output).
struct Stage {
    tool: Tool,
    path: PathBuf,
    flags: Vec<OsString>,
}

/// Whether a .vdb input is particles (only points grids) rather than a density.
fn vdb_is_particles(path: &Path) -> Result<bool, Failure> {
    let file = VdbFile::open(path).map_err(|e| Failure::input(e, path.display()))?;
    let grids = file.grids().map_err(|e| Failure::input(e, path.display()))?;
    Ok(!grids.is_empty() && grids.iter().all(|g| g.kind == GridKind::Points))
}

/// A frame's chain, as the flags set it: the tools (particles2vdb left out of a frame whose
/// input is a density), where their binaries are, the user's extra flags for each, and the
/// extra flags' words that hold frame patterns.
pub struct Chain {
    tools: Vec<Tool>,
    paths: HashMap<Tool, PathBuf>,
    extra: HashMap<Tool, Vec<String>>,
    patterned: Vec<(Tool, usize, PathBuf)>,
}

impl Chain {
    /// Checks the flags and finds the tools beside this executable.
    pub fn new(args: &Args) -> Result<Chain, Failure> {
        if args.output.as_os_str() == "-" && args.keep_intermediates.is_none() && args.sequence.frame_list().is_none() {
            // vdbmarch writes the EXR to stdout as it would alone.
        } else if let Some(ext) = args.output.extension() {
            if !ext.eq_ignore_ascii_case("exr") {
                return Err(Failure::usage(format!("the output is an EXR image; '{}' does not end in .exr", args.output.display())));
            }
        }
        if args.input.as_os_str() == "-" {
            return Err(Failure::usage("nimbus-render reads a file (it decides from the name whether particles2vdb runs); give the input's name"));
        }
        let mut extra = std::collections::HashMap::new();
        for (tool, text) in [
            (Tool::Particles2vdb, &args.particles2vdb_args),
            (Tool::Vdbphoton, &args.vdbphoton_args),
            (Tool::Vdbcache, &args.vdbcache_args),
            (Tool::Vdbmarch, &args.vdbmarch_args),
        ] {
            if let Some(text) = text {
                let words = shell_words(text).map_err(|e| Failure::usage(format!("--{}: {e}", tool.name())))?;
                extra.insert(tool, words);
            }
        }
        if extra.contains_key(&Tool::Vdbphoton) && !args.photons {
            return Err(Failure::usage("--vdbphoton is for the photon chain: add --photons"));
        }
        let exe = std::env::current_exe().map_err(|e| Failure::runtime(format!("cannot find my own executable: {e}"), "nimbus-render"))?;
        let dir = exe.parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
        let binary = |tool: Tool| -> Result<PathBuf, Failure> {
            let path = dir.join(format!("{}{}", tool.name(), std::env::consts::EXE_SUFFIX));
            if path.is_file() {
                Ok(path)
            } else {
                Err(Failure::runtime(format!("{} is not installed beside nimbus-render", tool.name()), path.display()))
            }
        };
        let mut tools = vec![Tool::Particles2vdb];
        if args.photons {
            tools.push(Tool::Vdbphoton);
        }
        tools.extend([Tool::Vdbcache, Tool::Vdbmarch]);
        let mut paths = std::collections::HashMap::new();
        for &tool in &tools {
            paths.insert(tool, binary(tool)?);
        }
        if let Some(dir) = &args.keep_intermediates {
            std::fs::create_dir_all(dir).map_err(|e| Failure::runtime(format!("cannot create the directory: {e}"), dir.display()))?;
        }
        if args.preview.is_some() && extra.get(&Tool::Vdbmarch).is_some_and(|w| w.iter().any(|w| w == "--preview" || w.starts_with("--preview="))) {
            return Err(Failure::usage("--preview is given twice: as nimbus-render's and in --vdbmarch"));
        }
        // The passthrough words holding a frame pattern (a `--vdbmarch '--preview p.$F4.png'`
        // file name): expanded per frame like the outputs, by the same parser.
        let patterned: Vec<(Tool, usize, PathBuf)> = extra
            .iter()
            .flat_map(|(&tool, words)| words.iter().enumerate().map(move |(i, w)| (tool, i, w)))
            .filter(|(_, _, w)| FramePattern::parse(w).is_ok_and(|p| p.is_sequence()))
            .map(|(tool, i, w)| (tool, i, PathBuf::from(w)))
            .collect();
        Ok(Chain { tools, paths, extra, patterned })
    }

    /// The names [`nimbus_cli::for_each_frame`] expands per frame: the output, the preview,
    /// then the extra flags' words with frame patterns.
    pub fn outputs<'a>(&'a self, args: &'a Args) -> Vec<Option<&'a Path>> {
        let mut outputs: Vec<Option<&Path>> = vec![Some(&args.output), args.preview.as_deref()];
        outputs.extend(self.patterned.iter().map(|(_, _, w)| Some(w.as_path())));
        outputs
    }

    /// Runs one frame's chain: `outputs` are [`Chain::outputs`] for the frame.
    pub fn frame(&self, args: &Args, input: Option<PathBuf>, outputs: Vec<Option<PathBuf>>, verbosity: Verbosity) -> Result<(), Failure> {
        let input = input.expect("nimbus-render has an input");
        let output = outputs[0].clone().expect("nimbus-render has an output");
        let mut extra = self.extra.clone();
        for ((tool, i, _), name) in self.patterned.iter().zip(&outputs[2..]) {
            if let (Some(words), Some(name)) = (extra.get_mut(tool), name) {
                words[*i] = name.display().to_string();
            }
        }
        if let Some(preview) = &outputs[1] {
            extra.entry(Tool::Vdbmarch).or_default().extend(["--preview".to_string(), preview.display().to_string()]);
        }
        if !input.exists() {
            return Err(Failure::input("no such file", input.display()));
        }
        if let Some(parent) = output.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|e| Failure::runtime(format!("cannot create the directory: {e}"), parent.display()))?;
        }
        let is_vdb = input.extension().is_some_and(|e| e.eq_ignore_ascii_case("vdb"));
        let particles = !is_vdb || vdb_is_particles(&input)?;
        let chain: Vec<Tool> = self.tools.iter().copied().filter(|&t| t != Tool::Particles2vdb || particles).collect();
        let stages: Vec<Stage> = chain
            .iter()
            .enumerate()
            .map(|(i, &tool)| Stage { tool, path: self.paths[&tool].clone(), flags: flags_for(args, &chain, i, extra.get(&tool)) })
            .collect();
        render_frame(&stages, &input, &output, args.keep_intermediates.as_deref(), verbosity)
    }
}

/// The flags `chain[index]` gets: the shared ones it is the first (or the only) taker of, the
/// ones every tool takes, then the user's extra flags for it.
pub fn flags_for(args: &Args, chain: &[Tool], index: usize, extra: Option<&Vec<String>>) -> Vec<OsString> {
    let tool = chain[index];
    let mut f: Vec<OsString> = Vec::new();
    // The tool that lights the volume records lights, environment and medium.
    let lighting = if chain.contains(&Tool::Vdbphoton) { Tool::Vdbphoton } else { Tool::Vdbcache };
    if tool == lighting {
        f.extend(args.lighting_flags.iter().cloned());
    }
    if tool == Tool::Vdbcache {
        f.extend(args.camera_flags.iter().cloned());
    }
    let mut push = |name: &str, value: String| {
        f.push(format!("--{name}").into());
        f.push(value.into());
    };
    // Every tool records the seed (nimbus:seed) and the next takes it from the file, so only
    // the first gets it (issue #47: vdbcache records it too).
    if let (0, Some(seed)) = (index, args.seed) {
        push("seed", seed.to_string());
    }
    if let (Some(q), true) = (args.quality, tool != Tool::Particles2vdb) {
        push("quality", q.to_possible_value().expect("a named preset").get_name().to_string());
    }
    push("device", args.common.device.to_possible_value().expect("a named device").get_name().to_string());
    if args.common.quiet {
        f.push("-q".into());
    }
    if args.common.verbose {
        f.push("-v".into());
    }
    f.extend(extra.into_iter().flatten().map(OsString::from));
    f
}

fn describe(status: ExitStatus) -> String {
    match status.code() {
        Some(c) => format!("exit code {c}"),
        None => {
            #[cfg(unix)]
            {
                use std::os::unix::process::ExitStatusExt;
                if let Some(s) = status.signal() {
                    return format!("killed by signal {s}");
                }
            }
            "killed".into()
        }
    }
}

/// Runs one frame's chain: piped, or with `keep` through files there one stage after another.
/// Each stage's time is how long after the previous one it finished (with pipes the stages run
/// at once); with -v each is printed, and the frame's line lists them.
fn render_frame(stages: &[Stage], input: &Path, output: &Path, keep: Option<&Path>, verbosity: Verbosity) -> Result<(), Failure> {
    let log = Log::new("nimbus-render", verbosity);
    let last = stages.len() - 1;
    let stem = output.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "frame".into());
    let intermediate = |i: usize| keep.map(|dir| dir.join(format!("{stem}.{}.vdb", stages[i].tool.product())));
    let mut failed: Vec<String> = Vec::new();
    let mut children: Vec<(Tool, Child)> = Vec::new();
    let mut upstream: Option<std::process::ChildStdout> = None;
    for (i, stage) in stages.iter().enumerate() {
        let mut cmd = Command::new(&stage.path);
        let source: PathBuf = match (i, keep) {
            (0, _) => input.to_path_buf(),
            (_, Some(_)) => intermediate(i - 1).expect("kept"),
            (_, None) => PathBuf::from("-"),
        };
        let sink: PathBuf = if i == last { output.to_path_buf() } else { intermediate(i).unwrap_or_else(|| PathBuf::from("-")) };
        cmd.arg(&source).arg("-o").arg(&sink).args(&stage.flags);
        match upstream.take() {
            Some(out) => cmd.stdin(Stdio::from(out)),
            None => cmd.stdin(Stdio::null()),
        };
        if i < last && keep.is_none() {
            cmd.stdout(Stdio::piped());
        }
        let mut child = cmd.spawn().map_err(|e| Failure::runtime(format!("cannot start {}: {e}", stage.tool.name()), stage.path.display()))?;
        upstream = child.stdout.take();
        if keep.is_some() {
            let status = log.stage(stage.tool.name(), || child.wait(), |_| String::new());
            let status = status.map_err(|e| Failure::runtime(e, stage.tool.name()))?;
            if !status.success() {
                return Err(Failure::runtime(format!("{} failed ({})", stage.tool.name(), describe(status)), input.display()));
            }
        } else {
            children.push((stage.tool, child));
        }
    }
    for (tool, mut child) in children {
        let status = log.stage(tool.name(), || child.wait(), |_| String::new()).map_err(|e| Failure::runtime(e, tool.name()))?;
        if !status.success() {
            failed.push(format!("{} ({})", tool.name(), describe(status)));
        }
    }
    if !failed.is_empty() {
        return Err(Failure::runtime(format!("{} failed", failed.join(", ")), input.display()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{flags_for, shell_words, Args, Tool};

    fn flags(args: &[&str], chain: &[Tool]) -> Vec<String> {
        let args = super::with_shared_flags(nimbus_cli::parse_args_from::<Args>([&["nimbus-render", "in.ply", "-o", "out.exr"], args].concat()));
        chain.iter().enumerate().map(|(i, _)| flags_for(&args, chain, i, None).iter().map(|f| f.to_string_lossy().into_owned()).collect::<Vec<_>>().join(" ")).collect()
    }

    #[test]
    fn shared_flags_go_where_metadata_does_not_carry_them() {
        let shared = ["--sun", "dir=0,0,-1,irradiance=2", "--eye", "0,-5,0", "--seed", "7", "--quality", "draft", "--albedo", "0.5", "-v"];
        let chain = [Tool::Particles2vdb, Tool::Vdbcache, Tool::Vdbmarch];
        let f = flags(&shared, &chain);
        assert_eq!(f[0], "--seed 7 --device auto -v", "particles2vdb records the seed");
        assert_eq!(f[1], "--sun dir=0,0,-1,irradiance=2 --albedo 0.5 --eye 0,-5,0 --quality draft --device auto -v");
        assert_eq!(f[2], "--quality draft --device auto -v", "vdbmarch reads lights, medium, camera and seed from the cache");
        // With photons, vdbphoton lights the volume and records the medium and the seed.
        let f = flags(&shared, &[Tool::Particles2vdb, Tool::Vdbphoton, Tool::Vdbcache, Tool::Vdbmarch]);
        assert!(f[1].starts_with("--sun ") && f[1].contains("--albedo 0.5") && !f[1].contains("--seed"), "{}", f[1]);
        assert!(!f[2].contains("--sun") && f[2].contains("--eye 0,-5,0"), "{}", f[2]);
        // A density input starts at vdbcache, which records the seed for vdbmarch.
        let f = flags(&shared, &[Tool::Vdbcache, Tool::Vdbmarch]);
        assert!(f[0].contains("--seed 7") && !f[1].contains("--seed"), "{f:?}");
    }

    #[test]
    fn shell_words_split_as_a_shell_does() {
        assert_eq!(shell_words("--voxel-size 2  --method usl").unwrap(), ["--voxel-size", "2", "--method", "usl"]);
        assert_eq!(shell_words(r#"--sun 'dir=0,0,-1, irradiance=3' --x "a b\"c" d\ e"#).unwrap(), ["--sun", "dir=0,0,-1, irradiance=3", "--x", "a b\"c", "d e"]);
        assert_eq!(shell_words("''").unwrap(), [""]);
        assert!(shell_words("").unwrap().is_empty());
        assert!(shell_words("'open").is_err());
        assert!(shell_words("\"open").is_err());
    }
}
