use std::fmt;
use std::process::ExitCode;

/// A failure to report: one line, and the exit code it ends the process with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Failure {
    pub code: u8,
    pub message: String,
}

impl Failure {
    /// Bad usage or bad input (exit code 2): the user can fix it by changing what they give.
    pub fn input(what: impl fmt::Display, place: impl fmt::Display) -> Failure {
        Failure { code: 2, message: format!("{what} ({place})") }
    }

    /// A bad flag or flag combination (exit code 2).
    pub fn usage(what: impl fmt::Display) -> Failure {
        Failure { code: 2, message: what.to_string() }
    }

    /// A failure already reported on stderr (by another tool of the pipe): the exit code
    /// only, no line of its own.
    pub fn reported(code: u8) -> Failure {
        Failure { code, message: String::new() }
    }

    /// Something went wrong while running (exit code 1).
    pub fn runtime(what: impl fmt::Display, place: impl fmt::Display) -> Failure {
        Failure { code: 1, message: format!("{what} ({place})") }
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Failure {}

/// Attaches where an error happened, and whether it is the input's fault.
pub trait ResultExt<T> {
    fn input_err(self, place: impl fmt::Display) -> Result<T, Failure>;
    fn runtime_err(self, place: impl fmt::Display) -> Result<T, Failure>;
}

impl<T, E: fmt::Display> ResultExt<T> for Result<T, E> {
    fn input_err(self, place: impl fmt::Display) -> Result<T, Failure> {
        self.map_err(|e| Failure::input(e, place))
    }

    fn runtime_err(self, place: impl fmt::Display) -> Result<T, Failure> {
        self.map_err(|e| Failure::runtime(e, place))
    }
}

/// Runs a tool's body and turns its outcome into the exit code, printing `error: ...` on
/// failure. A panic is a bug, but the user still gets one error line and exit code 1
/// rather than a backtrace as the last word.
pub fn run(body: impl FnOnce() -> Result<(), Failure> + std::panic::UnwindSafe) -> ExitCode {
    let outcome = std::panic::catch_unwind(body).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown".into());
        Err(Failure::runtime(format!("internal error: {what}"), "please report this"))
    });
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            if !failure.message.is_empty() {
                eprintln!("error: {failure}");
            }
            ExitCode::from(failure.code)
        }
    }
}
