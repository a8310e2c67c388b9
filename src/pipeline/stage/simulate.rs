//! The simulate stage: the simulator run at every point of both designs
//! through `engine::execute`, locally or as a Slurm array.

use super::{read_stamp, Keys, Stage, StageId};
use crate::engine::execute::{self, SimulatorSpec};
use crate::pipeline::points;
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use anyhow::{Context, Result};
use std::path::PathBuf;

pub(crate) struct Simulate;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    simulator: Option<SimulatorSpec>,
    seed: u64,
    #[serde(flatten)]
    system: serde_json::Map<String, serde_json::Value>,
}

impl Stage for Simulate {
    type Settings = Settings;
    const ID: StageId = StageId::SIMULATE;
    const UPSTREAM: &'static [StageId] = &[StageId::DESIGN];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.design().join("runs"), study.paths.validation_design().join("runs")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        Ok(Settings {
            simulator: study.run.simulator.clone(),
            seed: study.opts.seed,
            system: setup::system_settings(study, StageId::SIMULATE),
        })
    }
    fn run(&self, study: &Study<'_>, keys: &Keys<'_>) -> Result<()> {
        // Settings changed since the last run: its runs are not these. Forced
        // with the same settings, finished points are kept and only the
        // failed ones run again, with fresh attempts.
        let previous = read_stamp(&study.paths.stamp(Self::ID.name()));
        let stale = previous.as_ref().is_some_and(|s| s.key != keys.this);
        let forced = previous.is_some() && !stale;
        for (dir, label) in [(study.paths.design(), "design"), (study.paths.validation_design(), "validation design")] {
            let runs = dir.join("runs");
            if stale {
                execute::attempt::remove_after_attempts(&runs)
                    .with_context(|| format!("removing outdated runs {}", runs.display()))?;
            }
            let attempts = runs.join(".attempts");
            if forced {
                execute::attempt::remove_after_attempts(&attempts)
                    .with_context(|| format!("removing the previous attempts {}", attempts.display()))?;
            }
            let simulator = study.simulator(label == "validation design")?;
            points::run_design(study, &dir, &simulator, label)?;
        }
        Ok(())
    }
}
