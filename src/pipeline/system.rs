//! What a simulator system brings to `mdpipe run` beyond its command line,
//! as `report::SystemFigures` brings figures to a report. The runner and its
//! stages know no system; they ask the systems the study holds
//! (`Study::systems`, listed once in `setup::systems()`; the heavy-ion
//! stand-in, `stand_in`, is the one built in). Every method has a
//! default that adds nothing, so a system implements only what it brings.

use super::run_config::RunConfig;
use super::stage::{AnyStage, StageId};
use super::study::{RunPaths, Study};
use super::variants::Variant;
use crate::base::config::Config;
use crate::engine::execute::SimulatorSpec;
use crate::engine::model::{ModelFamily, Units};
use crate::engine::report::SystemFigures;
use anyhow::Result;
use std::path::PathBuf;
use std::sync::Arc;

/// Data a system made for the study (mock data with a known truth).
pub(super) struct StudyData {
    pub(super) measurements: PathBuf,
    /// Their covariance (`[data] covariance`), when the system measured it.
    pub(super) covariance: Option<PathBuf>,
}

pub(super) trait StudySystem: Sync {
    /// The name of its own table in `[run]` (`[run.<name>]`), if it has one.
    fn run_table(&self) -> Option<&'static str> {
        None
    }
    /// Checks its table of `run` before any stage runs.
    fn validate(&self, _run: &RunConfig) -> Result<()> {
        Ok(())
    }
    /// The declarations of its library candidates that `run` names, each
    /// pointing at its variant emulator under `paths` (what the standalone
    /// commands take from a study, `complete::fill_in_from_study`).
    fn library_declarations(&self, _run: &RunConfig, _paths: &RunPaths) -> Result<Vec<toml::Table>> {
        Ok(Vec::new())
    }
    /// The stages it adds to the generic ones, each with its rank among them.
    fn stages(&self) -> &'static [&'static dyn AnyStage] {
        &[]
    }
    /// What it adds to a generic stage's key: its own `[run]` settings that
    /// shape that stage's output (the generic stages know only their own).
    fn key_settings(&self, _study: &Study<'_>, _stage: StageId) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::new()
    }
    /// What the simulate stage runs when the study has no `[run.simulator]`.
    fn default_simulator(&self, _study: &Study<'_>, _validation: bool) -> Result<Option<SimulatorSpec>> {
        Ok(None)
    }
    /// Candidate physics from its own library (`[run.stand_in] candidates`), as variants of its simulator.
    fn library_variants(&self, _study: &Study<'_>) -> Result<Vec<Variant>> {
        Ok(Vec::new())
    }
    /// The data the study calibrates on, when the system made them.
    fn data(&self, _study: &Study<'_>) -> Option<StudyData> {
        None
    }
    /// A model family the study's configs may name (its `[truth]` process).
    fn family(&self) -> Option<Arc<dyn ModelFamily>> {
        None
    }
    /// Units of its parameters and observables, first in the study's figures.
    fn units(&self, _study: &Study<'_>) -> Option<Units> {
        None
    }
    /// Where its assessment of the calibrations against the truth goes,
    /// when it assesses this study (else the calibrate stage tables the cases).
    fn assessment(&self, _study: &Study<'_>) -> Option<PathBuf> {
        None
    }
    /// Writes that assessment from the calibrations in `dirs`.
    fn assess(&self, _study: &Study<'_>, _config: &Config, _dirs: &[PathBuf]) -> Result<()> {
        Ok(())
    }
    /// Its report figures, and the section its assessment puts above them.
    fn figures(&self) -> Option<&'static dyn SystemFigures> {
        None
    }
    fn report_section(&self, _study: &Study<'_>) -> Result<Option<String>> {
        Ok(None)
    }
}
