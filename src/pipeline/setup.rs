//! The study as its systems complete it (`study::StudySystem`): what its
//! simulate stage runs, what they add to its stages' keys, the data and the
//! analysis its calibrations use. The systems are the run's
//! (`Study::systems`, the list `app::systems()` passes in).

use super::run_config::RunConfig;
use super::stage::StageId;
use super::study::{absolute, Study, StudySystem};
use super::system::Systems;
use crate::base::artifacts;
use crate::base::config::Config;
use crate::engine::calibrate::Analysis;
use crate::engine::emulator::EmulatorFamily;
use crate::engine::execute::SimulatorSpec;
use crate::engine::model::Registry;
use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;
use std::sync::Arc;

/// The first answer any of the study's systems gives.
fn first<T>(study: &Study<'_>, ask: impl Fn(&dyn StudySystem) -> Option<T>) -> Option<T> {
    study.systems.iter().find_map(|s| ask(*s))
}

/// The first answer any of the study's systems gives, or its first error.
fn first_ok<T>(study: &Study<'_>, ask: impl Fn(&dyn StudySystem) -> Result<Option<T>>) -> Result<Option<T>> {
    for s in study.systems {
        if let Some(t) = ask(*s)? {
            return Ok(Some(t));
        }
    }
    Ok(None)
}

/// Every table of `[run]` that is not its own belongs to a system, which
/// checks it; and without `[run.simulator]` some system must run the points.
pub(super) fn check_system_tables(run: &RunConfig, systems: &Systems) -> Result<()> {
    let known: Vec<&str> = systems.iter().filter_map(|s| s.run_table()).collect();
    if let Some(name) = run.systems.keys().find(|name| !known.contains(&name.as_str())) {
        bail!("[run.{name}]: no system of that name (the systems: {})", known.join(", "));
    }
    if run.simulator.is_none() && run.systems.is_empty() {
        bail!("[run]: give a [run.simulator] table, or the table of a system that runs its own ({})", tables(&known));
    }
    for system in systems.iter() {
        system.validate(run)?;
    }
    Ok(())
}

/// Systems' tables as a config writes them: `[run.<system>]`.
pub(super) fn tables(names: &[&str]) -> String {
    names.iter().map(|n| format!("[run.{n}]")).collect::<Vec<_>>().join(", ")
}

/// What the systems add to a generic stage's key.
pub(super) fn system_settings(study: &Study<'_>, stage: StageId) -> serde_json::Map<String, serde_json::Value> {
    let mut settings = serde_json::Map::new();
    for system in study.systems {
        settings.extend(system.key_settings(study, stage));
    }
    settings
}

impl Study<'_> {
    /// What the simulate stage runs: `[run.simulator]`, or a system's own
    /// (a system's command runs the same in the design's Slurm array).
    pub(super) fn simulator(&self, validation: bool) -> Result<SimulatorSpec> {
        if let Some(s) = &self.run.simulator {
            return Ok(s.clone());
        }
        first_ok(self, |s| s.default_simulator(self, validation))?.ok_or_else(|| {
            let known: Vec<&str> = self.systems.iter().filter_map(|s| s.run_table()).collect();
            anyhow!(
                "{}: give a [run.simulator] table, or the table of a system that runs its own ({})",
                self.config.path.display(),
                tables(&known)
            )
        })
    }

    /// The analysis config pointed at the study's emulator (refined, with
    /// `[run.refine]`) and mock data.
    pub(super) fn study_config(&self) -> Result<Config> {
        Ok(self.study_config_with(&super::stage::refine::report::emulator_in_use(self)?))
    }

    /// The analysis config pointed at `emulator` and this run's mock data.
    pub(super) fn study_config_with(&self, emulator: &Path) -> Config {
        let mut c = self.config.clone();
        // The config's own [model] keys (its units) stay; the study's emulator is the artifact.
        let emulator_kind = c.model.get("kind").and_then(|k| k.as_str()) == Some("emulator");
        let mut model = if emulator_kind { c.model.clone() } else { toml::Table::new() };
        model.extend(EmulatorFamily::model_table(&absolute(emulator)));
        c.model = model;
        if let Some(data) = first(self, |s| s.data(self)) {
            c.data.measurements = data.measurements;
            c.data.covariance = data.covariance;
        }
        c
    }

    /// The study's analysis: the study's emulator as the model, a system's
    /// family (a system that simulates its own data) as the `[truth]` process.
    pub(super) fn analysis(&self, config: &Config) -> Result<Analysis> {
        let mut families = Registry::new();
        families.register(Arc::new(EmulatorFamily));
        for family in self.systems.iter().filter_map(|s| s.family()) {
            families.register(family);
        }
        let mut analysis = Analysis::resolve(config, &families)?;
        // The emulator knows no units; the system's come first, as in its figures.
        if let Some(units) = first(self, |s| s.units(self)) {
            analysis.units = units.or(&analysis.units);
        }
        Ok(analysis)
    }

    /// SHA-256 of the measurements the calibrations use (the config's, when
    /// no system made them: the key of the stage that did covers those).
    pub(super) fn data_hash(&self) -> Result<String> {
        if first(self, |s| s.data(self)).is_some() {
            return Ok(String::new());
        }
        let path = self.config.resolve(&self.config.data.measurements);
        Ok(artifacts::sha256_hex(
            &std::fs::read(&path).with_context(|| format!("reading the measurements {}", path.display()))?,
        ))
    }
}
