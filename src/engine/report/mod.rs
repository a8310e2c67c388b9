//! Self-contained HTML report with inline SVG figures (plotters), built from
//! run artifacts on disk, so `mdpipe report DIR…` works on any finished run.
//!
//! Colours follow the paper: no MD red, Kernel I blue, Kernel II green;
//! truth dashed grey.

use crate::base::artifacts::{self, Measurement};
use crate::engine::calibrate::results::summary::{ParamSummary, Summary};
use crate::engine::diagnose::Diagnosis;
use anyhow::{Context, Result};
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const W: u32 = 560;
pub const H: u32 = 380;

pub fn kernel_colour(kernel: &str) -> RGBColor {
    match kernel {
        "none" => RGBColor(205, 40, 40),
        "I" => RGBColor(40, 90, 205),
        _ => RGBColor(30, 150, 60),
    }
}

pub const TRUTH: RGBColor = RGBColor(120, 120, 120);

/// One calibration's artifacts, read back from its folder.
pub struct RunArtifacts {
    pub dir: PathBuf,
    pub summary: Summary,
    pub names: Vec<String>,
    /// Draws per parameter, in `names` order.
    pub draws: Vec<Vec<f64>>,
    pub predictions: polars::prelude::DataFrame,
    /// Each row of `predictions`: its observable and kind (checked on load).
    prediction_rows: Vec<(String, String)>,
    pub data: Vec<Measurement>,
}

impl RunArtifacts {
    pub fn load(dir: &Path) -> Result<Self> {
        let summary: Summary = serde_json::from_str(
            &std::fs::read_to_string(dir.join("summary.json"))
                .with_context(|| format!("reading {}/summary.json", dir.display()))?,
        )
        .with_context(|| format!("parsing {}/summary.json", dir.display()))?;
        let post = artifacts::read_parquet(&dir.join("posterior.parquet"))?;
        let names = summary.parameter_order.clone();
        let mut draws = Vec::new();
        for n in &names {
            let c =
                post.column(n).with_context(|| format!("{}/posterior.parquet: missing column '{n}'", dir.display()))?;
            draws.push(c.f64()?.into_no_null_iter().collect());
        }
        let predictions = artifacts::read_parquet(&dir.join("predictions.parquet"))?;
        let prediction_rows = row_labels(&predictions, &dir.join("predictions.parquet"))?;
        let data = artifacts::read_measurements(&dir.join("measurements.parquet"))?;
        Ok(RunArtifacts { dir: dir.to_path_buf(), summary, names, draws, predictions, prediction_rows, data })
    }

    pub fn param(&self, name: &str) -> Option<&[f64]> {
        self.names.iter().position(|n| n == name).map(|i| self.draws[i].as_slice())
    }

    /// Where a run's bands are drawn: on the grid past the data when the
    /// model could be evaluated there, else at the data (an emulator knows
    /// only the outputs it was trained on).
    pub fn curve_kind(&self, observable: &str) -> &'static str {
        if self.pred_col(observable, "grid", "x").is_empty() {
            "data"
        } else {
            "grid"
        }
    }

    pub fn pred_col(&self, observable: &str, kind: &str, col: &str) -> Vec<f64> {
        let rows = (0..self.prediction_rows.len())
            .filter(|&i| self.prediction_rows[i].0 == observable && self.prediction_rows[i].1 == kind);
        // Older runs have no `truth` column: treat a missing column as unknown.
        match self.predictions.column(col).ok().and_then(|c| c.f64().ok()) {
            Some(vals) => rows.map(|i| vals.get(i).unwrap_or(f64::NAN)).collect(),
            None => rows.map(|_| f64::NAN).collect(),
        }
    }
}

/// Each row's `observable` and `kind` of a predictions table; an error
/// naming the file, the column and the row where one is missing, not text
/// or empty.
fn row_labels(predictions: &polars::prelude::DataFrame, path: &Path) -> Result<Vec<(String, String)>> {
    let text = |name: &str| -> Result<Vec<String>> {
        let column = predictions.column(name).map_err(|_| anyhow::anyhow!("{}: no column '{name}'", path.display()))?;
        let values = column.str().map_err(|_| anyhow::anyhow!("{}: column '{name}' is not text", path.display()))?;
        (0..values.len())
            .map(|row| {
                values
                    .get(row)
                    .map(str::to_string)
                    .ok_or_else(|| anyhow::anyhow!("{}: row {}: column '{name}' is empty", path.display(), row + 1))
            })
            .collect()
    };
    Ok(text("observable")?.into_iter().zip(text("kind")?).collect())
}

pub fn svg(
    draw: impl FnOnce(&DrawingArea<SVGBackend, plotters::coord::Shift>) -> Result<()>,
    w: u32,
    h: u32,
) -> Result<String> {
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        draw(&root)?;
        root.present().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    Ok(s)
}

/// `yr` raised at the top so that a legend of `rows` entries in a top corner
/// sits above every point drawn: about 20 px a row plus its frame, of a
/// plotting area of about H − 100 px. A legend drawn over the data hid the
/// very bins where a mismatch shows.
pub fn room_for_legend(yr: (f64, f64), rows: usize) -> (f64, f64) {
    let share = ((20 * rows + 24) as f64 / (H - 100) as f64).min(0.6);
    (yr.0, yr.1 + (yr.1 - yr.0) * share / (1.0 - share))
}

/// Draws a chart's legend, framed on a white ground, in the corner `at`
/// (figures leave room for it with [`room_for_legend`]).
pub fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    at: SeriesLabelPosition,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(at)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| anyhow::anyhow!("plotting: {e:?}"))
}

/// `p!(plotters call)`: the call's error as an `anyhow` error, returned.
macro_rules! p {
    ($e:expr) => {
        $e.map_err(|e| anyhow::anyhow!("plotting: {e:?}"))?
    };
}
pub(crate) use p;

mod calibration_plots;
mod diagnosis_plots;
pub mod emulator;
mod html;
pub mod png;

pub use calibration_plots::*;
pub use diagnosis_plots::*;
pub use html::*;

/// An axis label, "name [units]", or the name alone when no unit is known.
pub fn axis(name: &str, units: &str) -> String {
    if units.is_empty() {
        name.to_string()
    } else {
        format!("{name} [{units}]")
    }
}

pub fn range_of(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |a, v| (a.0.min(v), a.1.max(v)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = 0.05 * (hi - lo).max(1e-9);
    (lo - pad, hi + pad)
}

type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// Figures a system adds to reports of its own calibrations; the report
/// itself knows no system.
pub trait SystemFigures: Sync {
    /// Whether `run` is one of this system's calibrations.
    fn claims(&self, run: &RunArtifacts) -> bool;
    /// Figures (caption, SVG) after the corner plot of one observable set.
    fn posterior_figures(
        &self,
        _group: &[&RunArtifacts],
        _truth: &BTreeMap<String, f64>,
    ) -> Result<Vec<(String, String)>> {
        Ok(Vec::new())
    }
    /// One observable's predictions, instead of the generic bands.
    fn prediction_figure(&self, _run: &RunArtifacts, _observable: &str) -> Result<Option<(String, String)>> {
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use polars::prelude::{Column, DataFrame};

    fn table(columns: Vec<Column>) -> DataFrame {
        DataFrame::new(columns.first().map_or(0, |c| c.len()), columns).unwrap()
    }

    /// A predictions table a user points the report at is checked on load:
    /// a missing, numeric or empty label is an error naming the file, the
    /// column and the row, never a panic.
    #[test]
    fn a_damaged_predictions_table_is_refused_by_name() {
        let path = Path::new("run/predictions.parquet");
        let good =
            table(vec![Column::new("observable".into(), ["y", "y"]), Column::new("kind".into(), ["data", "grid"])]);
        let rows = row_labels(&good, path).unwrap();
        assert_eq!(rows[1], ("y".to_string(), "grid".to_string()));
        let missing = table(vec![Column::new("observable".into(), ["y"])]);
        let numeric = table(vec![Column::new("observable".into(), [1.0]), Column::new("kind".into(), ["data"])]);
        let empty = table(vec![
            Column::new("observable".into(), [Some("y"), None]),
            Column::new("kind".into(), ["data", "grid"]),
        ]);
        for (frame, says) in [
            (missing, "run/predictions.parquet: no column 'kind'"),
            (numeric, "run/predictions.parquet: column 'observable' is not text"),
            (empty, "run/predictions.parquet: row 2: column 'observable' is empty"),
        ] {
            let error = row_labels(&frame, path).unwrap_err().to_string();
            assert_eq!(error, says);
        }
    }
}
