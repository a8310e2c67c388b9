//! Columns of a Parquet table read whole, with errors that name the file,
//! the row and the field: the one helper every table reader uses.

use anyhow::{anyhow, Result};
use polars::prelude::{DataFrame, DataType};
use std::path::Path;

/// Column `name` as numbers (any numeric type), every row present.
pub fn f64_column(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<f64>> {
    let c = column(df, file, name)?
        .cast(&DataType::Float64)
        .map_err(|_| anyhow!("{}: column '{name}' must be numeric", file.display()))?;
    let ca = c.f64()?;
    (0..df.height())
        .map(|i| ca.get(i).ok_or_else(|| anyhow!("{}: row {}, field '{name}': missing value", file.display(), i + 1)))
        .collect()
}

/// Column `name` as strings, every row present.
pub fn str_column(df: &DataFrame, file: &Path, name: &str) -> Result<Vec<String>> {
    let c = column(df, file, name)?;
    let ca = c.str().map_err(|_| anyhow!("{}: column '{name}' must be a string column", file.display()))?;
    (0..df.height())
        .map(|i| {
            ca.get(i)
                .map(String::from)
                .ok_or_else(|| anyhow!("{}: row {}, field '{name}': missing value", file.display(), i + 1))
        })
        .collect()
}

/// Whether the table has a column of that name.
pub fn has_column(df: &DataFrame, name: &str) -> bool {
    df.column(name).is_ok()
}

fn column<'a>(df: &'a DataFrame, file: &Path, name: &str) -> Result<&'a polars::prelude::Column> {
    df.column(name).map_err(|_| {
        let found: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
        anyhow!("{}: missing column '{name}' (found: {})", file.display(), found.join(", "))
    })
}
