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
//! Exit code 0 when every frame was done (or skipped with `--skip-existing`), 1 when any
//! frame failed (listed on the last line), 2 for bad usage.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, ExitStatus, Stdio};

use clap::{Parser, ValueEnum};
use nimbus_cli::{for_each_frame, parse_dvec3, parse_rgb, run, CommonArgs, Failure, Log, Quality, SequenceArgs, Verbosity};
use nimbus_optics::Light;
use nimbus_vdb::{GridKind, VdbFile};

#[derive(Parser, Debug, Clone)]
#[command(
    name = "nimbus-render",
    version,
    about = "Particles (or a density VDB) -> EXR through the whole nimbus chain, frame by frame over a sequence"
)]
struct Args {
    /// Particle file (.ply, .csv, .tsv, .vdb points) or density .vdb; with a frame pattern
    /// (####, %04d, $F4) for a sequence.
    input: PathBuf,
    /// Output EXR, with a frame pattern for a sequence.
    #[arg(short, long, value_name = "FILE.exr")]
    output: PathBuf,
    #[command(flatten)]
    sequence: SequenceArgs,
    /// Keep each frame's intermediate VDBs in DIR, named by the output's frame
    /// (DIR/smoke.0001.density.vdb, .photons.vdb, .cache.vdb); without it they are piped.
    #[arg(long, value_name = "DIR")]
    keep_intermediates: Option<PathBuf>,
    /// Print the frames in chunks of N frames, one frame set a line, and exit (what a farm's
    /// array tasks each render: scripts/farm/slurm-submit.sh).
    #[arg(long, value_name = "N", requires = "frames")]
    print_chunks: Option<usize>,
    /// Trace a photon map (vdbphoton) and gather it in vdbcache (default: vdbcache's paths,
    /// no photons).
    #[arg(long)]
    photons: bool,
    /// Extra flags for particles2vdb, as one shell-quoted string ('--voxel-size 2').
    #[arg(long = "particles2vdb", value_name = "ARGS", allow_hyphen_values = true)]
    particles2vdb_args: Option<String>,
    /// Extra flags for vdbphoton (with --photons).
    #[arg(long = "vdbphoton", value_name = "ARGS", allow_hyphen_values = true)]
    vdbphoton_args: Option<String>,
    /// Extra flags for vdbcache.
    #[arg(long = "vdbcache", value_name = "ARGS", allow_hyphen_values = true)]
    vdbcache_args: Option<String>,
    /// Extra flags for vdbmarch.
    #[arg(long = "vdbmarch", value_name = "ARGS", allow_hyphen_values = true)]
    vdbmarch_args: Option<String>,
    /// A sun: dir=X,Y,Z,irradiance=R,G,B (repeatable; to the lighting tool).
    #[arg(long, value_name = "SPEC", value_parser = check(Light::parse_sun))]
    sun: Vec<String>,
    /// A point light: pos=X,Y,Z,intensity=R,G,B (repeatable; to the lighting tool).
    #[arg(long, value_name = "SPEC", value_parser = check(Light::parse_point))]
    point: Vec<String>,
    /// Uniform sky radiance R,G,B (to the lighting tool).
    #[arg(long, value_name = "R,G,B", value_parser = check(parse_rgb))]
    sky: Option<String>,
    /// An equirectangular HDR environment map (to the lighting tool).
    #[arg(long, value_name = "FILE.exr")]
    environment: Option<PathBuf>,
    /// The environment map's strength.
    #[arg(long, value_name = "S", requires = "environment")]
    environment_strength: Option<f32>,
    /// The environment map's turn about +Z, degrees.
    #[arg(long, value_name = "DEG", requires = "environment", allow_negative_numbers = true)]
    environment_rotation: Option<f32>,
    /// Extinction per unit density (to the lighting tool).
    #[arg(long, allow_negative_numbers = true)]
    extinction: Option<f32>,
    /// Single-scattering albedo, grey or R,G,B (to the lighting tool).
    #[arg(long, value_parser = check(parse_rgb))]
    albedo: Option<String>,
    /// Henyey-Greenstein asymmetry (to the lighting tool).
    #[arg(long, allow_negative_numbers = true)]
    g: Option<f32>,
    /// Camera position X,Y,Z (to vdbcache, which records it for vdbmarch).
    #[arg(long, value_parser = check(parse_dvec3), allow_hyphen_values = true)]
    eye: Option<String>,
    /// Camera target X,Y,Z.
    #[arg(long, value_parser = check(parse_dvec3), allow_hyphen_values = true)]
    look_at: Option<String>,
    /// Camera up X,Y,Z.
    #[arg(long, value_parser = check(parse_dvec3), allow_hyphen_values = true)]
    up: Option<String>,
    /// Horizontal field of view, degrees.
    #[arg(long)]
    fov: Option<f64>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Random seed (default 0, the same for every frame: noise does not crawl between frames).
    #[arg(long)]
    seed: Option<u64>,
    /// Preset for vdbphoton, vdbcache and vdbmarch: draft, preview or final.
    #[arg(long, value_enum)]
    quality: Option<Quality>,
    #[command(flatten)]
    common: CommonArgs,
}

/// A value parser that checks the text with `parse` and keeps the text, passed on as given.
fn check<T, E: std::fmt::Display>(parse: fn(&str) -> Result<T, E>) -> impl Fn(&str) -> Result<String, String> + Clone + Send + Sync + 'static
where
    T: 'static,
    E: 'static,
{
    move |s: &str| parse(s).map(|_| s.to_string()).map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    let args = Args::parse();
    run(move || nimbus_render(args))
}

/// The tools of the chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Tool {
    Particles2vdb,
    Vdbphoton,
    Vdbcache,
    Vdbmarch,
}

impl Tool {
    fn name(self) -> &'static str {
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
fn shell_words(text: &str) -> Result<Vec<String>, String> {
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
    let verbosity = log.verbosity();
    drop(log);
    for_each_frame("nimbus-render", &args.sequence, verbosity, Some(&args.input), &[Some(&args.output)], |input, outputs| {
        let input = input.expect("nimbus-render has an input");
        let output = outputs[0].clone().expect("nimbus-render has an output");
        if !input.exists() {
            return Err(Failure::input("no such file", input.display()));
        }
        if let Some(parent) = output.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|e| Failure::runtime(format!("cannot create the directory: {e}"), parent.display()))?;
        }
        let is_vdb = input.extension().is_some_and(|e| e.eq_ignore_ascii_case("vdb"));
        let particles = !is_vdb || vdb_is_particles(&input)?;
        let chain: Vec<Tool> = tools.iter().copied().filter(|&t| t != Tool::Particles2vdb || particles).collect();
        let stages: Vec<Stage> = chain
            .iter()
            .enumerate()
            .map(|(i, &tool)| Stage { tool, path: paths[&tool].clone(), flags: flags_for(&args, &chain, i, extra.get(&tool)) })
            .collect();
        render_frame(&stages, &input, &output, args.keep_intermediates.as_deref(), verbosity)
    })
}

/// The flags `chain[index]` gets: the shared ones it is the first (or the only) taker of, the
/// ones every tool takes, then the user's extra flags for it.
fn flags_for(args: &Args, chain: &[Tool], index: usize, extra: Option<&Vec<String>>) -> Vec<OsString> {
    let tool = chain[index];
    let mut f: Vec<OsString> = Vec::new();
    let mut push = |name: &str, value: String| {
        f.push(format!("--{name}").into());
        f.push(value.into());
    };
    // The tool that lights the volume records lights, environment and medium.
    let lighting = if chain.contains(&Tool::Vdbphoton) { Tool::Vdbphoton } else { Tool::Vdbcache };
    if tool == lighting {
        for s in &args.sun {
            push("sun", s.clone());
        }
        for p in &args.point {
            push("point", p.clone());
        }
        if let Some(s) = &args.sky {
            push("sky", s.clone());
        }
        if let Some(e) = &args.environment {
            push("environment", e.display().to_string());
        }
        if let Some(s) = args.environment_strength {
            push("environment-strength", s.to_string());
        }
        if let Some(r) = args.environment_rotation {
            push("environment-rotation", r.to_string());
        }
        if let Some(x) = args.extinction {
            push("extinction", x.to_string());
        }
        if let Some(a) = &args.albedo {
            push("albedo", a.clone());
        }
        if let Some(g) = args.g {
            push("g", g.to_string());
        }
    }
    if tool == Tool::Vdbcache {
        for (name, value) in [("eye", &args.eye), ("look-at", &args.look_at), ("up", &args.up)] {
            if let Some(v) = value {
                push(name, v.clone());
            }
        }
        if let Some(v) = args.fov {
            push("fov", v.to_string());
        }
        if let Some(v) = args.width {
            push("width", v.to_string());
        }
        if let Some(v) = args.height {
            push("height", v.to_string());
        }
    }
    // particles2vdb and vdbphoton record the seed (nimbus:seed) and the rest take it from the
    // file; vdbcache does not record it, so where the chain starts at vdbcache (a density
    // input, no photons) vdbmarch gets it too.
    let first_records = matches!(chain[0], Tool::Particles2vdb | Tool::Vdbphoton);
    if let (true, Some(seed)) = (index == 0 || (tool == Tool::Vdbmarch && !first_records), args.seed) {
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
    use clap::Parser;

    fn flags(args: &[&str], chain: &[Tool]) -> Vec<String> {
        let args = Args::parse_from([&["nimbus-render", "in.ply", "-o", "out.exr"], args].concat());
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
        // A density input starts at vdbcache, which does not record the seed: vdbmarch gets it.
        let f = flags(&shared, &[Tool::Vdbcache, Tool::Vdbmarch]);
        assert!(f[0].contains("--seed 7") && f[1].contains("--seed 7"), "{f:?}");
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
