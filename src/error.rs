//! The one error type of terratile: every variant says *where* (file and byte offset, line,
//! config key, stage parameter) so that a user can find and fix the input.

use std::path::{Path, PathBuf};

/// A terratile result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong, with the context a user needs to fix it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system refused a file operation.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A binary file is malformed at a known byte offset.
    #[error("{}: byte {offset}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// Byte offset of the offending field or record.
        offset: u64,
        /// What is wrong there.
        message: String,
    },
    /// A text file is malformed at a known line (1-based).
    #[error("{}:{line}: {message}", path.display())]
    Text {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong on that line.
        message: String,
    },
    /// A pipeline file is invalid: wrong type, unknown key, bad value.
    #[error("{}:{line}:{column}: {key}: {message}", path.display())]
    Config {
        /// The pipeline file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// Dotted key path, e.g. `input.classes`.
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// A stage parameter has a value the stage cannot work with.
    #[error("{stage}: {param} = {value}: {message}")]
    Param {
        /// The stage (`denoise`, `resample`, …).
        stage: &'static str,
        /// The parameter name as written in pipeline.toml.
        param: &'static str,
        /// The offending value, formatted.
        value: String,
        /// Why it is rejected.
        message: String,
    },
    /// The data cannot go through a stage (e.g. every point removed as noise).
    #[error("{stage}: {message}")]
    Data {
        /// The stage that cannot proceed.
        stage: &'static str,
        /// Why.
        message: String,
    },
    /// A command-line argument is invalid.
    #[error("{0}")]
    Usage(String),
    /// A bug or an unexpected failure inside terratile (exit code 1, not 2).
    #[error("internal error: {0}")]
    Internal(String),
}

impl Error {
    /// Exit code for the CLI: 2 for bad input or usage, 1 for internal failures.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Internal(_) => 1,
            _ => 2,
        }
    }

    /// A `Format` error at `offset` of `path`.
    pub fn format(path: &Path, offset: u64, message: impl Into<String>) -> Error {
        Error::Format {
            path: path.to_path_buf(),
            offset,
            message: message.into(),
        }
    }

    /// A `Text` error at 1-based `line` of `path`.
    pub fn text(path: &Path, line: u64, message: impl Into<String>) -> Error {
        Error::Text {
            path: path.to_path_buf(),
            line,
            message: message.into(),
        }
    }

    /// An `Io` error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Error {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// A `Param` error: `stage`'s `param` cannot be `value`.
    pub fn param(
        stage: &'static str,
        param: &'static str,
        value: impl std::fmt::Display,
        message: impl Into<String>,
    ) -> Error {
        Error::Param {
            stage,
            param,
            value: value.to_string(),
            message: message.into(),
        }
    }
}
