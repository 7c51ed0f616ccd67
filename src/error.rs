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
    /// A setting at a dotted key of the pipeline file (`assets[0].output`) is wrong: checks
    /// that know the key but not the file return this, and the pipeline file's loader
    /// locates it (`LoadedPipeline::param_error`).
    #[error("{key}: {message}")]
    Key {
        /// Dotted key path, e.g. `assets[1].simplify.ratio`.
        key: String,
        /// What is wrong with it.
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

    /// A [`Error::Key`] error: the setting at `key` is wrong.
    pub fn key(key: impl Into<String>, message: impl Into<String>) -> Error {
        Error::Key {
            key: key.into(),
            message: message.into(),
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

/// Range checks shared by the settings of every stage: each passes a good value and returns
/// the [`Error::Param`] that names the stage, the key and the value otherwise.
pub(crate) mod check {
    use super::{Error, Result};

    /// `value` must be a finite number > 0.
    pub(crate) fn positive(
        stage: &'static str,
        param: &'static str,
        value: f64,
        message: &str,
    ) -> Result<()> {
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(Error::param(stage, param, value, message))
        }
    }

    /// `value` must be a finite number >= 0.
    pub(crate) fn non_negative(
        stage: &'static str,
        param: &'static str,
        value: f64,
        message: &str,
    ) -> Result<()> {
        if value.is_finite() && value >= 0.0 {
            Ok(())
        } else {
            Err(Error::param(stage, param, value, message))
        }
    }
}

/// `s` on one line, safe for a terminal: every control character (CR, LF, tab, ESC, DEL,
/// the C1 range) and the bidirectional-override characters are written as escapes
/// (`\r`, `\n`, `\u{1b}`, …), so a file name, a TOML value or file content echoed in a
/// message can neither break the one-line error rule nor drive the terminal. Other text,
/// quotes and backslashes included, is kept as is.
pub fn one_line(s: &str) -> std::borrow::Cow<'_, str> {
    let unsafe_char =
        |c: char| c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
    if !s.chars().any(unsafe_char) {
        return std::borrow::Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if unsafe_char(c) {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    std::borrow::Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_escapes_control_characters_only() {
        assert_eq!(one_line("a.las: byte 4: bad"), "a.las: byte 4: bad");
        assert_eq!(one_line("a\r\nb\tc"), "a\\r\\nb\\tc");
        assert_eq!(one_line("\u{1b}[31mred"), "\\u{1b}[31mred");
        assert_eq!(one_line("x\u{9b}y\u{7f}"), "x\\u{9b}y\\u{7f}");
        assert_eq!(one_line("\u{202e}gpj.exe"), "\\u{202e}gpj.exe");
        assert_eq!(one_line("é \"q\" \\ ü"), "é \"q\" \\ ü");
    }
}
