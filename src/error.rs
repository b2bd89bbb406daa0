//! The one error type carried from the library to the CLI, which prints it as a
//! single line. Every variant names the file, line or flag at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// An OBJ or MTL file is malformed; `line` is 1-based, 0 when unknown.
    #[error("{}{}: {msg}", path.display(), if *line > 0 { format!(":{line}") } else { String::new() })]
    Parse {
        path: PathBuf,
        line: usize,
        msg: String,
    },
    /// A scene that cannot be rendered (e.g. no triangles at all).
    #[error("scene {name}: {msg}")]
    Scene { name: String, msg: String },
    /// A command-line value out of range; `flag` is the flag's name.
    #[error("{flag}: {msg}")]
    Usage { flag: String, msg: String },
    /// A report that could not be serialised (never expected: reports are
    /// plain data; non-finite numbers become null).
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// Anything else worth one line.
    #[error("{0}")]
    Other(String),
}

impl Error {
    pub fn usage(flag: &str, msg: impl Into<String>) -> Self {
        Error::Usage {
            flag: flag.to_string(),
            msg: msg.into(),
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

pub type Result<T> = std::result::Result<T, Error>;
