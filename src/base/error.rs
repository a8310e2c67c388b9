//! The library's typed errors for bad input, what a caller may act on
//! rather than read: the file, the row (or line, or bin) and the field, or
//! the column a table lacks. The library returns them inside `anyhow::Error`
//! (which carries the context of what was being done when they happened);
//! a caller finds them with `error.downcast_ref::<FieldError>()` or
//! `ColumnError` (or `ConfigError` for a config), and `app` prints the whole chain as the message. The
//! samplers' `SamplerError` and `Stopped` (`engine::calibrate`) and the
//! choices' `UnknownChoice` (`base::choices`) are typed the same way.

use std::fmt::Display;
use std::path::{Path, PathBuf};

/// A bad value in a table: where it is and what is wrong with it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {at}, field '{field}': {problem}", file.display())]
pub struct FieldError {
    pub file: PathBuf,
    /// "row 3" (Parquet), "line 4" (CSV), "bin 2" (HEPData).
    pub at: String,
    pub field: String,
    pub problem: String,
}

/// "; expected: a, b" when the reader says which columns it expects.
fn expecting(expected: &[&str]) -> String {
    if expected.is_empty() {
        String::new()
    } else {
        format!("; expected: {}", expected.join(", "))
    }
}

impl ColumnError {
    /// The same error, saying which columns the reader expects.
    pub fn expecting(self, columns: &'static [&'static str]) -> ColumnError {
        match self {
            ColumnError::Missing { file, column, found, .. } => {
                ColumnError::Missing { file, column, found, expected: columns }
            }
            other => other,
        }
    }
}

impl FieldError {
    pub fn new(file: &Path, at: impl Display, field: &str, problem: impl Display) -> FieldError {
        FieldError { file: file.to_path_buf(), at: at.to_string(), field: field.into(), problem: problem.to_string() }
    }
}

/// A config that is not what mdpipe reads: its file, where in it (a table,
/// a table and key: "[discrepancy.bounds] cbar"; empty for the TOML
/// syntax, whose message says where) and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {}{problem}", file.display(), if place.is_empty() { String::new() } else { format!("{place}: ") })]
pub struct ConfigError {
    pub file: PathBuf,
    pub place: String,
    pub problem: String,
}

impl ConfigError {
    pub fn new(file: &Path, place: impl Display, problem: impl Display) -> ConfigError {
        ConfigError { file: file.to_path_buf(), place: place.to_string(), problem: problem.to_string() }
    }
}

/// A table without a column it must have, or with one of the wrong type.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ColumnError {
    #[error("{}: missing column '{column}' (found: {}{})", file.display(), found.join(", "), expecting(expected))]
    Missing { file: PathBuf, column: String, found: Vec<String>, expected: &'static [&'static str] },
    #[error("{}: column '{column}' must be {expected}", file.display())]
    WrongType { file: PathBuf, column: String, expected: &'static str },
}
