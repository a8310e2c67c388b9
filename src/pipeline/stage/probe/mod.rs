//! A stage built only for the tests, to show what adding a stage takes: this
//! folder, its `StageId` variant (`base::choices`) and one line in
//! `plan::generic`. It reads the calibrations and writes how many cases ran
//! (OUT/probe.json); the loop keys, skips and stamps it like any other.

use super::{Keys, Stage, StageId};
use crate::base::artifacts;
use crate::pipeline::study::Study;
use anyhow::Result;
use std::path::PathBuf;

pub(in crate::pipeline) struct Probe;

impl Stage for Probe {
    type Settings = Vec<Vec<String>>;
    const ID: StageId = StageId::Probe;
    const UPSTREAM: &'static [StageId] = &[StageId::Calibrate];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.out.join("probe.json")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Self::Settings> {
        Ok(study.run.observable_sets.clone())
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let cases = study.stored_fits(&study.paths.calibrate()).len();
        artifacts::write_json_atomic(&study.paths.out.join("probe.json"), &serde_json::json!({ "cases": cases }))
    }
}
