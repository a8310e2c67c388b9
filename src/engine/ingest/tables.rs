//! Runs of a simulator that writes a table per point (`output = "table"` in
//! `[run.simulator]`): `RUNS/<id>/outputs.csv` or `outputs.parquet`, columns
//! `observable, x, value` and optionally `error`. A point whose table cannot
//! be read is flagged with the file, row and field, and left out.

use super::{missing_points, point_folders, IngestReport, Ingested, IngestedRow, PointReport};
use crate::base::artifacts::{self, Provenance};
use anyhow::{anyhow, bail, Context, Result};
use polars::prelude::*;
use std::path::{Path, PathBuf};

/// Reads every point's table; like `ingest_runs`, with `design` (default
/// `runs_dir/design.parquet`) naming the points expected.
pub fn ingest_tables(runs_dir: &Path, design: Option<&Path>) -> Result<(Ingested, Option<DataFrame>)> {
    let folders = point_folders(runs_dir)?;
    let default_design = runs_dir.join("design.parquet");
    let design_path = design.map(Path::to_path_buf).or_else(|| default_design.exists().then_some(default_design));
    let design_df = design_path.as_deref().map(artifacts::read_parquet).transpose()?;
    let mut points = Vec::new();
    let mut rows = Vec::new();
    for (id, dir) in &folders {
        let mut report = PointReport {
            design_id: *id,
            folder: dir.display().to_string(),
            source: String::new(),
            good_events: 0,
            skipped: Vec::new(),
            flagged: None,
            undefined_bins: Vec::new(),
        };
        match read_point(*id, dir) {
            Ok((source, point_rows)) => {
                report.source = source;
                let (good, bad): (Vec<IngestedRow>, Vec<IngestedRow>) =
                    point_rows.into_iter().partition(|r| r.value.is_finite());
                report.undefined_bins = bad.iter().map(|r| format!("{}[{}]", r.observable, r.x)).collect();
                rows.extend(good);
            }
            Err(e) => report.flagged = Some(format!("{e:#}")),
        }
        points.push(report);
    }
    let missing_points = missing_points(&folders, design_df.as_ref(), design_path.as_deref())?;
    let prov = Provenance::new(String::new(), String::new(), 0, &format!("ingest tables {}", runs_dir.display()));
    Ok((
        Ingested {
            rows,
            covariance: Default::default(),
            report: IngestReport { runs_dir: runs_dir.display().to_string(), points, missing_points, provenance: prov },
        },
        design_df,
    ))
}

fn read_point(id: i64, dir: &Path) -> Result<(String, Vec<IngestedRow>)> {
    let csv_path = dir.join("outputs.csv");
    let parquet_path = dir.join("outputs.parquet");
    if csv_path.exists() {
        return Ok((csv_path.display().to_string(), read_csv(id, &csv_path)?));
    }
    if parquet_path.exists() {
        return Ok((parquet_path.display().to_string(), read_parquet(id, &parquet_path)?));
    }
    bail!("{}: no outputs.csv or outputs.parquet", dir.display())
}

fn read_csv(id: i64, path: &PathBuf) -> Result<Vec<IngestedRow>> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("opening {}", path.display()))?;
    let headers = reader.headers().with_context(|| format!("{}: reading the header", path.display()))?.clone();
    let column = |name: &str| headers.iter().position(|h| h == name);
    let need = |name: &str| {
        column(name).ok_or_else(|| {
            anyhow!(
                "{}: no '{name}' column (the columns are observable, x, value and optionally error)",
                path.display()
            )
        })
    };
    let (o, x, v, e) = (need("observable")?, need("x")?, need("value")?, column("error"));
    let mut rows = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let line = i + 2;
        let record = record.with_context(|| format!("{}: line {line}", path.display()))?;
        let number = |k: usize, field: &str| -> Result<f64> {
            let text = record.get(k).unwrap_or("");
            text.parse::<f64>()
                .map_err(|_| anyhow!("{}: line {line}, field '{field}': {text:?} is not a number", path.display()))
        };
        let x_value = number(x, "x")?;
        if !x_value.is_finite() {
            bail!("{}: line {line}, field 'x': not finite", path.display());
        }
        rows.push(IngestedRow {
            design_id: id,
            observable: record.get(o).unwrap_or("").to_string(),
            x: x_value,
            value: number(v, "value")?,
            error: e.map(|k| number(k, "error")).transpose()?.unwrap_or(0.0),
            n_events: 0,
        });
    }
    if rows.is_empty() {
        bail!("{}: no rows", path.display());
    }
    Ok(rows)
}

fn read_parquet(id: i64, path: &Path) -> Result<Vec<IngestedRow>> {
    let df = artifacts::read_parquet(path)?;
    let text = |name: &str| -> Result<Vec<String>> {
        let c =
            df.column(name).map_err(|_| anyhow!("{}: no '{name}' column", path.display()))?.cast(&DataType::String)?;
        let ca = c.str()?.clone();
        Ok((0..df.height()).map(|i| ca.get(i).unwrap_or("").to_string()).collect())
    };
    let numbers = |name: &str| -> Result<Vec<f64>> {
        let c =
            df.column(name).map_err(|_| anyhow!("{}: no '{name}' column", path.display()))?.cast(&DataType::Float64)?;
        let ca = c.f64()?.clone();
        (0..df.height())
            .map(|i| {
                ca.get(i).ok_or_else(|| anyhow!("{}: row {}, field '{name}': missing value", path.display(), i + 1))
            })
            .collect()
    };
    let (observables, xs, values) = (text("observable")?, numbers("x")?, numbers("value")?);
    let errors = if df.column("error").is_ok() { numbers("error")? } else { vec![0.0; df.height()] };
    Ok((0..df.height())
        .map(|i| IngestedRow {
            design_id: id,
            observable: observables[i].clone(),
            x: xs[i],
            value: values[i],
            error: errors[i],
            n_events: 0,
        })
        .collect())
}
