//! A table as written by hand or by a program: CSV (with a header, `#`
//! comments) or Parquet, read whole, with typed columns whose errors name
//! the file, the line or row, and the field. Every long or wide table mdpipe
//! reads (measurements, a simulator's outputs, training tables) goes through it.

use super::error::{ColumnError, FieldError};
use anyhow::{anyhow, Context, Result};
use polars::prelude::{DataFrame, ParquetReader, SerReader};
use std::path::Path;

/// A table read as text cells (CSV) or typed columns (Parquet), with
/// row numbers for error messages.
pub enum RawTable {
    Csv { headers: Vec<String>, rows: Vec<(usize, Vec<String>)> },
    Parquet(DataFrame),
}

impl RawTable {
    pub fn read(path: &Path) -> Result<RawTable> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if ext == "parquet" || ext == "pq" {
            return Ok(RawTable::Parquet(read_parquet(path)?));
        }
        let mut reader = csv::ReaderBuilder::new()
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            // A short or long row is reported by the field it lacks, with its line.
            .flexible(true)
            .from_path(path)
            .with_context(|| format!("opening table {}", path.display()))?;
        let headers: Vec<String> = reader
            .headers()
            .with_context(|| format!("{}: reading header", path.display()))?
            .iter()
            .map(String::from)
            .collect();
        let mut rows = Vec::new();
        for rec in reader.records() {
            let rec = rec.with_context(|| format!("{}: malformed CSV", path.display()))?;
            let line = rec.position().map(|p| p.line() as usize).unwrap_or(0);
            rows.push((line, rec.iter().map(String::from).collect()));
        }
        Ok(RawTable::Csv { headers, rows })
    }

    pub fn columns(&self) -> Vec<String> {
        match self {
            RawTable::Csv { headers, .. } => headers.clone(),
            RawTable::Parquet(df) => df.get_column_names().iter().map(|s| s.to_string()).collect(),
        }
    }

    pub fn height(&self) -> usize {
        match self {
            RawTable::Csv { rows, .. } => rows.len(),
            RawTable::Parquet(df) => df.height(),
        }
    }

    /// The file's line (CSV) or row (Parquet, 1-based) of row `i`.
    pub fn line(&self, i: usize) -> usize {
        match self {
            RawTable::Csv { rows, .. } => rows[i].0,
            RawTable::Parquet(_) => i + 1,
        }
    }

    /// "line N" (CSV) or "row N" (Parquet, 1-based).
    pub fn location(&self, i: usize) -> String {
        match self {
            RawTable::Csv { rows, .. } => format!("line {}", rows[i].0),
            RawTable::Parquet(_) => format!("row {}", i + 1),
        }
    }

    pub fn has(&self, name: &str) -> bool {
        self.columns().iter().any(|c| c == name)
    }

    pub fn missing(&self, path: &Path, name: &str) -> anyhow::Error {
        ColumnError::Missing { file: path.to_path_buf(), column: name.into(), found: self.columns(), expected: &[] }
            .into()
    }

    pub fn numbers(&self, path: &Path, name: &str) -> Result<Vec<f64>> {
        match self {
            RawTable::Csv { headers, rows } => {
                let k = headers.iter().position(|h| h == name).ok_or_else(|| self.missing(path, name))?;
                rows.iter()
                    .map(|(line, cells)| {
                        let s = cells.get(k).map(String::as_str).unwrap_or("");
                        s.parse::<f64>().map_err(|_| {
                            FieldError::new(
                                path,
                                format_args!("line {line}"),
                                name,
                                format_args!("cannot parse {s:?} as a number"),
                            )
                            .into()
                        })
                    })
                    .collect()
            }
            RawTable::Parquet(df) => crate::base::columns::f64_column(df, path, name),
        }
    }

    /// A column whose cells may be empty (CSV) or null (Parquet): `None` there.
    pub fn optional_numbers(&self, path: &Path, name: &str) -> Result<Vec<Option<f64>>> {
        match self {
            RawTable::Csv { headers, rows } => {
                let k = headers.iter().position(|h| h == name).ok_or_else(|| self.missing(path, name))?;
                rows.iter()
                    .map(|(line, cells)| match cells.get(k).map(String::as_str).unwrap_or("") {
                        "" => Ok(None),
                        s => s.parse::<f64>().map(Some).map_err(|_| {
                            let problem = format_args!("cannot parse {s:?} as a number");
                            FieldError::new(path, format_args!("line {line}"), name, problem).into()
                        }),
                    })
                    .collect()
            }
            RawTable::Parquet(df) => crate::base::columns::optional_f64_column(df, path, name),
        }
    }

    pub fn strings(&self, path: &Path, name: &str) -> Result<Vec<String>> {
        match self {
            RawTable::Csv { headers, rows } => {
                let k = headers.iter().position(|h| h == name).ok_or_else(|| self.missing(path, name))?;
                Ok(rows.iter().map(|(_, cells)| cells.get(k).cloned().unwrap_or_default()).collect())
            }
            RawTable::Parquet(df) => crate::base::columns::str_column(df, path, name),
        }
    }
}

/// Reads a Parquet file whole.
pub fn read_parquet(path: &Path) -> Result<DataFrame> {
    let f = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let read = without_panics(path, "Parquet", || ParquetReader::new(f).finish())?;
    read.map_err(|e| anyhow!("reading Parquet file {}: {e}", path.display()))
}

/// Runs a third-party parser, turning a panic on a corrupt file (polars'
/// Parquet metadata decoder panics on some damaged footers) into an error
/// that names the file: no input may panic mdpipe.
pub fn without_panics<T>(path: &Path, format: &str, parse: impl FnOnce() -> T) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(parse)).map_err(|p| {
        let why = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        anyhow!("{}: not a readable {format} file (the decoder failed: {why})", path.display())
    })
}
