//! The heavy-ion stand-in as a system of `mdpipe run` (`study::StudySystem`, `system::System`):
//! its command as the default simulator, its mock data with the truth known
//! (the mock stage, `mock.rs`), its library of candidate physics as
//! simulator variants, and the assessment of the calibrations against that
//! truth (study.json, study.md) with its report section and figures.

mod mock;
mod settings;

use crate::base::artifacts;
use crate::base::config::Config;
use crate::engine::execute::{OutputKind, SimulatorSpec};
use crate::engine::model::{ModelFamily, Units};
use crate::engine::report::SystemFigures;
use crate::pipeline::run_config::RunConfig;
use crate::pipeline::stage::StageId;
use crate::pipeline::study::*;
use crate::pipeline::system::{System, SystemStage};
use crate::pipeline::variants::Variant;
use crate::systems::heavy_ion::family::HeavyIonFamily;
use crate::systems::heavy_ion::figures::HeavyIonFigures;
use crate::systems::heavy_ion::{self, DeltaF};
use anyhow::{anyhow, Context, Result};
use settings::StandInRun;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// The heavy-ion stand-in.
pub(crate) struct StandIn;

impl StudySystem for StandIn {
    fn run_table(&self) -> Option<&'static str> {
        Some(settings::TABLE)
    }

    fn validate(&self, run: &RunConfig) -> Result<()> {
        match StandInRun::of(run)? {
            Some(s) => s.validate(run).with_context(|| format!("[run.{}]", settings::TABLE)),
            None => Ok(()),
        }
    }

    fn library_declarations(&self, run: &RunConfig, paths: &RunPaths) -> Result<Vec<toml::Table>> {
        let names = StandInRun::of(run)?.map(|s| s.candidates).unwrap_or_default();
        names
            .iter()
            .map(|name| {
                let emulator = absolute(&paths.candidate(name).join("emulator"));
                heavy_ion::candidate(name)?.declaration(emulator).to_table()
            })
            .collect()
    }

    /// Its keys of `[run]` that shape the runs: events per point, Cooper–Frye
    /// samples per event, and the model's δf.
    fn key_settings(&self, study: &Study<'_>, stage: StageId) -> serde_json::Map<String, serde_json::Value> {
        let mut settings = serde_json::Map::new();
        let Ok(Some(stand_in)) = StandInRun::of(study.run) else { return settings };
        if matches!(stage, StageId::DESIGN | StageId::SIMULATE | StageId::REFINE | StageId::CANDIDATES) {
            settings.insert("events".into(), stand_in.events.into());
            settings.insert("oversample".into(), stand_in.oversample.into());
            settings.insert("delta_f".into(), stand_in.model_delta_f.into());
        }
        settings
    }

    fn default_simulator(&self, study: &Study<'_>, validation: bool) -> Result<Option<SimulatorSpec>> {
        let Some(stand_in) = StandInRun::of(study.run)? else { return Ok(None) };
        stand_in_simulator(&stand_in, &stand_in.model_delta_f, runs_seed(study, validation)).map(Some)
    }

    fn library_variants(&self, study: &Study<'_>) -> Result<Vec<Variant>> {
        library_variants(study)
    }

    fn data(&self, study: &Study<'_>) -> Option<StudyData> {
        mock_study(study).then(|| {
            // The mock's bins are counted from the same events (correlated by
            // 0.6-0.95 within a spectrum); with errors alone the likelihood
            // is overconfident and the MD fits excluded ε_sw by 2-3 sd.
            let covariance = mock::folder(study).join("covariance.csv");
            StudyData {
                measurements: absolute(&mock::measurements(study)),
                covariance: covariance.exists().then(|| absolute(&covariance)),
            }
        })
    }

    fn family(&self) -> Option<Arc<dyn ModelFamily>> {
        Some(Arc::new(HeavyIonFamily))
    }

    fn units(&self, study: &Study<'_>) -> Option<Units> {
        mock_study(study).then(HeavyIonFamily::units)
    }

    fn assessment(&self, study: &Study<'_>) -> Option<PathBuf> {
        mock_study(study).then(|| study.paths.out.join("study.json"))
    }

    fn assess(&self, study: &Study<'_>, config: &Config, dirs: &[PathBuf]) -> Result<()> {
        let truth_curve: BTreeMap<String, f64> = mock::truth_named(study)?.into_iter().collect();
        let assessed = heavy_ion::study::assess(
            config,
            dirs,
            &truth_curve,
            &crate::pipeline::stage::refine::report::emulator_in_use(study)?,
            &study.paths.validation(),
            &mock::measurements(study),
        )?;
        artifacts::write_json_atomic(&study.paths.out.join("study.json"), &assessed)?;
        let mut md = assessed.markdown();
        if let Some(rounds) = crate::pipeline::stage::refine::report::rounds(study)? {
            md.push_str(&rounds.study_section());
        }
        artifacts::write_text_atomic(&study.paths.out.join("study.md"), &md)?;
        crate::base::messages::say!("{md}");
        Ok(())
    }

    fn figures(&self) -> Option<&'static dyn SystemFigures> {
        Some(&HeavyIonFigures)
    }

    fn report_section(&self, study: &Study<'_>) -> Result<Option<String>> {
        let Some(path) = self.assessment(study) else { return Ok(None) };
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let assessed: heavy_ion::study::Study = serde_json::from_str(&text)?;
        Ok(Some(assessed.html()))
    }
}

impl System for StandIn {
    /// Its mock data, made before the first stage that reads the data, and
    /// read by every stage that does.
    fn stages(&self) -> &'static [SystemStage] {
        &[SystemStage {
            stage: &mock::Mock,
            after: StageId::EMULATOR,
            read_by: &[StageId::REFINE, StageId::CALIBRATE, StageId::DIAGNOSE],
        }]
    }
}

/// Seed of the stand-in's events, distinct for the training and validation designs.
fn runs_seed(study: &Study<'_>, validation: bool) -> u64 {
    study.opts.seed.wrapping_mul(31).wrapping_add(if validation { 104_729 } else { 11 })
}

/// The stand-in as a simulator like any other: one point's events with
/// the particlization `delta_f` (the design may add its candidates'
/// parameters, which `simulate heavy-ion --design` reads).
fn stand_in_simulator(stand_in: &StandInRun, delta_f: &str, seed: u64) -> Result<SimulatorSpec> {
    let events = stand_in.events.ok_or_else(|| anyhow!("[run.stand_in] events is needed to run the stand-in"))?;
    let command = format!(
        "{{mdpipe}} simulate heavy-ion --design {{design}} --only {{id}} --point-folder --delta-f {delta_f} --events {events} --oversample {} --layout hdf5 --seed {seed} --out {{point}}",
        stand_in.oversample,
    );
    Ok(SimulatorSpec {
        command,
        placeholders: Default::default(),
        output: OutputKind::IebeMusic,
        time_limit: "1h".into(),
        retries: 1,
        parallel: None,
        slurm: Default::default(),
    })
}

/// The stand-in's library candidates `[run.stand_in] candidates` names, as
/// variants of its simulator: each a command of its own (the Grad δf
/// switched on, or the model's δf) with its parameter added to the design.
fn library_variants(study: &Study<'_>) -> Result<Vec<Variant>> {
    let Some(stand_in) = StandInRun::of(study.run)? else { return Ok(Vec::new()) };
    let model_delta_f: DeltaF = stand_in.model_delta_f.parse()?;
    stand_in
        .candidates
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let c = heavy_ion::candidate(name)?;
            let delta_f =
                if c.delta_f(model_delta_f) == DeltaF::Grad { "grad" } else { stand_in.model_delta_f.as_str() };
            let seed = study.opts.seed.wrapping_add(1_000 * (k as u64 + 1));
            let simulator = stand_in_simulator(&stand_in, delta_f, seed)?;
            Ok(Variant {
                declaration: c.declaration(absolute(&study.paths.candidate(name).join("emulator"))).to_table()?,
                name: c.name.into(),
                parameters: c.design_parameter().into_iter().collect(),
                parameter_file: Default::default(),
                simulator,
                design_seed: seed,
            })
        })
        .collect()
}

/// Whether the study calibrates on the stand-in's mock data (`[run.stand_in] mock_delta_f`).
fn mock_study(study: &Study<'_>) -> bool {
    StandInRun::of(study.run).ok().flatten().is_some_and(|s| s.mock_study())
}

#[cfg(test)]
mod tests {
    use crate::pipeline::stage::StageId;
    use crate::pipeline::Systems;

    /// Its mock stage runs before every stage that reads the data, and they read it.
    #[test]
    fn the_mock_stage_runs_before_the_stages_that_read_the_data() {
        let stages = crate::pipeline::plan::stages(&Systems::new(vec![&super::StandIn]));
        let at = |id: StageId| stages.iter().position(|p| p.stage.id() == id).unwrap();
        let mock = at(super::mock::MOCK);
        for reader in [StageId::REFINE, StageId::CALIBRATE, StageId::DIAGNOSE] {
            assert!(mock < at(reader), "{reader}");
            assert!(stages[at(reader)].upstream.contains(&super::mock::MOCK), "{reader}");
        }
    }
}
