//! The refine stage (only with `[run.refine]`): rounds of adaptive design
//! (`pipeline::refine_rounds`) until the emulator's error where the posterior
//! lives is below the data error; the stages after it use its emulator.

use super::{Keys, Presence, StageDef};
use crate::pipeline::study::Study;
use anyhow::Result;
use std::path::PathBuf;

pub(super) const STAGE: StageDef =
    StageDef { name: "refine", rank: 60, upstream: &["emulator", "mock"], present, outputs, settings, body: refine };

fn present(study: &Study<'_>) -> Result<Presence> {
    Ok(if study.run.refine.is_some() {
        Presence::Runs
    } else {
        Presence::Absent(format!("{} has no [run.refine] table", study.config.path.display()))
    })
}

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    Ok(vec![study.refine_dir().join("rounds.json")])
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let run = study.run;
    Ok(
        serde_json::json!({"config": study.analysis_hash()?, "data": study.data_hash()?, "refine": serde_json::to_value(&run.refine)?, "simulator": serde_json::to_value(&run.simulator)?,
        "events": run.events, "oversample": run.oversample, "delta_f": run.model_delta_f, "set": study.diagnose_observables(), "kernels": run.kernels, "seed": study.opts.seed}),
    )
}

fn refine(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    study.refine_rounds()
}
