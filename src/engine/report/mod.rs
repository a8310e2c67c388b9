//! Self-contained HTML report with inline SVG figures (plotters), built from
//! run artifacts on disk, so `mdpipe report DIR…` works on any finished run.
//!
//! Colours follow the paper: no MD red, Kernel I blue, Kernel II green;
//! truth dashed grey.

use crate::base::artifacts::{self, Measurement};
use crate::engine::calibrate::summary::{ParamSummary, Summary};
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
        let data = artifacts::read_measurements(&dir.join("measurements.parquet"))?;
        Ok(RunArtifacts { dir: dir.to_path_buf(), summary, names, draws, predictions, data })
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
        let obs = self.predictions.column("observable").unwrap().str().unwrap();
        let kinds = self.predictions.column("kind").unwrap().str().unwrap();
        let rows =
            (0..self.predictions.height()).filter(|&i| obs.get(i) == Some(observable) && kinds.get(i) == Some(kind));
        // Older runs have no `truth` column: treat a missing column as unknown.
        match self.predictions.column(col).ok().and_then(|c| c.f64().ok()) {
            Some(vals) => rows.map(|i| vals.get(i).unwrap_or(f64::NAN)).collect(),
            None => rows.map(|_| f64::NAN).collect(),
        }
    }
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
