//! The candidates stage (when the study declares candidates): each candidate
//! physics as a variant of the study's simulator (`pipeline::variants`),
//! built as the base model is built: a design over θ and the candidate's own
//! parameters, runs through the same executor with the same retries, ingest,
//! an emulator and its cross-validation.

mod variants;

use super::{Keys, Presence, Stage, StageId};
use crate::base::artifacts;
use crate::engine::design::DesignSpec;
use crate::engine::emulator::EmulatorSettings;
use crate::pipeline::points::{self, NewDesign};
use crate::pipeline::setup;
use crate::pipeline::study::Study;
use crate::pipeline::variants::Variant;
use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};
pub(crate) use variants::{presence, variants};

pub(crate) struct Candidates;

#[derive(serde::Serialize)]
pub(crate) struct Settings {
    spec: String,
    variants: Vec<Variant>,
    points: usize,
    observables: Vec<String>,
    emulator: Option<EmulatorSettings>,
    seed: u64,
    #[serde(flatten)]
    system: serde_json::Map<String, serde_json::Value>,
}

impl Stage for Candidates {
    type Settings = Settings;
    const ID: StageId = StageId::CANDIDATES;
    const UPSTREAM: &'static [StageId] = &[StageId::DESIGN];
    fn present(&self, study: &Study<'_>) -> Result<Presence> {
        presence(study)
    }
    fn outputs(&self, study: &Study<'_>) -> Result<Vec<PathBuf>> {
        let variants = variants(study)?;
        Ok(variants.iter().map(|v| study.paths.candidate(&v.name).join("emulator").join("emulator.json")).collect())
    }
    fn settings(&self, study: &Study<'_>) -> Result<Settings> {
        let run = study.run;
        Ok(Settings {
            spec: study.design_spec_hash()?,
            variants: variants(study)?,
            points: run.candidate_points.unwrap_or(run.points),
            observables: study.all_observables(),
            emulator: study.emulator.clone(),
            seed: study.opts.seed,
            system: setup::system_settings(study, StageId::CANDIDATES),
        })
    }
    fn run(&self, study: &Study<'_>, _keys: &Keys<'_>) -> Result<()> {
        let spec_path = study.config.resolve(&study.run.design);
        let spec_hash = artifacts::sha256_hex(
            &std::fs::read(&spec_path).with_context(|| format!("reading {}", spec_path.display()))?,
        );
        let spec = DesignSpec::load(&spec_path)?;
        for v in variants(study)? {
            let dir = study.paths.candidate(&v.name);
            crate::engine::execute::attempt::remove_after_attempts(&dir)
                .with_context(|| format!("removing the previous variant {}", dir.display()))?;
            let design_dir = dir.join("design");
            let label = format!("candidate {}", v.name);
            let design = NewDesign {
                spec: &v.design_spec(&spec),
                spec_hash: &spec_hash,
                simulator: &v.simulator,
                label: &label,
                points: study.run.candidate_points.unwrap_or(study.run.points),
                seed: v.design_seed,
                dir: &design_dir,
            };
            points::write_design(study, &design)?;
            points::run_design(study, &design_dir, &v.simulator, &label)?;
            let training = dir.join("training.parquet");
            points::ingest_design(study, &design_dir, &training)?;
            train_variant(study, &v, &training, &dir)?;
        }
        Ok(())
    }
}

/// Trains a variant's emulator on `training` into `dir/emulator` and
/// cross-validates it: a variant decides verdicts as much as the base
/// emulator does.
fn train_variant(study: &Study<'_>, v: &Variant, training: &Path, dir: &Path) -> Result<()> {
    let mut settings = study
        .emulator
        .clone()
        .ok_or_else(|| anyhow!("{}: the candidates stage needs an [emulator] table", study.config.path.display()))?;
    settings.parameters.extend(v.parameters.iter().map(|p| p.name.clone()));
    let command = format!("run {} --stage candidates ({})", study.config.path.display(), v.name);
    let (_, r) = crate::engine::emulator::train_with_settings(
        &settings,
        &study.config.hash,
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
