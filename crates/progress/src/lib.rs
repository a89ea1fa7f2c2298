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
use std::sync::{Arc, RwLock};

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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

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
        let t = task("loop", 2);
        t.advance(1);
        t.advance(1);
        t.finish();
        install(None);
        task("unseen again", 1).advance(1);
        assert_eq!(*record.0.lock().unwrap(), ["begin loop 2", "advance 1", "advance 1", "end"]);
    }
}
