use std::fs;
use std::io::{self, IsTerminal, Read, Write};
use std::path::{Path, PathBuf};

use crate::Failure;

/// A path flag of [`Input`] or [`Output`]: `-` is the standard stream (`None`), a path is
/// itself, and no flag is the standard stream unless that is a terminal (`missing` then).
fn stream_arg(arg: Option<&Path>, terminal: bool, missing: &str) -> Result<Option<PathBuf>, Failure> {
    match arg {
        Some(p) if p.as_os_str() == "-" => Ok(None),
        Some(p) => Ok(Some(p.to_path_buf())),
        None if !terminal => Ok(None),
        None => Err(Failure::usage(missing)),
    }
}

fn lower_extension(path: &Path) -> Option<String> {
    path.extension().map(|e| e.to_string_lossy().to_lowercase())
}

/// Where a tool reads from: a file, or stdin.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Input {
    Path(PathBuf),
    Stdin,
}

impl Input {
    /// `None` means "not given": stdin when it is a pipe or file, else a usage error, since
    /// waiting on a terminal for binary data is never what the user meant.
    pub fn from_arg(arg: Option<&Path>) -> Result<Input, Failure> {
        let path = stream_arg(arg, io::stdin().is_terminal(), "no input: give a file, or pipe one in (see --help)")?;
        Ok(path.map_or(Input::Stdin, Input::Path))
    }

    fn path(&self) -> Option<&Path> {
        match self {
            Input::Path(p) => Some(p),
            Input::Stdin => None,
        }
    }

    /// The name used in messages.
    pub fn name(&self) -> String {
        self.path().map_or("stdin".into(), |p| p.display().to_string())
    }

    /// The file's extension, lower-cased, when there is one.
    pub fn extension(&self) -> Option<String> {
        self.path().and_then(lower_extension)
    }

    pub fn open(&self) -> Result<Box<dyn Read>, Failure> {
        match self {
            Input::Path(p) => {
                let f = fs::File::open(p).map_err(|e| Failure::input(format!("cannot open: {e}"), p.display()))?;
                Ok(Box::new(io::BufReader::with_capacity(1 << 20, f)))
            }
            Input::Stdin => Ok(Box::new(io::BufReader::with_capacity(1 << 20, io::stdin().lock()))),
        }
    }

    pub fn read_all(&self) -> Result<Vec<u8>, Failure> {
        let mut bytes = Vec::new();
        self.open()?
            .read_to_end(&mut bytes)
            .map_err(|e| Failure::input(format!("cannot read: {e}"), self.name()))?;
        Ok(bytes)
    }
}

/// Where a tool writes to: a file (atomically), or stdout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Output {
    Path(PathBuf),
    Stdout,
}

impl Output {
    /// `None` means "not given": stdout when it is not a terminal, else a usage error, so
    /// binary data never floods a terminal.
    pub fn from_arg(arg: Option<&Path>) -> Result<Output, Failure> {
        let path = stream_arg(arg, io::stdout().is_terminal(), "no output: give -o FILE, or pipe into the next tool (see --help)")?;
        Ok(path.map_or(Output::Stdout, Output::Path))
    }

    fn path(&self) -> Option<&Path> {
        match self {
            Output::Path(p) => Some(p),
            Output::Stdout => None,
        }
    }

    pub fn name(&self) -> String {
        self.path().map_or("stdout".into(), |p| p.display().to_string())
    }

    pub fn extension(&self) -> Option<String> {
        self.path().and_then(lower_extension)
    }

    /// Writes the whole file. Nothing is written to a path unless everything succeeded.
    pub fn write(&self, bytes: &[u8]) -> Result<(), Failure> {
        match self {
            Output::Path(p) => write_atomic(p, |w| w.write_all(bytes)),
            Output::Stdout => {
                let mut out = io::stdout().lock();
                out.write_all(bytes)
                    .and_then(|_| out.flush())
                    .map_err(|e| Failure::runtime(format!("cannot write: {e}"), "stdout"))
            }
        }
    }
}

/// Writes `path` through a temporary file beside it, renamed into place only once `fill`
/// succeeded and the data reached the disk: readers never see a partial file, and a failed
/// run leaves the old file (or none) behind. A run stopped by SIGTERM, SIGINT or SIGHUP (a
/// farm cancelling a task, Ctrl-C) removes its temporary files before it dies
/// ([`in_flight`]).
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut io::BufWriter<fs::File>) -> io::Result<()>) -> Result<(), Failure> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| Failure::usage(format!("not a file name ({})", path.display())))?;
    let tmp = dir.join(format!(".{}.{}.tmp", name.to_string_lossy(), std::process::id()));
    let slot = in_flight::register(&tmp);
    let result = (|| {
        let mut w = io::BufWriter::new(fs::File::create(&tmp)?);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    in_flight::release(slot);
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Failure::runtime(format!("cannot write: {e}"), path.display())
    })
}

/// The temporary files being written, which a terminating signal removes: a cancelled farm
/// task (Slurm's scancel sends SIGTERM, then SIGKILL after KillWait) leaves no partial file.
/// The handler only reads lock-free slots and calls unlink, both async-signal-safe, then dies
/// of the same signal with its default action.
mod in_flight {
    use std::ffi::CString;
    use std::path::Path;
    use std::sync::atomic::{AtomicPtr, Ordering};
    use std::sync::Once;

    const SLOTS: usize = 16;
    static PATHS: [AtomicPtr<libc::c_char>; SLOTS] = [const { AtomicPtr::new(std::ptr::null_mut()) }; SLOTS];
    static INSTALL: Once = Once::new();
    const SIGNALS: [libc::c_int; 3] = [libc::SIGTERM, libc::SIGINT, libc::SIGHUP];

    extern "C" fn on_signal(signal: libc::c_int) {
        for slot in &PATHS {
            let p = slot.load(Ordering::SeqCst);
            if !p.is_null() {
                // SAFETY: p is a NUL-terminated path leaked by register and freed only after
                // it left the slot.
                unsafe { libc::unlink(p) };
            }
        }
        // SAFETY: restoring the default action and re-raising are async-signal-safe.
        unsafe {
            libc::signal(signal, libc::SIG_DFL);
            libc::raise(signal);
        }
    }

    fn install() {
        INSTALL.call_once(|| {
            for s in SIGNALS {
                // SAFETY: installs a handler that only does async-signal-safe work; a signal a
                // caller ignores (nohup's SIGHUP) stays ignored.
                unsafe {
                    let previous = libc::signal(s, on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t);
                    if previous == libc::SIG_IGN {
                        libc::signal(s, libc::SIG_IGN);
                    }
                }
            }
        });
    }

    /// Puts `path` in a free slot (None when all are taken: the file is still written, only
    /// not cleaned up on a signal).
    pub(super) fn register(path: &Path) -> Option<usize> {
        install();
        let c = CString::new(path.as_os_str().as_encoded_bytes()).ok()?.into_raw();
        for (i, slot) in PATHS.iter().enumerate() {
            if slot.compare_exchange(std::ptr::null_mut(), c, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                return Some(i);
            }
        }
        // SAFETY: c came from into_raw above and was never shared.
        drop(unsafe { CString::from_raw(c) });
        None
    }

    pub(super) fn release(slot: Option<usize>) {
        if let Some(i) = slot {
            let p = PATHS[i].swap(std::ptr::null_mut(), Ordering::SeqCst);
            if !p.is_null() {
                // SAFETY: p came from CString::into_raw in register and left the slot.
                drop(unsafe { CString::from_raw(p) });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = std::env::temp_dir().join(format!("nimbus-cli-test-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let target = dir.join("out.vdb");
        let err = write_atomic(&target, |w| {
            w.write_all(b"half a file")?;
            Err(io::Error::other("disk on fire"))
        })
        .unwrap_err();
        assert_eq!(err.code, 1);
        assert!(err.message.contains("disk on fire"));
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 0, "no partial or temporary file remains");

        write_atomic(&target, |w| w.write_all(b"whole")).unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"whole");
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1);
        fs::remove_dir_all(&dir).unwrap();
    }

    /// A run killed by SIGTERM mid-write (a farm cancelling a task) leaves neither the target
    /// nor the temporary file: the test runs itself again as a child that signals itself
    /// half-way through a write.
    #[test]
    fn a_terminating_signal_removes_the_temporary_file() {
        const NAME: &str = "io::tests::a_terminating_signal_removes_the_temporary_file";
        if let Ok(dir) = std::env::var("NIMBUS_SIGNAL_TEST_DIR") {
            let _ = write_atomic(&Path::new(&dir).join("out.exr"), |w| {
                w.write_all(&[7u8; 1 << 16])?;
                w.flush()?;
                // SAFETY: raising a signal is always sound; the handler ends the process.
                unsafe { libc::raise(libc::SIGTERM) };
                Ok(())
            });
            std::process::exit(3);
        }
        use std::os::unix::process::ExitStatusExt;
        let dir = std::env::temp_dir().join(format!("nimbus-cli-signal-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let status = std::process::Command::new(std::env::current_exe().unwrap())
            .args([NAME, "--exact", "--test-threads=1"])
            .env("NIMBUS_SIGNAL_TEST_DIR", &dir)
            .stdout(std::process::Stdio::null())
            .status()
            .unwrap();
        assert_eq!(status.signal(), Some(libc::SIGTERM), "the child died of the signal it raised ({status})");
        let left: Vec<_> = fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name()).collect();
        assert!(left.is_empty(), "nothing left behind: {left:?}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn dash_means_the_standard_streams() {
        assert_eq!(Input::from_arg(Some(Path::new("-"))).unwrap(), Input::Stdin);
        assert_eq!(Output::from_arg(Some(Path::new("-"))).unwrap(), Output::Stdout);
        assert_eq!(Input::from_arg(Some(Path::new("a.PLY"))).unwrap().extension().as_deref(), Some("ply"));
    }

    #[test]
    fn missing_file_is_an_input_error() {
        let e = Input::Path("/nonexistent/particles.ply".into()).read_all().unwrap_err();
        assert_eq!(e.code, 2);
        assert!(e.message.contains("/nonexistent/particles.ply"));
    }
}
