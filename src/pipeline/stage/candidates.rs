//! The candidates stage (when the study declares candidates): each candidate
//! physics as a variant of the study's simulator (`pipeline::variants`),
//! built as the base model is built: a design over θ and the candidate's own
//! parameters, runs through the same executor with the same retries, ingest,
//! an emulator and its cross-validation.

use super::{Keys, Presence, StageDef};
use crate::base::artifacts;
use crate::engine::design::DesignSpec;
use crate::pipeline::study::Study;
use crate::pipeline::variants::Variant;
use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};

pub(super) const STAGE: StageDef = StageDef {
    name: "candidates",
    rank: 90,
    upstream: &["design"],
    present: with_candidates,
    outputs,
    settings,
    body: candidates,
};

/// Whether the study declares candidates (`[[candidates]]` or `[run] candidates`).
pub(super) fn with_candidates(study: &Study<'_>) -> Result<Presence> {
    Ok(if study.variants()?.is_empty() {
        Presence::Absent(format!(
            "{} declares no candidates ([[candidates]] or [run] candidates)",
            study.config.path.display()
        ))
    } else {
        Presence::Runs
    })
}

fn outputs(study: &Study<'_>) -> Result<Vec<PathBuf>> {
    let variants = study.variants()?;
    Ok(variants.iter().map(|v| study.paths.candidate(&v.name).join("emulator").join("emulator.json")).collect())
}

fn settings(study: &Study<'_>) -> Result<serde_json::Value> {
    let run = study.run;
    Ok(
        serde_json::json!({"spec": study.design_spec_hash()?, "variants": serde_json::to_value(study.variants()?)?, "points": run.candidate_points.unwrap_or(run.points), "events": run.events,
        "oversample": run.oversample, "delta_f": run.model_delta_f, "observables": study.all_observables(), "emulator": serde_json::to_value(&study.emulator)?, "seed": study.opts.seed}),
    )
}

fn candidates(study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
    let spec_path = study.config.resolve(&study.run.design);
    let spec_hash =
        artifacts::sha256_hex(&std::fs::read(&spec_path).with_context(|| format!("reading {}", spec_path.display()))?);
    let spec = DesignSpec::load(&spec_path)?;
    for v in study.variants()? {
        let dir = study.paths.candidate(&v.name);
        crate::engine::execute::attempt::remove_after_attempts(&dir)
            .with_context(|| format!("removing the previous variant {}", dir.display()))?;
        let design_dir = dir.join("design");
        let points = study.run.candidate_points.unwrap_or(study.run.points);
        let label = format!("candidate {}", v.name);
        study.write_design_for(
            &v.design_spec(&spec),
            &v.simulator,
            &label,
            &spec_hash,
            points,
            v.design_seed,
            &design_dir,
        )?;
        study.run_design(&design_dir, &v.simulator, &label)?;
        let training = dir.join("training.parquet");
        study.ingest_design(&design_dir, &training)?;
        study.train_variant(&v, &training, &dir)?;
    }
    Ok(())
}

impl Study<'_> {
    /// Trains a variant's emulator on `training` into `dir/emulator` and
    /// cross-validates it: a variant decides verdicts as much as the base
    /// emulator does.
    pub(in crate::pipeline) fn train_variant(&self, v: &Variant, training: &Path, dir: &Path) -> Result<()> {
        let mut settings = self
            .emulator
            .clone()
            .ok_or_else(|| anyhow!("{}: the candidates stage needs an [emulator] table", self.config.path.display()))?;
        settings.parameters.extend(v.parameters.iter().map(|p| p.name.clone()));
        let command = format!("run {} --stage candidates ({})", self.config.path.display(), v.name);
        let (_, r) = crate::engine::emulator::train_with_settings(
            &settings,
            &self.config.hash,
            &command,
            training,
            None,
            &dir.join("emulator"),
            v.design_seed,
        )?;
        crate::base::messages::say!(
            "  {}: {} points x {} outputs -> {} components ({})",
            v.name,
            r.n_points,
            r.n_outputs,
            r.n_components,
            settings.parameters.join(", ")
        );
        let cv = crate::engine::emulator::validate::run(&dir.join("emulator"), None, 5, v.design_seed)?;
        if let Some(cv) = &cv.cross_validation {
            crate::engine::emulator::validate::print(&format!("  {}: 5-fold cross-validation", v.name), cv);
        }
        Ok(())
    }
}
