//! Columns of a Parquet table read whole, with errors that name the file,
//! the row and the field: the one helper every table reader uses.

use super::error::{ColumnError, FieldError};
use anyhow::Result;
use polars::prelude::{DataFrame, DataType};
use std::path::Path;

/// Column `name` as numbers (any numeric type), every row present.
pub fn f64_column(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<f64>> {
    let c = column(df, file, name)?.cast(&DataType::Float64).map_err(|_| wrong_type(file, name, "numeric"))?;
    let ca = c.f64()?;
    (0..df.height()).map(|i| ca.get(i).ok_or_else(|| missing_value(file, i, name))).collect()
}

/// Column `name` as numbers, a null row as `None`.
pub fn optional_f64_column(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<Option<f64>>> {
    let c = column(df, file, name)?.cast(&DataType::Float64).map_err(|_| wrong_type(file, name, "numeric"))?;
    let ca = c.f64()?;
    Ok((0..df.height()).map(|i| ca.get(i)).collect())
}

/// Column `name` as strings, every row present.
pub fn str_column(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<String>> {
    let c = column(df, file, name)?;
    let ca = c.str().map_err(|_| wrong_type(file, name, "a string column"))?;
    (0..df.height()).map(|i| ca.get(i).map(String::from).ok_or_else(|| missing_value(file, i, name))).collect()
}

/// Whether the table has a column of that name.
pub fn has_column(df: &DataFrame, name: &str) -> bool {
    df.column(name).is_ok()
}

fn column<'a>(df: &'a DataFrame, file: &Path, name: &str) -> Result<&'a polars::prelude::Column> {
    df.column(name).map_err(|_| {
        let found: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
        ColumnError::Missing { file: file.to_path_buf(), column: name.into(), found, expected: &[] }.into()
    })
}

fn wrong_type(file: &Path, column: &str, expected: &'static str) -> anyhow::Error {
    ColumnError::WrongType { file: file.to_path_buf(), column: column.into(), expected }.into()
}

fn missing_value(file: &Path, row: usize, field: &str) -> anyhow::Error {
    FieldError::new(file, format_args!("row {}", row + 1), field, "missing value").into()
}
