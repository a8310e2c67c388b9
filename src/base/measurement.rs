//! One measured value, and the checks every reader applies to it; one
//! entry of a covariance between two measured values.

use super::error::FieldError;
use anyhow::Result;
use std::path::Path;

/// One measured value.
#[derive(Clone, Debug)]
pub struct Measurement {
    pub observable: String,
    pub x: f64,
    pub value: f64,
    pub error: f64,
    /// Where it was read from: the CSV line or Parquet row (1-based), 0 if made in memory.
    pub line: usize,
}

impl PartialEq for Measurement {
    fn eq(&self, o: &Self) -> bool {
        self.observable == o.observable && self.x == o.x && self.value == o.value && self.error == o.error
    }
}

impl Measurement {
    pub fn new(observable: &str, x: f64, value: f64, error: f64) -> Self {
        Measurement { observable: observable.to_string(), x, value, error, line: 0 }
    }

    /// "FILE: line N" for CSV, "FILE: row N" for Parquet, for error messages.
    pub fn location(&self, path: &Path) -> String {
        format!("{}: {}", path.display(), at(path, self.line))
    }

    /// A bad value in this measurement's field.
    pub fn field_error(&self, path: &Path, field: &str, problem: impl std::fmt::Display) -> anyhow::Error {
        FieldError::new(path, at(path, self.line), field, problem).into()
    }
}

/// "row N" in a Parquet file, "line N" in a CSV file.
fn at(path: &Path, line: usize) -> String {
    let is_parquet = path.extension().is_some_and(|e| e == "parquet" || e == "pq");
    format!("{} {line}", if is_parquet { "row" } else { "line" })
}

/// A row's fields: a named observable, finite numbers, a positive error.
pub(super) fn validate_row(path: &Path, where_: &str, m: &Measurement) -> Result<()> {
    validate_row_with(path, where_, m, "error")
}

/// The same, the error read from the column `error_field` (`stat` beside
/// systematics as columns).
pub(super) fn validate_row_with(path: &Path, where_: &str, m: &Measurement, error_field: &str) -> Result<()> {
    let bad = |field: &str, problem: String| Err(FieldError::new(path, where_, field, problem).into());
    if m.observable.trim().is_empty() {
        return bad("observable", "empty observable name".into());
    }
    for (field, v) in [("x", m.x), ("value", m.value), (error_field, m.error)] {
        if !v.is_finite() {
            return bad(field, format!("value is {v}, must be a finite number"));
        }
    }
    if m.error <= 0.0 {
        return bad(error_field, format!("{} is not a positive 1-sigma error", m.error));
    }
    Ok(())
}

/// One entry of a covariance file.
#[derive(Clone, Debug, PartialEq)]
pub struct CovarianceEntry {
    pub observable_a: String,
    pub x_a: f64,
    pub observable_b: String,
    pub x_b: f64,
    pub covariance: f64,
    /// CSV line or Parquet row (1-based), for messages.
    pub line: usize,
    /// Half a unit in the last digit `covariance` was written with (a file
    /// printed to 8 significant digits, HEPData's 2 or 3), 0 for a value
    /// computed here: how far the value meant may be from the one read.
    pub rounding: f64,
}

impl CovarianceEntry {
    pub fn location(&self, path: &Path) -> String {
        format!("{}: {}", path.display(), at(path, self.line))
    }

    /// A bad value in this entry's field.
    pub fn field_error(&self, path: &Path, field: &str, problem: impl std::fmt::Display) -> anyhow::Error {
        FieldError::new(path, at(path, self.line), field, problem).into()
    }
}
