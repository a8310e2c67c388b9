//! The emulator stage: the emulator trained on the training runs and
//! validated on the held-out design.

use super::{Keys, Stage, StageId};
use crate::engine::emulator::EmulatorSettings;
use crate::pipeline::study::Study;
use anyhow::{bail, Result};
use std::path::PathBuf;

pub(crate) struct Emulator;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    emulator: Option<EmulatorSettings>,
    seed: u64,
}

impl Stage for Emulator {
    type Settings = Settings;
    const ID: StageId = StageId::EMULATOR;
    const UPSTREAM: &'static [StageId] = &[StageId::INGEST];
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        Ok(vec![study.paths.emulator().join("emulator.json"), study.paths.emulator().join("validation.json")])
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        Ok(Settings { emulator: study.emulator.clone(), seed: study.opts.seed })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        if study.config.emulator.is_none() {
            bail!("{}: the emulator stage needs an [emulator] table", study.config.path.display());
        }
        let (_, r) = crate::engine::emulator::train_and_save(
            &study.config.path,
            &study.paths.training(),
            None,
            &study.paths.emulator(),
            study.opts.seed,
        )?;
        crate::base::messages::say!(
            "  {} points x {} outputs -> {} components in {:.1} s",
            r.n_points,
            r.n_outputs,
            r.n_components,
            r.training_seconds
        );
        let v = crate::engine::emulator::validate::run(
            &study.paths.emulator(),
            Some(&study.paths.validation()),
            5,
            study.opts.seed,
        )?;
        if let Some(h) = &v.holdout {
            crate::engine::emulator::validate::print("held-out design", h);
        }
        Ok(())
    }
}
