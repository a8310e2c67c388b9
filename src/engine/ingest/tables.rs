//! Runs of a simulator that writes a table per point (`output = "table"` in
//! `[run.simulator]`): `RUNS/<id>/outputs.csv` or `outputs.parquet`, columns
//! `observable, x, value` and optionally `error`. A point whose table cannot
//! be read is flagged with the file, row and field, and left out.

use super::{missing_points, point_folders, IngestReport, Ingested, IngestedRow, PointReport};
use crate::base::artifacts::{self, Provenance};
use crate::base::table::RawTable;
use anyhow::{anyhow, bail, Result};
use polars::prelude::*;
use std::path::Path;

/// A simulator that writes `outputs.csv` or `outputs.parquet` per point.
pub struct TableRuns;

impl super::RunsReader for TableRuns {
    fn read(&self, runs_dir: &Path, design: Option<&Path>) -> Result<(Ingested, Option<DataFrame>)> {
        ingest_tables(runs_dir, design)
    }
}

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
    let path = [dir.join("outputs.csv"), dir.join("outputs.parquet")]
        .into_iter()
        .find(|p| p.exists())
        .ok_or_else(|| anyhow!("{}: no outputs.csv or outputs.parquet", dir.display()))?;
    Ok((path.display().to_string(), read_table(id, &path)?))
}

/// A point's `observable, x, value[, error]` table; values may be undefined
/// (a bin the run could not fill), the x must be finite.
fn read_table(id: i64, path: &Path) -> Result<Vec<IngestedRow>> {
    let raw = RawTable::read(path)?;
    let hint = |e: anyhow::Error| anyhow!("{e:#} (the columns are observable, x, value and optionally error)");
    let observables = raw.strings(path, "observable").map_err(hint)?;
    let (xs, values) = (raw.numbers(path, "x").map_err(hint)?, raw.numbers(path, "value").map_err(hint)?);
    let errors = if raw.has("error") { raw.numbers(path, "error")? } else { vec![0.0; raw.height()] };
    if let Some(i) = xs.iter().position(|x| !x.is_finite()) {
        return Err(crate::base::error::FieldError::new(path, raw.location(i), "x", "not finite").into());
    }
    if raw.height() == 0 {
        bail!("{}: no rows", path.display());
    }
    Ok((0..raw.height())
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
