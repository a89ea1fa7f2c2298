//! A process-wide progress hook (design.md section 7, issue #31): the engines' long loops say
//! what they do and how much of it is done; a front end installs a [`Sink`] that shows it
//! (nimbus-cli draws bars on a terminal). Without a sink every call is a load and a branch,
//! so library users and tests pay nothing.
//!
//! An engine wraps a loop in a [`Task`] and counts finished items from its rayon workers:
//!
//! ```
//! let task = nimbus_progress::task("single scattering", 1000);
//! (0..1000u64).for_each(|_| task.advance(1));
//! drop(task); // or task.finish()
//! ```
//!
//! One sink serves the process: the tools run one job at a time. Tasks nest only in sequence
//! (a task begun while another is open is shown after it); counts are advisory and never
//! change what an engine computes.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock};

/// What shows progress: one task at a time, begun, advanced from any thread, ended.
pub trait Sink: Send + Sync {
    /// A task of `total` items begins (`total` 0: unknown).
    fn begin(&self, what: &str, total: u64);
    /// `n` more items of the current task are done.
    fn advance(&self, n: u64);
    /// The current task ended.
    fn end(&self);
}

static INSTALLED: AtomicBool = AtomicBool::new(false);
static SINK: RwLock<Option<Arc<dyn Sink>>> = RwLock::new(None);

/// Makes `sink` the process's progress sink (None removes it).
pub fn install(sink: Option<Arc<dyn Sink>>) {
    let mut slot = SINK.write().unwrap_or_else(|e| e.into_inner());
    INSTALLED.store(sink.is_some(), Ordering::Release);
    *slot = sink;
}

fn sink() -> Option<Arc<dyn Sink>> {
    if !INSTALLED.load(Ordering::Acquire) {
        return None;
    }
    SINK.read().unwrap_or_else(|e| e.into_inner()).clone()
}

/// Whether a sink is installed: tasks begun now are heard.
pub fn shown() -> bool {
    INSTALLED.load(Ordering::Acquire)
}

/// About how many steps [`step_size`] splits heard work into.
pub const STEPS: u64 = 64;

/// Items per step for work that goes in steps of at most `most` items (a GPU dispatch and
/// its read-back, say): `most`; where a sink is installed, few enough that `items` take
/// about [`STEPS`] steps, so that a bar moves, but at least `least`. An engine's steps never
/// change what it computes, only how often it hears back.
pub fn step_size(items: u64, most: u64, least: u64) -> u64 {
    let step = if shown() { most.min(items.div_ceil(STEPS).max(least)) } else { most };
    step.max(1)
}

/// One announced loop; ends when dropped. Cheap to share by reference across rayon workers.
pub struct Task {
    sink: Option<Arc<dyn Sink>>,
}

/// Begins a task of `total` items (0 when unknown) named `what`.
pub fn task(what: &str, total: u64) -> Task {
    let sink = sink();
    if let Some(s) = &sink {
        s.begin(what, total);
    }
    Task { sink }
}

impl Task {
    /// `n` more items are done.
    #[inline]
    pub fn advance(&self, n: u64) {
        if let Some(s) = &self.sink {
            s.advance(n);
        }
    }

    /// Whether a sink hears this task: an engine may then split its work finer (never
    /// changing what it computes).
    pub fn shown(&self) -> bool {
        self.sink.is_some()
    }

    /// Ends the task (as dropping it does).
    pub fn finish(self) {}
}

impl Drop for Task {
    fn drop(&mut self) {
        if let Some(s) = &self.sink {
            s.end();
        }
    }
}

/// What a [`Tally`] heard of one task.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Heard {
    pub what: String,
    pub total: u64,
    /// Calls of [`Task::advance`].
    pub steps: u64,
    /// Items they counted.
    pub done: u64,
}

/// A sink that keeps what it hears, for tests of an engine's progress.
#[derive(Default)]
pub struct Tally(Mutex<Vec<Heard>>);

impl Tally {
    /// Runs `f` with a tally installed (and none after): its result, and the tasks heard.
    /// The sink is the process's: a test binary using this should hold one test.
    pub fn during<T>(f: impl FnOnce() -> T) -> (T, Vec<Heard>) {
        let tally = Arc::new(Tally::default());
        install(Some(tally.clone()));
        let result = f();
        install(None);
        let heard = std::mem::take(&mut *tally.0.lock().unwrap_or_else(|e| e.into_inner()));
        (result, heard)
    }
}

impl Sink for Tally {
    fn begin(&self, what: &str, total: u64) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).push(Heard { what: what.to_string(), total, steps: 0, done: 0 });
    }
    fn advance(&self, n: u64) {
        if let Some(task) = self.0.lock().unwrap_or_else(|e| e.into_inner()).last_mut() {
            task.steps += 1;
            task.done += n;
        }
    }
    fn end(&self) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default)]
    struct Record(Mutex<Vec<String>>);

    impl Sink for Record {
        fn begin(&self, what: &str, total: u64) {
            self.0.lock().unwrap().push(format!("begin {what} {total}"));
        }
        fn advance(&self, n: u64) {
            self.0.lock().unwrap().push(format!("advance {n}"));
        }
        fn end(&self) {
            self.0.lock().unwrap().push("end".into());
        }
    }

    #[test]
    fn a_task_reaches_the_installed_sink_and_nothing_without_one() {
        task("unseen", 3).advance(3);
        let record = Arc::new(Record::default());
        install(Some(record.clone()));
        assert_eq!(step_size(6400, 1000, 1), 100, "heard work goes in about STEPS steps");
        assert_eq!(step_size(6400, 1000, 500), 500);
        let t = task("loop", 2);
        t.advance(1);
        t.advance(1);
        t.finish();
        install(None);
        task("unseen again", 1).advance(1);
        assert_eq!(step_size(1000, 100, 1), 100, "unheard work goes in the largest steps");
        assert_eq!(*record.0.lock().unwrap(), ["begin loop 2", "advance 1", "advance 1", "end"]);
    }
}
