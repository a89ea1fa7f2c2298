use std::fs;
use std::io::{self, IsTerminal, Read, Write};
use std::path::{Path, PathBuf};

use crate::Failure;

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
        match arg {
            Some(p) if p.as_os_str() == "-" => Ok(Input::Stdin),
            Some(p) => Ok(Input::Path(p.to_path_buf())),
            None if !io::stdin().is_terminal() => Ok(Input::Stdin),
            None => Err(Failure::usage("no input: give a file, or pipe one in (see --help)")),
        }
    }

    /// The name used in messages.
    pub fn name(&self) -> String {
        match self {
            Input::Path(p) => p.display().to_string(),
            Input::Stdin => "stdin".into(),
        }
    }

    /// The file's extension, lower-cased, when there is one.
    pub fn extension(&self) -> Option<String> {
        match self {
            Input::Path(p) => p.extension().map(|e| e.to_string_lossy().to_lowercase()),
            Input::Stdin => None,
        }
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
        match arg {
            Some(p) if p.as_os_str() == "-" => Ok(Output::Stdout),
            Some(p) => Ok(Output::Path(p.to_path_buf())),
            None if !io::stdout().is_terminal() => Ok(Output::Stdout),
            None => Err(Failure::usage("no output: give -o FILE, or pipe into the next tool (see --help)")),
        }
    }

    pub fn name(&self) -> String {
        match self {
            Output::Path(p) => p.display().to_string(),
            Output::Stdout => "stdout".into(),
        }
    }

    pub fn extension(&self) -> Option<String> {
        match self {
            Output::Path(p) => p.extension().map(|e| e.to_string_lossy().to_lowercase()),
            Output::Stdout => None,
        }
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
/// run leaves the old file (or none) behind.
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut io::BufWriter<fs::File>) -> io::Result<()>) -> Result<(), Failure> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| Failure::usage(format!("not a file name ({})", path.display())))?;
    let tmp = dir.join(format!(".{}.{}.tmp", name.to_string_lossy(), std::process::id()));
    let result = (|| {
        let mut w = io::BufWriter::new(fs::File::create(&tmp)?);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Failure::runtime(format!("cannot write: {e}"), path.display())
    })
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
