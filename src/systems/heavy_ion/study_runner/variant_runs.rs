//! The diagnose stage's refinement of variant emulators: when the verdict is
//! "emulator_limited" and `[run.refine] variant_budget` allows runs, each
//! variant the verdict lists gets new stand-in runs where its own posterior
//! lies (`engine::refine::variant`), is retrained on every run so far, and
//! the diagnosis is made once more with the refined variants. Writes
//! `diagnose/refine/<candidate>/` (rounds, pilots, designs with runs,
//! emulators) and `diagnose/refine/diagnosis_before.json`; the diagnosis in
//! `diagnose/` is the one after refinement.

use super::{absolute, Runner};
use crate::base::artifacts::Provenance;
use crate::base::config::Config;
use crate::base::progress::observer;
use crate::engine::calibrate::{Analysis, Overrides};
use crate::engine::diagnose::Diagnosis;
use crate::engine::emulator::{read_training_table, TrainingTable};
use crate::engine::refine::variant::{refine_variant, PointRunner, RoundSettings};
use crate::systems::heavy_ion::{self, events::Layout, DeltaF, HeavyIonParams, StandInCandidate};
use anyhow::{anyhow, Result};
use std::path::Path;

/// New event-by-event stand-in runs of one variant, ingested as the
/// candidates stage ingests its design.
struct VariantRuns<'r, 'a> {
    runner: &'r Runner<'a>,
    candidate: &'static StandInCandidate,
    delta_f: DeltaF,
    seed: u64,
}

impl PointRunner for VariantRuns<'_, '_> {
    fn run(&self, names: &[String], points: &[Vec<f64>], first_id: i64, dir: &Path) -> Result<TrainingTable> {
        let run = self.runner.run;
        let design_dir = dir.join("design");
        let spec_path = self.runner.config.resolve(&run.design);
        let mut spec = crate::engine::design::DesignSpec::load(&spec_path)?;
        spec.parameters.extend(self.candidate.design_parameter());
        let ids: Vec<i64> = (first_id..first_id + points.len() as i64).collect();
        let prov = Provenance::new(
            self.runner.config.hash.clone(),
            String::new(),
            self.seed,
            &format!("run {} --stage diagnose (refining {})", self.runner.config.path.display(), self.candidate.name),
        );
        let label = format!("mdpipe refine, variant {} ({} points)", self.candidate.name, ids.len());
        let runs = super::refine_rounds::write_new_points(&spec, &ids, points, names, &prov, &label, &design_dir)?;
        let d = heavy_ion::read_design_points(&design_dir.join("design.parquet"))?;
        let at: Vec<(i64, HeavyIonParams)> = d.ids.into_iter().zip(d.points).collect();
        heavy_ion::simulate_runs(
            &at,
            self.delta_f,
            run.events.unwrap_or_default(),
            run.oversample,
            self.seed,
            Layout::Hdf5,
            &runs,
        )?;
        let table = dir.join("training.parquet");
        self.runner.ingest_design(&design_dir, &table)?;
        read_training_table(&table, names)
    }
}

impl Runner<'_> {
    /// Refines the variant emulators an "emulator_limited" verdict lists and
    /// points `config`'s declarations at the refined ones. Returns whether
    /// any was refined (and the diagnosis must be made again).
    pub(super) fn refine_variants(
        &self,
        config: &mut Config,
        analysis: &Analysis,
        overrides: &Overrides,
        diagnosis: &Diagnosis,
    ) -> Result<bool> {
        let Some(settings) = self.run.refine.as_ref().filter(|r| r.variant_budget > 0) else { return Ok(false) };
        if diagnosis.verdict.best != "emulator_limited" {
            return Ok(false);
        }
        let rounds = RoundSettings {
            points_per_round: settings.points_per_round,
            budget: settings.variant_budget,
            draws: settings.draws,
        };
        let model_delta_f: DeltaF = self.run.model_delta_f.parse()?;
        for (k, name) in diagnosis.verdict.refine.iter().enumerate() {
            let candidate = heavy_ion::candidate(name)?;
            let variant = analysis
                .candidates()?
                .into_iter()
                .find(|c| &c.name == name)
                .ok_or_else(|| anyhow!("the verdict lists {name}, which is not declared"))?;
            let seed = self.opts.seed.wrapping_add(9_000 + 100 * k as u64);
            let runner = VariantRuns { runner: self, candidate, delta_f: candidate.delta_f(model_delta_f), seed };
            let out = self.paths.diagnose().join("refine").join(name);
            let emulator = self.paths.candidate(name).join("emulator");
            let refined = refine_variant(
                analysis,
                overrides,
                &variant,
                &emulator,
                &runner,
                &rounds,
                &out,
                seed,
                observer(self.opts.show_progress),
            )?;
            println!("  {name}: {}", refined.stopped);
            let table = config
                .candidates
                .iter_mut()
                .find(|t| t.get("name").and_then(|v| v.as_str()) == Some(name))
                .ok_or_else(|| anyhow!("no declaration of {name}"))?;
            table.insert("emulator".into(), absolute(&refined.emulator).display().to_string().into());
        }
        Ok(true)
    }
}
