//! The diagnose stage's refinement of variant emulators: when the verdict is
//! "emulator_limited" and `[run.refine] variant_budget` allows runs, each
//! variant the verdict lists gets new runs where its own posterior
//! lies (`engine::refine::variant`), run by the executor as the candidates
//! stage ran its design, is retrained on every run so far, and
//! the diagnosis is made once more with the refined variants. Writes
//! `diagnose/refine/<candidate>/` (rounds, pilots, designs with runs,
//! emulators) and `diagnose/refine/diagnosis_before.json`; the diagnosis in
//! `diagnose/` is the one after refinement.

use crate::base::artifacts::Provenance;
use crate::base::config::Config;
use crate::base::progress::observer;
use crate::engine::calibrate::{Analysis, Overrides};
use crate::engine::design::DesignSpec;
use crate::engine::diagnose::Diagnosis;
use crate::engine::emulator::{read_training_table, TrainingTable};
use crate::engine::refine::variant::{refine_variant, PointRunner, RoundSettings};
use crate::pipeline::points;
use crate::pipeline::study::{absolute, Study};
use crate::pipeline::variants::Variant;
use anyhow::{anyhow, Result};
use std::path::Path;

/// New runs of one variant at the points refinement chose, through the
/// executor as the candidates stage ran its design, then ingested.
struct VariantRuns<'r, 'a> {
    runner: &'r Study<'a>,
    variant: Variant,
    seed: u64,
}

impl PointRunner for VariantRuns<'_, '_> {
    fn run(&self, names: &[String], points: &[Vec<f64>], first_id: i64, dir: &Path) -> Result<TrainingTable> {
        let r = self.runner;
        let design_dir = dir.join("design");
        let spec = self.variant.design_spec(&DesignSpec::load(&r.config.resolve(&r.run.design))?);
        let label = format!("refinement of {} from {first_id}", self.variant.name);
        let ids: Vec<i64> = (first_id..first_id + points.len() as i64).collect();
        let prov = Provenance::new(
            r.config.hash.clone(),
            String::new(),
            self.seed,
            &format!("run {} --stage diagnose (refining {})", r.config.path.display(), self.variant.name),
        );
        let simulator = &self.variant.simulator;
        let chosen =
            points::ChosenPoints { spec: &spec, simulator, label: &label, ids: &ids, points, names, prov: &prov };
        let table = dir.join("training.parquet");
        points::run_chosen_points(r, &chosen, &design_dir, &table)?;
        read_training_table(&table, names)
    }
}

/// Refines the variant emulators an "emulator_limited" verdict lists and
/// points `config`'s declarations at the refined ones. Returns whether
/// any was refined (and the diagnosis must be made again).
pub(super) fn refine_variants(
    study: &Study<'_>,
    config: &mut Config,
    analysis: &Analysis,
    overrides: &Overrides,
    diagnosis: &Diagnosis,
) -> Result<bool> {
    let Some(settings) = study.run.refine.as_ref().filter(|r| r.variant_budget > 0) else { return Ok(false) };
    if diagnosis.verdict.best != "emulator_limited" {
        return Ok(false);
    }
    let rounds = RoundSettings {
        points_per_round: settings.points_per_round,
        budget: settings.variant_budget,
        draws: settings.draws,
    };
    let variants = crate::pipeline::stage::candidates::variants(study)?;
    for (k, name) in diagnosis.verdict.refine.iter().enumerate() {
        let declared = variants.iter().find(|v| &v.name == name);
        let variant = analysis
            .candidates()?
            .into_iter()
            .find(|c| &c.name == name)
            .ok_or_else(|| anyhow!("the verdict lists {name}, which is not declared"))?;
        let seed = study.opts.seed.wrapping_add(9_000 + 100 * k as u64);
        let declared = declared.ok_or_else(|| anyhow!("the verdict lists {name}, which the study does not declare"))?;
        let runner = VariantRuns { runner: study, variant: declared.clone(), seed };
        let out = study.paths.diagnose().join("refine").join(name);
        let emulator = study.paths.candidate(name).join("emulator");
        let refined = refine_variant(
            analysis,
            overrides,
            &variant,
            &emulator,
            &runner,
            &rounds,
            &out,
            seed,
            observer(study.opts.show_progress),
        )?;
        crate::base::messages::say!("  {name}: {}", refined.stopped);
        let table = config
            .candidates
            .iter_mut()
            .find(|t| t.get("name").and_then(|v| v.as_str()) == Some(name))
            .ok_or_else(|| anyhow!("no declaration of {name}"))?;
        table.insert("emulator".into(), absolute(&refined.emulator).display().to_string().into());
    }
    Ok(true)
}
