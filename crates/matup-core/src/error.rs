//! The one error type of matup's libraries.

use std::path::{Path, PathBuf};

/// Everything that can go wrong in matup's libraries. Each variant that concerns a file
/// carries its path, so the message a user sees always names the file and the problem.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },

    #[error("{}: cannot read or write: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    #[error("{}: {message}", folder.display())]
    Material { folder: PathBuf, message: String },

    #[error("unknown {kind} '{name}'; known: {}", known.join(", "))]
    UnknownPlugin {
        kind: &'static str,
        name: String,
        known: Vec<String>,
    },

    #[error("{kind} '{name}' is registered twice")]
    DuplicatePlugin { kind: &'static str, name: String },

    #[error("{plugin}: {message}")]
    Plugin { plugin: String, message: String },

    #[error("{0}")]
    Invalid(String),

    #[error("{what} is not supported by {plugin}")]
    Unsupported { plugin: String, what: String },

    #[error(
        "interrupted after {epochs_done} finished epoch(s); run again with --resume to continue"
    )]
    Cancelled { epochs_done: usize },

    /// The user asked a run without checkpoints to stop: it stopped before writing what was
    /// not finished.
    #[error("interrupted: what was not finished was not written; run the same command again")]
    Interrupted,

    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// `Result` with matup's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        Error::File {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn material(folder: &Path, message: impl Into<String>) -> Self {
        Error::Material {
            folder: folder.to_path_buf(),
            message: message.into(),
        }
    }
}
