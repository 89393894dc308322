//! The library's error type.
//!
//! Every message is one line that names the file (when there is one) and the problem,
//! because the command line prints it as-is after `error: ` and users fix inputs from it.
//! Modules add variants here rather than inventing their own types, so that `main` has a
//! single place that turns failures into exit codes.

use std::fmt::Display;
use std::path::{Path, PathBuf};

/// What went wrong, with the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A control mesh could not be read or is not a valid manifold mesh (the message comes
    /// from `subdiv` and already names the file and the first offending element).
    #[error(transparent)]
    Mesh(#[from] subdiv::MeshError),
    /// An input or output file could not be read, decoded, created or written.
    #[error("{}: {problem}", path.display())]
    File { path: PathBuf, problem: String },
    /// A parameter is out of range or inconsistent (no file involved).
    #[error("{0}")]
    Invalid(String),
}

/// Result with [`Error`] as the default error.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A problem with `path`; `problem` is flattened to one line.
    pub fn file(path: impl AsRef<Path>, problem: impl Display) -> Self {
        Error::File {
            path: path.as_ref().to_path_buf(),
            problem: one_line(&problem.to_string()),
        }
    }

    /// An I/O failure while doing `action` ("cannot create", "cannot read", ...) on `path`.
    pub fn io(path: impl AsRef<Path>, action: &str, err: std::io::Error) -> Self {
        Self::file(path, format!("{action}: {err}"))
    }

    /// A bad parameter.
    pub fn invalid(msg: impl Display) -> Self {
        Error::Invalid(one_line(&msg.to_string()))
    }
}

/// Collapses line breaks and runs of whitespace, because third-party messages (image
/// decoders, clap) sometimes span several lines and our contract is one line per error.
/// Other control characters (which hostile files can smuggle into messages that quote
/// them, e.g. terminal escape sequences) become U+FFFD.
pub fn one_line(s: &str) -> String {
    s.split_whitespace()
        .map(|w| w.replace(|c: char| c.is_control(), "\u{fffd}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_one_line_and_name_the_file() {
        let e = Error::file("a/b.png", "bad\n  header\r\nline");
        assert_eq!(e.to_string(), "a/b.png: bad header line");
        assert_eq!(one_line("'\x1b[31mred\x07'"), "'\u{fffd}[31mred\u{fffd}'");
        let e = Error::io(
            "x.exr",
            "cannot create",
            std::io::Error::from(std::io::ErrorKind::NotFound),
        );
        assert!(e.to_string().starts_with("x.exr: cannot create: "));
    }
}
