//! The refine stage (only with `[run.refine]`): rounds of adaptive design
//! (`rounds`) until the emulator's error where the posterior lives is below
//! the data error; the stages after it use its emulator
//! (`report::emulator_in_use`, from its report `rounds.json`).

pub(crate) mod report;
mod rounds;

use super::{Keys, Presence, Stage, StageId};
use crate::base::choices::Kernel;
use crate::engine::execute::SimulatorSpec;
use crate::pipeline::run_config::RefineConfig;
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use anyhow::Result;
use report::refine_dir;
use std::path::PathBuf;

pub(crate) struct Refine;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    config: String,
    data: String,
    refine: Option<RefineConfig>,
    simulator: Option<SimulatorSpec>,
    set: Vec<String>,
    kernels: Vec<Kernel>,
    seed: u64,
    #[serde(flatten)]
    system: serde_json::Map<String, serde_json::Value>,
}

impl Stage for Refine {
    type Settings = Settings;
    const ID: StageId = StageId::REFINE;
    const UPSTREAM: &'static [StageId] = &[StageId::EMULATOR];
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        Ok(if study.run.refine.is_some() {
            Presence::Runs
        } else {
            Presence::Absent(format!("{} has no [run.refine] table", study.config.path.display()))
        })
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![refine_dir(study).join("rounds.json")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        let run = study.run;
        Ok(Settings {
            config: study.analysis_hash()?,
            data: study.data_hash()?,
            refine: run.refine.clone(),
            simulator: run.simulator.clone(),
            set: study.diagnose_observables(),
            kernels: run.kernels.clone(),
            seed: study.opts.seed,
            system: setup::system_settings(study, StageId::REFINE),
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        rounds::refine_rounds(study)
    }
}
