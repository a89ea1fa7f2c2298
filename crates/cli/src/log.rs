use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    Quiet,
    Normal,
    Verbose,
}

impl Verbosity {
    pub fn from_flags(quiet: bool, verbose: bool) -> Verbosity {
        if quiet {
            Verbosity::Quiet
        } else if verbose {
            Verbosity::Verbose
        } else {
            Verbosity::Normal
        }
    }
}

/// Per-stage wall-clock times, in order, for `-v` and for the file's metadata.
#[derive(Debug, Default, Clone)]
pub struct StageTimes {
    pub stages: Vec<(String, Duration)>,
}

impl StageTimes {
    pub fn total(&self) -> Duration {
        self.stages.iter().map(|s| s.1).sum()
    }

    /// `read=0.012,trace=1.204` in seconds: compact enough for one metadata string.
    pub fn to_metadata(&self) -> String {
        self.stages.iter().map(|(n, d)| format!("{n}={:.3}", d.as_secs_f64())).collect::<Vec<_>>().join(",")
    }

    /// `read 0.012 s, march 1.204 s`: a sequence's per-frame progress line.
    pub fn describe(&self) -> String {
        self.stages.iter().map(|(n, d)| format!("{n} {:.3} s", d.as_secs_f64())).collect::<Vec<_>>().join(", ")
    }
}

/// The stage times of the last [`Log`] dropped, for the per-frame line of a sequence
/// (`frames::for_each_frame`): a tool's body makes its own Log and drops it with the frame.
static LAST_TIMES: Mutex<Option<StageTimes>> = Mutex::new(None);

pub(crate) fn take_last_times() -> Option<StageTimes> {
    LAST_TIMES.lock().ok().and_then(|mut t| t.take())
}

impl Drop for Log {
    fn drop(&mut self) {
        if let (Ok(mut last), Ok(times)) = (LAST_TIMES.lock(), self.times.lock()) {
            *last = Some(times.clone());
        }
    }
}

/// The tool's voice on stderr: errors always, warnings unless `-q`, stage lines with `-v`.
pub struct Log {
    tool: &'static str,
    verbosity: Verbosity,
    times: Mutex<StageTimes>,
    started: Instant,
}

impl Log {
    /// The tool's log; where bars may show (stderr a terminal, not `-q`), it also installs
    /// the bars as the engines' progress sink ([`nimbus_progress`]), so their long loops
    /// show one bar each.
    pub fn new(tool: &'static str, verbosity: Verbosity) -> Log {
        let log = Log { tool, verbosity, times: Mutex::new(StageTimes::default()), started: Instant::now() };
        if log.bars_visible() {
            nimbus_progress::install(Some(std::sync::Arc::new(Bars { tool, current: Mutex::new(None) })));
        }
        log
    }

    /// Bars are drawn only on a terminal, and not with `-q` (design.md section 7).
    fn bars_visible(&self) -> bool {
        self.verbosity > Verbosity::Quiet && std::io::stderr().is_terminal() && std::env::var_os("NIMBUS_NO_PROGRESS").is_none()
    }

    pub fn verbosity(&self) -> Verbosity {
        self.verbosity
    }

    pub fn warn(&self, what: impl std::fmt::Display) {
        if self.verbosity > Verbosity::Quiet {
            eprintln!("warning: {what}");
        }
    }

    /// A line a user should read, not a fault: printed unless `-q`.
    pub fn note(&self, what: impl std::fmt::Display) {
        if self.verbosity > Verbosity::Quiet {
            eprintln!("{}: {what}", self.tool);
        }
    }

    /// A line printed only with `-v`.
    pub fn verbose(&self, what: impl std::fmt::Display) {
        if self.verbosity == Verbosity::Verbose {
            eprintln!("{}: {what}", self.tool);
        }
    }

    /// Runs one stage, recording its time; with `-v` prints the time and what `summary` says
    /// about the stage's result (counts).
    pub fn stage<T>(&self, name: &str, body: impl FnOnce() -> T, summary: impl FnOnce(&T) -> String) -> T {
        let start = Instant::now();
        let result = body();
        let took = start.elapsed();
        self.times.lock().unwrap().stages.push((name.to_string(), took));
        if self.verbosity == Verbosity::Verbose {
            let s = summary(&result);
            let sep = if s.is_empty() { "" } else { "  " };
            eprintln!("{}: {:<14} {:>9.3} s{sep}{s}", self.tool, name, took.as_secs_f64());
        }
        result
    }

    pub fn times(&self) -> StageTimes {
        self.times.lock().unwrap().clone()
    }

    /// With `-v`, the closing total line.
    pub fn finish(&self) {
        self.verbose(format!("{:<14} {:>9.3} s", "total", self.started.elapsed().as_secs_f64()));
    }

    /// A progress bar over `len` steps, drawn only when stderr is a terminal and not `-q`.
    pub fn progress(&self, what: &str, len: u64) -> Progress {
        let visible = self.bars_visible();
        let bar = if visible { new_bar(self.tool, what, len) } else { ProgressBar::hidden() };
        Progress { bar, visible, shown: Arc::new(AtomicBool::new(false)), started: Instant::now() }
    }
}

/// A bar that starts hidden: [`Progress::inc`] shows it once its step has run a second, so
/// steps shorter than that never flash one (design.md section 7).
fn new_bar(tool: &str, what: &str, len: u64) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::hidden());
    bar.set_style(
        ProgressStyle::with_template("{prefix} {msg:<17} [{bar:32}] {percent:>3}% {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(tool.to_string());
    bar.set_message(what.to_string());
    bar
}

/// The engines' progress sink on a terminal: one bar per task.
struct Bars {
    tool: &'static str,
    current: Mutex<Option<Progress>>,
}

impl nimbus_progress::Sink for Bars {
    fn begin(&self, what: &str, total: u64) {
        let bar = Progress { bar: new_bar(self.tool, what, total), visible: true, shown: Arc::new(AtomicBool::new(false)), started: Instant::now() };
        if let Some(old) = self.current.lock().unwrap_or_else(|e| e.into_inner()).replace(bar) {
            old.finish();
        }
    }

    fn advance(&self, n: u64) {
        // Cloned out of the lock: a bar's handle is an Arc.
        let bar = self.current.lock().unwrap_or_else(|e| e.into_inner()).clone();
        if let Some(bar) = bar {
            bar.inc(n);
        }
    }

    fn end(&self) {
        if let Some(bar) = self.current.lock().unwrap_or_else(|e| e.into_inner()).take() {
            bar.finish();
        }
    }
}

/// A progress bar handle; cheap to share across rayon workers.
#[derive(Clone)]
pub struct Progress {
    bar: ProgressBar,
    /// Whether the bar may show at all (a terminal, not -q).
    visible: bool,
    shown: Arc<AtomicBool>,
    started: Instant,
}

impl Progress {
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        if !self.visible || self.shown.load(Ordering::Relaxed) || self.started.elapsed() < Duration::from_secs(1) {
            return;
        }
        if !self.shown.swap(true, Ordering::Relaxed) {
            self.bar.set_draw_target(ProgressDrawTarget::stderr());
            self.bar.enable_steady_tick(Duration::from_millis(250));
        }
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
