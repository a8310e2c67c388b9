//! `[run.stand_in]`: what a study asks of the heavy-ion stand-in, decoded
//! and checked here, never by the generic `[run]` table. With the table the
//! stand-in is the study's simulator when `[run.simulator]` is absent, its
//! mock data (with `mock_delta_f`) replace the config's measurements, and
//! its library candidates (`candidates`) become simulator variants.

use crate::base::paper_table::PAPER_TABLE_OBSERVABLES;
use crate::pipeline::run_config::RunConfig;
use crate::systems::heavy_ion::{self, DeltaF};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;

/// The name of the stand-in's table in `[run]`.
pub(super) const TABLE: &str = "stand_in";

/// `[run.stand_in]`.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct StandInRun {
    /// Events per design point of the stand-in's model runs, and Cooper–Frye samples per event.
    #[serde(default)]
    pub(super) events: Option<usize>,
    #[serde(default = "default_oversample")]
    pub(super) oversample: usize,
    /// Particlization of the model runs: none (f_eq), as in the paper.
    #[serde(default = "default_model_delta_f")]
    pub(super) model_delta_f: String,
    /// Mock data: the stand-in at the parameters' `truth` values with this δf.
    /// Without it, the calibrations use the config's `[data] measurements`.
    #[serde(default)]
    pub(super) mock_delta_f: Option<String>,
    /// Stand-in parameters of the mock data when they are not the calibration
    /// parameters' truth values (a constant η/s = 0.1 behind a kink model:
    /// `{ eta_s = 0.1, e_sw = 0.2 }`).
    #[serde(default)]
    pub(super) mock_truth: Option<BTreeMap<String, f64>>,
    #[serde(default)]
    pub(super) mock_events: Option<usize>,
    /// Diagnose candidates from the stand-in's library, by name.
    #[serde(default)]
    pub(super) candidates: Vec<String>,
}

fn default_oversample() -> usize {
    heavy_ion::events::DEFAULT_OVERSAMPLE
}

fn default_model_delta_f() -> String {
    "none".into()
}

impl StandInRun {
    /// The study's `[run.stand_in]`, when it has one.
    pub(super) fn of(run: &RunConfig) -> Result<Option<StandInRun>> {
        let Some(table) = run.systems.get(TABLE) else { return Ok(None) };
        let settings: StandInRun =
            toml::Value::Table(table.clone()).try_into().map_err(|e| anyhow::anyhow!("[run.{TABLE}]: {e}"))?;
        Ok(Some(settings))
    }

    /// A study on the stand-in's mock data (with its truth known), rather than on measurements.
    pub(super) fn mock_study(&self) -> bool {
        self.mock_delta_f.is_some()
    }

    /// Checks everything a later stage would trip on, before any stage runs.
    pub(super) fn validate(&self, run: &RunConfig) -> Result<()> {
        for (field, n) in
            [("events", self.events), ("mock_events", self.mock_events), ("oversample", Some(self.oversample))]
        {
            if n == Some(0) {
                bail!("{field} must be at least 1");
            }
        }
        if run.simulator.is_none() && self.events.is_none() {
            bail!("give `events` (the stand-in's events per point) or a [run.simulator] table");
        }
        self.model_delta_f.parse::<DeltaF>().context("model_delta_f")?;
        if let Some(m) = &self.mock_delta_f {
            m.parse::<DeltaF>().context("mock_delta_f")?;
            if self.mock_events.is_none() {
                bail!("mock_delta_f needs mock_events (the events of the stand-in's mock data)");
            }
        }
        if run.simulator.is_none() {
            let known: Vec<&str> = PAPER_TABLE_OBSERVABLES.iter().map(|(_, name)| *name).collect();
            for o in run.observable_sets.iter().flatten() {
                if !known.contains(&o.as_str()) {
                    bail!("observable_sets: unknown observable '{o}' (the stand-in gives {})", known.join(", "));
                }
            }
        }
        if !self.candidates.is_empty() && run.simulator.is_some() {
            bail!("candidates: these name the heavy-ion stand-in's library; with your own simulator declare each candidate as a [[candidates]] table saying how the simulator turns it on (`parameter_file`, `placeholders` or `command`) and its `parameters` (see docs/cluster.md)");
        }
        for c in &self.candidates {
            heavy_ion::candidate(c).context("candidates")?;
        }
        Ok(())
    }
}
