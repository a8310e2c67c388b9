//! Measurement covariance beyond the per-point errors: correlated
//! systematics, a normalization uncertainty, the jackknife covariance between
//! bins measured on the same events.
//!
//! File format (CSV with a header, or Parquet with the same columns):
//! `observable_a, x_a, observable_b, x_b, covariance`. Each row is the
//! covariance of two measured points, in the measurements' units squared,
//! *added* to the diagonal of their errors² (so a diagonal entry adds
//! variance, and a file of off-diagonal entries keeps the errors as they are).
//! A pair may be given in either order or both; if both, they must agree.
//!
//! A table of simulator runs may carry `TABLE.noise_correlation.csv` beside
//! it, in the same layout with the last column `correlation`: the runs'
//! statistical errors' correlation between outputs, pooled over the runs
//! (bins of one run share its events). Without it, the errors are taken as
//! independent between outputs.

use super::artifacts::read_parquet;
use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;

pub const COVARIANCE_COLUMNS: [&str; 5] = ["observable_a", "x_a", "observable_b", "x_b", "covariance"];

/// Where the pooled correlation of a run table's errors is kept.
pub fn noise_correlation_path(table: &Path) -> std::path::PathBuf {
    table.with_extension("noise_correlation.csv")
}

pub use super::measurement::CovarianceEntry;

pub fn read_covariance(path: &Path) -> Result<Vec<CovarianceEntry>> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let rows = if ext == "parquet" || ext == "pq" {
        read_parquet_rows(path)?
    } else {
        read_csv_rows(path, COVARIANCE_COLUMNS)?
    };
    for e in &rows {
        if !(e.x_a.is_finite() && e.x_b.is_finite() && e.covariance.is_finite()) {
            bail!("{}: x and covariance must be finite numbers", e.location(path));
        }
    }
    Ok(rows)
}

const CORRELATION_COLUMNS: [&str; 5] = ["observable_a", "x_a", "observable_b", "x_b", "correlation"];

/// A noise-correlation file (CSV); each entry's `covariance` holds the
/// correlation, checked to be finite and within [-1, 1].
pub fn read_noise_correlation(path: &Path) -> Result<Vec<CovarianceEntry>> {
    let rows = read_csv_rows(path, CORRELATION_COLUMNS)?;
    for e in &rows {
        if !(e.x_a.is_finite() && e.x_b.is_finite() && e.covariance.abs() <= 1.0 + 1e-9) {
            let problem = format!("{} is not a correlation (finite, within [-1, 1])", e.covariance);
            return Err(e.field_error(path, "correlation", problem));
        }
    }
    Ok(rows)
}

/// Entries holding correlations as CSV text, header first.
pub fn noise_correlation_csv(entries: &[CovarianceEntry]) -> String {
    pairs_csv(entries, CORRELATION_COLUMNS)
}

fn read_csv_rows(path: &Path, columns: [&str; 5]) -> Result<Vec<CovarianceEntry>> {
    let file = path.display();
    let mut reader = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("opening {file}"))?;
    let headers = reader.headers().with_context(|| format!("{file}: reading header"))?.clone();
    let mut idx = [0usize; 5];
    for (k, name) in columns.iter().enumerate() {
        idx[k] = headers
            .iter()
            .position(|h| h == *name)
            .ok_or_else(|| anyhow!("{file}: line 1: missing column '{name}' (expected: {})", columns.join(", ")))?;
    }
    let mut out = Vec::new();
    for rec in reader.records() {
        let rec = rec.with_context(|| format!("{file}: malformed CSV"))?;
        let line = rec.position().map(|p| p.line() as usize).unwrap_or(0);
        let field = |k: usize| rec.get(idx[k]).unwrap_or("");
        let num = |k: usize| -> Result<f64> {
            field(k).parse::<f64>().map_err(|_| {
                let problem = format!("cannot parse {:?} as a number", field(k));
                anyhow::Error::from(super::error::FieldError::new(path, format!("line {line}"), columns[k], problem))
            })
        };
        out.push(CovarianceEntry {
            observable_a: field(0).to_string(),
            x_a: num(1)?,
            observable_b: field(2).to_string(),
            x_b: num(3)?,
            covariance: num(4)?,
            line,
            rounding: printed_rounding(field(4)),
        });
    }
    Ok(out)
}

fn read_parquet_rows(path: &Path) -> Result<Vec<CovarianceEntry>> {
    use super::columns::{f64_column, str_column};
    let df = read_parquet(path)?;
    let (oa, ob) = (str_column(&df, path, "observable_a")?, str_column(&df, path, "observable_b")?);
    let (xa, xb) = (f64_column(&df, path, "x_a")?, f64_column(&df, path, "x_b")?);
    let c = f64_column(&df, path, "covariance")?;
    Ok((0..df.height())
        .map(|i| CovarianceEntry {
            observable_a: oa[i].clone(),
            x_a: xa[i],
            observable_b: ob[i].clone(),
            x_b: xb[i],
            covariance: c[i],
            line: i + 1,
            // A Parquet double holds no digits of its own: its shortest
            // decimal form is what the writer rounded it to.
            rounding: printed_rounding(&format!("{:e}", c[i])),
        })
        .collect())
}

/// Half a unit in the last digit of a number as printed (`"2.50e-3"` →
/// 5e-6, `"1200"` → 0.5): how far the written value may be from the one
/// meant. A double printed in full has a rounding below its own precision.
pub fn printed_rounding(text: &str) -> f64 {
    let text = text.trim().trim_start_matches(['+', '-']);
    let (mantissa, exponent) = match text.find(['e', 'E']) {
        Some(at) => (&text[..at], text[at + 1..].parse::<i32>().unwrap_or(0)),
        None => (text, 0),
    };
    let decimals = mantissa.find('.').map_or(0, |dot| mantissa.len() - dot - 1) as i32;
    0.5 * 10f64.powi(exponent - decimals)
}

/// Entries as CSV text, header first.
pub fn covariance_csv(entries: &[CovarianceEntry]) -> String {
    pairs_csv(entries, COVARIANCE_COLUMNS)
}

fn pairs_csv(entries: &[CovarianceEntry], columns: [&str; 5]) -> String {
    let mut text = format!("{}\n", columns.join(","));
    for e in entries {
        text.push_str(&format!("{},{},{},{},{:e}\n", e.observable_a, e.x_a, e.observable_b, e.x_b, e.covariance));
    }
    text
}

/// Writes entries as CSV (temporary file, then renamed).
pub fn write_covariance_csv(path: &Path, entries: &[CovarianceEntry]) -> Result<()> {
    super::artifacts::write_text_atomic(path, &covariance_csv(entries))
}

#[cfg(test)]
mod tests {
    use super::printed_rounding;

    #[test]
    fn a_printed_number_knows_its_last_digit() {
        for (text, half_unit) in
            [("2.50e-3", 5e-6), ("1200", 0.5), ("-0.00120", 5e-6), ("1.2345678E+02", 5e-6), ("3", 0.5)]
        {
            let got = printed_rounding(text);
            assert!((got / half_unit - 1.0).abs() < 1e-12, "{text}: {got} vs {half_unit}");
        }
    }
}
