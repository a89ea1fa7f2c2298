//! Frame sequences (design.md section 8, issue #20): the frame patterns in file names, the
//! frame sets of `--frames`, and the loop every tool runs over a sequence.
//!
//! - Patterns: `####` (a frame padded to the count of `#`), `%04d` / `%d` (C's), `$F4` /
//!   `$F` (Houdini's). A name may hold several; all take the same frame.
//! - Frame sets: `N`, `A-B`, `A-BxS` (every S-th frame from A), and comma lists of them
//!   (`1-10,20,30-40x5`); `A-B:S` too, as OpenJD's range expressions write the step.
//!   Frames are whole numbers >= 0; a frame listed twice runs once.
//! - [`SequenceArgs`]: `--frames SET`, `--frame N`, `--skip-existing`, flattened into each
//!   tool as [`crate::CommonArgs`] is. [`for_each_frame`] runs a tool's body once per frame
//!   with the frame's names, one frame after another (each frame holds its whole volume in
//!   memory, so frames never run side by side within one process: run several processes, or
//!   a farm, for that), reports a failed frame by number and goes on, and fails at the end
//!   with the list of failed frames.

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use crate::{Failure, Verbosity};

/// One frame-pattern token in a name.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Token {
    /// Byte range of the token in the name.
    start: usize,
    end: usize,
    /// Digits the frame is padded to with zeros (0 or 1: no padding).
    pad: usize,
}

/// A file name with frame patterns in it, or none.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FramePattern {
    text: String,
    tokens: Vec<Token>,
}

impl FramePattern {
    /// Finds the patterns in `text`. Errors on a malformed `%` pattern that looks like one
    /// (`%4` without `d`).
    pub fn parse(text: &str) -> Result<FramePattern, String> {
        let bytes = text.as_bytes();
        let mut tokens = Vec::new();
        let mut i = 0;
        while i < bytes.len() {
            match bytes[i] {
                b'#' => {
                    let start = i;
                    while i < bytes.len() && bytes[i] == b'#' {
                        i += 1;
                    }
                    tokens.push(Token { start, end: i, pad: i - start });
                    continue;
                }
                b'%' => {
                    let start = i;
                    let mut j = i + 1;
                    while j < bytes.len() && bytes[j].is_ascii_digit() {
                        j += 1;
                    }
                    if j < bytes.len() && bytes[j] == b'd' {
                        let digits = &text[i + 1..j];
                        let pad = if digits.is_empty() {
                            0
                        } else if digits.starts_with('0') {
                            digits.parse::<usize>().map_err(|_| format!("bad frame pattern in '{text}'"))?
                        } else {
                            // %4d pads with spaces in C; a file name wants zeros.
                            return Err(format!("'{}' pads with spaces; use %0{}d for zeros ('{text}')", &text[start..=j], digits));
                        };
                        if pad > 12 {
                            return Err(format!("frame padding {pad} is too wide ('{text}')"));
                        }
                        tokens.push(Token { start, end: j + 1, pad });
                        i = j + 1;
                        continue;
                    }
                    if j > i + 1 {
                        return Err(format!("'{}' is not a frame pattern: did you mean {}d? ('{text}')", &text[start..j], &text[start..j]));
                    }
                }
                b'$' if bytes.get(i + 1) == Some(&b'F') => {
                    let start = i;
                    let mut j = i + 2;
                    while j < bytes.len() && bytes[j].is_ascii_digit() {
                        j += 1;
                    }
                    // $FF (Houdini's fractional frame) or $FPS are other variables.
                    if j == i + 2 && bytes.get(j).is_some_and(|b| b.is_ascii_alphabetic() || *b == b'_') {
                        return Err(format!("only $F and $F<N> are frame patterns, not '{}' ('{text}')", &text[start..]));
                    }
                    let pad = if j > i + 2 { text[i + 2..j].parse::<usize>().map_err(|_| format!("bad frame pattern in '{text}'"))? } else { 0 };
                    if pad > 12 {
                        return Err(format!("frame padding {pad} is too wide ('{text}')"));
                    }
                    tokens.push(Token { start, end: j, pad });
                    i = j;
                    continue;
                }
                _ => {}
            }
            i += 1;
        }
        Ok(FramePattern { text: text.to_string(), tokens })
    }

    /// Whether the name holds a frame pattern.
    pub fn is_sequence(&self) -> bool {
        !self.tokens.is_empty()
    }

    /// The name of `frame`.
    pub fn name(&self, frame: u64) -> String {
        let mut out = String::with_capacity(self.text.len() + 8);
        let mut at = 0;
        for t in &self.tokens {
            out.push_str(&self.text[at..t.start]);
            out.push_str(&format!("{frame:0width$}", width = t.pad));
            at = t.end;
        }
        out.push_str(&self.text[at..]);
        out
    }

    pub fn path(&self, frame: u64) -> PathBuf {
        PathBuf::from(self.name(frame))
    }

    pub fn as_str(&self) -> &str {
        &self.text
    }
}

/// The frames of `--frames`, in the order given, each once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameSet(pub Vec<u64>);

/// Most frames one set may list (a typo such as 1-10000000 fails fast instead of running).
pub const MAX_FRAMES: usize = 1_000_000;

impl FrameSet {
    pub fn parse(text: &str) -> Result<FrameSet, String> {
        let number = |s: &str| -> Result<u64, String> {
            let s = s.trim();
            if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
                return Err(format!("'{s}' is not a frame number (whole numbers >= 0) in '{text}'"));
            }
            s.parse::<u64>().map_err(|e| format!("'{s}': {e} in '{text}'"))
        };
        let mut frames = Vec::new();
        let mut seen = std::collections::HashSet::new();
        if text.trim().is_empty() {
            return Err("empty frame set (give e.g. 1-240, 1-240x2 or 1,5,9)".into());
        }
        for item in text.split(',') {
            let item = item.trim();
            let (range, step) = match item.split_once(['x', ':']) {
                Some((r, s)) => (r, number(s)?),
                None => (item, 1),
            };
            if step == 0 {
                return Err(format!("step 0 in '{item}' ({text})"));
            }
            let (first, last) = match range.split_once('-') {
                Some((a, b)) => (number(a)?, number(b)?),
                None if item.contains(['x', ':']) => return Err(format!("a step needs a range, as 1-240x2, not '{item}' ({text})")),
                None => {
                    let n = number(range)?;
                    (n, n)
                }
            };
            if first > last {
                return Err(format!("range '{range}' runs backwards ({text})"));
            }
            let mut f = first;
            while f <= last {
                if seen.insert(f) {
                    frames.push(f);
                    if frames.len() > MAX_FRAMES {
                        return Err(format!("more than {MAX_FRAMES} frames in '{text}'"));
                    }
                }
                f = match f.checked_add(step) {
                    Some(n) => n,
                    None => break,
                };
            }
        }
        Ok(FrameSet(frames))
    }

    /// The frames in chunks of `size` (the last may be shorter), each as a frame set's text:
    /// a farm's tasks (`nimbus-render --print-chunks`).
    pub fn chunks(&self, size: usize) -> Vec<String> {
        self.0.chunks(size.max(1)).map(FrameSet::describe).collect()
    }

    /// A compact text of the frames, as `1-3,7,9`.
    pub fn describe(frames: &[u64]) -> String {
        let mut parts = Vec::new();
        let mut i = 0;
        while i < frames.len() {
            let mut j = i;
            while j + 1 < frames.len() && frames[j + 1] == frames[j] + 1 {
                j += 1;
            }
            parts.push(if j > i { format!("{}-{}", frames[i], frames[j]) } else { frames[i].to_string() });
            i = j + 1;
        }
        parts.join(",")
    }
}

impl fmt::Display for FrameSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&FrameSet::describe(&self.0))
    }
}

/// `--frames`, `--frame`, `--skip-existing`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Sequence")]
pub struct SequenceArgs {
    /// Render a sequence: the frames as 1-240, 1-240x2 (every second), 1,5,9 or a mix
    /// (1-10,20); the input and output names then hold a frame pattern: ####, %04d or $F4
    /// (padded to 4 digits), %d or $F (unpadded).
    #[arg(long, value_name = "SET", value_parser = FrameSet::parse, conflicts_with = "frame")]
    pub frames: Option<FrameSet>,
    /// One frame of a sequence (as --frames N).
    #[arg(long, value_name = "N")]
    pub frame: Option<u64>,
    /// Do only the frames whose output file is missing (a rerun finishes a sequence).
    #[arg(long)]
    pub skip_existing: bool,
}

/// What [`SequenceArgs::plan`] decided: the frames, and the patterns of the input and the
/// outputs.
#[derive(Debug, Clone)]
pub struct Plan {
    pub frames: Vec<u64>,
    pub input: FramePattern,
    /// The outputs given (the first is the main one); None where not given.
    pub outputs: Vec<Option<FramePattern>>,
}

/// One frame's names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameNames {
    pub frame: u64,
    pub input: PathBuf,
    pub outputs: Vec<Option<PathBuf>>,
}

impl Plan {
    pub fn names(&self, frame: u64) -> FrameNames {
        FrameNames { frame, input: self.input.path(frame), outputs: self.outputs.iter().map(|o| o.as_ref().map(|p| p.path(frame))).collect() }
    }
}

fn is_stream(p: Option<&Path>) -> bool {
    p.is_none_or(|p| p.as_os_str() == "-")
}

fn pattern_of(p: &Path) -> Result<FramePattern, Failure> {
    let text = p.to_str().ok_or_else(|| Failure::usage(format!("a sequence's file name must be UTF-8 ({})", p.display())))?;
    FramePattern::parse(text).map_err(Failure::usage)
}

impl SequenceArgs {
    /// The frames asked for, if any.
    pub fn frame_list(&self) -> Option<Vec<u64>> {
        match (&self.frames, self.frame) {
            (Some(set), _) => Some(set.0.clone()),
            (None, Some(f)) => Some(vec![f]),
            (None, None) => None,
        }
    }

    /// The sequence `input` and `outputs` (the main output first, then others such as a
    /// preview) describe with these flags, or None for one file as before. Errors (exit 2):
    /// frames without a pattern in the names, a pattern without frames, a pattern in the
    /// output but not the input or the reverse, stdin or stdout in a sequence.
    pub fn plan(&self, input: Option<&Path>, outputs: &[Option<&Path>]) -> Result<Option<Plan>, Failure> {
        let input_pattern = match input {
            Some(p) if !is_stream(Some(p)) => Some(pattern_of(p)?),
            _ => None,
        };
        let mut output_patterns = Vec::new();
        for o in outputs {
            output_patterns.push(match o {
                Some(p) if !is_stream(Some(p)) => Some(pattern_of(p)?),
                _ => None,
            });
        }
        let any_pattern = input_pattern.as_ref().is_some_and(FramePattern::is_sequence) || output_patterns.iter().flatten().any(FramePattern::is_sequence);
        let Some(frames) = self.frame_list() else {
            if any_pattern {
                return Err(Failure::usage("the file names hold a frame pattern (####, %04d, $F4): give --frames SET or --frame N"));
            }
            return Ok(None);
        };
        let flag = if self.frames.is_some() { "--frames" } else { "--frame" };
        if frames.is_empty() {
            return Err(Failure::usage(format!("{flag} lists no frames")));
        }
        let Some(input_pattern) = input_pattern else {
            return Err(Failure::usage(format!("{flag}: stdin cannot be a sequence; give the input file name with a frame pattern (####, %04d, $F4)")));
        };
        if !input_pattern.is_sequence() {
            return Err(Failure::usage(format!("{flag}: the input '{}' has no frame pattern (####, %04d, $F4)", input_pattern.as_str())));
        }
        let main = match output_patterns.first() {
            Some(Some(p)) => p,
            _ => return Err(Failure::usage(format!("{flag}: stdout cannot be a sequence; give -o with a frame pattern (####, %04d, $F4)"))),
        };
        if !main.is_sequence() {
            return Err(Failure::usage(format!("{flag}: the output '{}' has no frame pattern, so every frame would overwrite it (####, %04d, $F4)", main.as_str())));
        }
        for (o, p) in outputs.iter().zip(&output_patterns).skip(1) {
            if let (Some(path), Some(p)) = (o, p) {
                if !p.is_sequence() {
                    return Err(Failure::usage(format!("{flag}: the output '{}' has no frame pattern (####, %04d, $F4)", path.display())));
                }
            } else if o.is_some() {
                return Err(Failure::usage(format!("{flag}: stdout cannot be a sequence")));
            }
        }
        Ok(Some(Plan { frames, input: input_pattern, outputs: output_patterns }))
    }
}

/// How one frame went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameOutcome {
    Done,
    Skipped,
    Failed(Failure),
}

/// The end of a sequence: Ok where every frame was done or skipped, else one failure listing
/// the failed frames, exit code 2 where every frame failed for bad usage or input (exit 2
/// each: the flags or the names are wrong), else 1.
pub fn sequence_result(tool: &str, outcomes: &[(u64, FrameOutcome)]) -> Result<(), Failure> {
    let failed: Vec<(u64, &Failure)> = outcomes.iter().filter_map(|(f, o)| if let FrameOutcome::Failed(e) = o { Some((*f, e)) } else { None }).collect();
    if failed.is_empty() {
        return Ok(());
    }
    let frames: Vec<u64> = failed.iter().map(|f| f.0).collect();
    let code = if failed.len() == outcomes.len() && failed.iter().all(|f| f.1.code == 2) { 2 } else { 1 };
    Err(Failure {
        code,
        message: format!("{} of {} frames failed: {} ({tool})", failed.len(), outcomes.len(), FrameSet::describe(&frames)),
    })
}

/// Runs `body` on each frame of the sequence the flags and names describe (with the frame's
/// input and outputs), or once on the names as given where they are not a sequence.
/// `--skip-existing` skips a frame whose main output exists. A failed frame is printed as
/// `error: frame N: ...` at once; the run goes on, and fails at the end listing them. Unless
/// `-q`, each frame ends with a line `<tool>: frame N: S s (stage times)`.
pub fn for_each_frame(
    tool: &'static str,
    seq: &SequenceArgs,
    verbosity: Verbosity,
    input: Option<&Path>,
    outputs: &[Option<&Path>],
    mut body: impl FnMut(Option<PathBuf>, Vec<Option<PathBuf>>) -> Result<(), Failure>,
) -> Result<(), Failure> {
    let Some(plan) = seq.plan(input, outputs)? else {
        if seq.skip_existing {
            if let Some(Some(out)) = outputs.first() {
                if out.as_os_str() != "-" && out.exists() {
                    if verbosity > Verbosity::Quiet {
                        eprintln!("{tool}: skipped ({} exists)", out.display());
                    }
                    return Ok(());
                }
            }
        }
        return body(input.map(Path::to_path_buf), outputs.iter().map(|o| o.map(Path::to_path_buf)).collect());
    };
    let mut outcomes = Vec::with_capacity(plan.frames.len());
    for &frame in &plan.frames {
        let names = plan.names(frame);
        let out = names.outputs[0].clone().expect("a sequence has an output");
        if seq.skip_existing && out.exists() {
            if verbosity > Verbosity::Quiet {
                eprintln!("{tool}: frame {frame}: skipped ({} exists)", out.display());
            }
            outcomes.push((frame, FrameOutcome::Skipped));
            continue;
        }
        let start = Instant::now();
        crate::log::take_last_times();
        match body(Some(names.input), names.outputs) {
            Ok(()) => {
                if verbosity > Verbosity::Quiet {
                    let stages = crate::log::take_last_times().map(|t| t.describe()).unwrap_or_default();
                    let sep = if stages.is_empty() { "" } else { "  " };
                    eprintln!("{tool}: frame {frame}: {:.3} s{sep}{stages}", start.elapsed().as_secs_f64());
                }
                outcomes.push((frame, FrameOutcome::Done));
            }
            Err(e) => {
                eprintln!("error: frame {frame}: {e}");
                outcomes.push((frame, FrameOutcome::Failed(e)));
            }
        }
    }
    sequence_result(tool, &outcomes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name(p: &str, f: u64) -> String {
        FramePattern::parse(p).unwrap().name(f)
    }

    #[test]
    fn hashes_pad_to_their_count() {
        assert_eq!(name("smoke.####.ply", 7), "smoke.0007.ply");
        assert_eq!(name("smoke.#.ply", 7), "smoke.7.ply");
        assert_eq!(name("smoke.##.ply", 123), "smoke.123.ply");
        assert_eq!(name("f/####/s.####.vdb", 12), "f/0012/s.0012.vdb");
    }

    #[test]
    fn printf_patterns() {
        assert_eq!(name("smoke.%04d.ply", 7), "smoke.0007.ply");
        assert_eq!(name("smoke.%d.ply", 7), "smoke.7.ply");
        assert_eq!(name("smoke_%06d.exr", 240), "smoke_000240.exr");
        assert!(FramePattern::parse("smoke.%4d.ply").unwrap_err().contains("%04d"));
        assert!(FramePattern::parse("smoke.%04.ply").is_err());
        // A lone percent sign is only a character.
        assert!(!FramePattern::parse("100%.ply").unwrap().is_sequence());
    }

    #[test]
    fn houdini_patterns() {
        assert_eq!(name("smoke.$F4.ply", 7), "smoke.0007.ply");
        assert_eq!(name("smoke.$F.ply", 7), "smoke.7.ply");
        assert_eq!(name("smoke.$F3", 1234), "smoke.1234");
        assert!(FramePattern::parse("smoke.$FF.ply").is_err());
        assert!(!FramePattern::parse("$HIP/smoke.ply").unwrap().is_sequence());
    }

    #[test]
    fn names_without_a_pattern() {
        let p = FramePattern::parse("smoke.ply").unwrap();
        assert!(!p.is_sequence());
        assert_eq!(p.name(3), "smoke.ply");
    }

    #[test]
    fn frame_sets() {
        assert_eq!(FrameSet::parse("1-5").unwrap().0, vec![1, 2, 3, 4, 5]);
        assert_eq!(FrameSet::parse("1-9x2").unwrap().0, vec![1, 3, 5, 7, 9]);
        assert_eq!(FrameSet::parse("1-10x4").unwrap().0, vec![1, 5, 9]);
        assert_eq!(FrameSet::parse("1,5,9").unwrap().0, vec![1, 5, 9]);
        assert_eq!(FrameSet::parse("1-3,20, 30-34x2").unwrap().0, vec![1, 2, 3, 20, 30, 32, 34]);
        assert_eq!(FrameSet::parse("7").unwrap().0, vec![7]);
        assert_eq!(FrameSet::parse("0-2").unwrap().0, vec![0, 1, 2]);
        assert_eq!(FrameSet::parse("3,1-4").unwrap().0, vec![3, 1, 2, 4], "given order, each frame once");
        assert_eq!(FrameSet::parse("1-240").unwrap().0.len(), 240);
        assert_eq!(FrameSet::parse("1-9:4").unwrap().0, vec![1, 5, 9], "OpenJD's step");
    }

    #[test]
    fn bad_frame_sets() {
        for bad in ["", "5-1", "1-", "-3", "a-b", "1-10x0", "1-10x", "1..10", "1,,2", "1.5", "3x2", "0-99999999"] {
            assert!(FrameSet::parse(bad).is_err(), "'{bad}' should be refused");
        }
        assert!(FrameSet::parse("5-1").unwrap_err().contains("backwards"));
    }

    #[test]
    fn chunks_for_a_farm() {
        let set = FrameSet::parse("1-7,10").unwrap();
        assert_eq!(set.chunks(3), ["1-3", "4-6", "7,10"]);
        assert_eq!(set.chunks(100), ["1-7,10"]);
        for chunk in set.chunks(3) {
            assert!(FrameSet::parse(&chunk).is_ok(), "a chunk reads back as a frame set");
        }
    }

    #[test]
    fn describe_compacts_runs() {
        assert_eq!(FrameSet::describe(&[1, 2, 3, 7, 9, 10]), "1-3,7,9-10");
        assert_eq!(FrameSet::describe(&[4]), "4");
    }

    fn seq(frames: &str) -> SequenceArgs {
        SequenceArgs { frames: Some(FrameSet::parse(frames).unwrap()), ..Default::default() }
    }

    #[test]
    fn plans() {
        let p = seq("1-2").plan(Some(Path::new("in.####.ply")), &[Some(Path::new("out.$F4.vdb"))]).unwrap().unwrap();
        assert_eq!(p.frames, vec![1, 2]);
        let n = p.names(2);
        assert_eq!(n.input, PathBuf::from("in.0002.ply"));
        assert_eq!(n.outputs, vec![Some(PathBuf::from("out.0002.vdb"))]);
        // Not a sequence: the names as given.
        assert!(SequenceArgs::default().plan(Some(Path::new("in.ply")), &[Some(Path::new("out.vdb"))]).unwrap().is_none());
        let one = SequenceArgs { frame: Some(9), ..Default::default() };
        assert_eq!(one.plan(Some(Path::new("a.%d")), &[Some(Path::new("b.%d"))]).unwrap().unwrap().frames, vec![9]);
    }

    #[test]
    fn plan_errors_are_usage_errors() {
        let cases: [(SequenceArgs, Option<&str>, Option<&str>, &str); 7] = [
            (seq("1-3"), Some("in.ply"), Some("out.####.exr"), "input 'in.ply' has no frame pattern"),
            (seq("1-3"), Some("in.####.ply"), Some("out.exr"), "every frame would overwrite"),
            (seq("1-3"), Some("in.ply"), Some("out.exr"), "no frame pattern"),
            (seq("1-3"), Some("-"), Some("out.####.exr"), "stdin cannot be a sequence"),
            (seq("1-3"), None, Some("out.####.exr"), "stdin cannot be a sequence"),
            (seq("1-3"), Some("in.####.ply"), Some("-"), "stdout cannot be a sequence"),
            (SequenceArgs::default(), Some("in.####.ply"), Some("out.####.exr"), "give --frames"),
        ];
        for (s, i, o, want) in cases {
            let e = s.plan(i.map(Path::new), &[o.map(Path::new)]).unwrap_err();
            assert_eq!(e.code, 2, "{e}");
            assert!(e.message.contains(want), "'{e}' should say '{want}'");
        }
        // A second output (a preview) needs its own pattern.
        let e = seq("1").plan(Some(Path::new("a.#")), &[Some(Path::new("b.#.exr")), Some(Path::new("b.png"))]).unwrap_err();
        assert!(e.message.contains("b.png"));
    }

    #[test]
    fn the_loop_goes_on_past_a_failed_frame() {
        let mut seen = Vec::new();
        let s = seq("1-4");
        let r = for_each_frame("t", &s, Verbosity::Quiet, Some(Path::new("in.#")), &[Some(Path::new("/nonexistent-dir/out.#"))], |i, o| {
            seen.push((i.unwrap(), o[0].clone().unwrap()));
            if seen.len() % 2 == 0 {
                Err(Failure::input("cannot open", "x"))
            } else {
                Ok(())
            }
        });
        assert_eq!(seen.len(), 4, "every frame ran");
        assert_eq!(seen[3], (PathBuf::from("in.4"), PathBuf::from("/nonexistent-dir/out.4")));
        let e = r.unwrap_err();
        assert_eq!(e.code, 1, "some frames were done");
        assert!(e.message.starts_with("2 of 4 frames failed: 2,4"), "{e}");
        // All failing for bad input: exit 2.
        let e = for_each_frame("t", &s, Verbosity::Quiet, Some(Path::new("in.#")), &[Some(Path::new("out.#"))], |_, _| Err(Failure::input("bad", "x"))).unwrap_err();
        assert_eq!((e.code, e.message.as_str()), (2, "4 of 4 frames failed: 1-4 (t)"));
    }

    #[test]
    fn skip_existing_skips_frames_with_output() {
        let dir = std::env::temp_dir().join(format!("nimbus-frames-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("out.2"), b"done").unwrap();
        let out = dir.join("out.#");
        let s = SequenceArgs { skip_existing: true, ..seq("1-3") };
        let mut ran = Vec::new();
        for_each_frame("t", &s, Verbosity::Quiet, Some(Path::new("in.#")), &[Some(&out)], |i, _| {
            ran.push(i.unwrap());
            Ok(())
        })
        .unwrap();
        assert_eq!(ran, vec![PathBuf::from("in.1"), PathBuf::from("in.3")]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
