//! `[model] kind = "emulator"`: a trained emulator as the model, and as
//! `diagnose` candidates the variant emulators declared in `[[candidates]]`
//! (trained on runs with extra physics switched on).

use super::correction::CorrectedModel;
use super::discover::EmulatedDiscoverer;
use super::EmulatedModel;
use crate::base::config::{Config, ParamSpec};
use crate::engine::model::{CandidateModel, Discoverer, ModelFamily, ModelSetup, Simulator, Units};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

pub struct EmulatorFamily;

/// `[model]` of kind "emulator".
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct EmulatorModelTable {
    /// Folder written by `mdpipe train-emulator`, relative to the config.
    artifact: PathBuf,
    /// Units of x and of each observable, for tables and figures (an emulator
    /// knows only names): `units = { x = "s", observables = { rate = "1/s" } }`.
    #[serde(default)]
    units: EmulatorUnits,
    /// A quantity that sets the observables apart, by name, with its value
    /// for each: `observable_labels = { current = { v_low = 0.5, v_high = 1.0 } }`.
    /// Discovery then also searches corrections whose one coefficient is
    /// shared across them, scaled by it (`emulator::shared`).
    #[serde(default)]
    observable_labels: BTreeMap<String, BTreeMap<String, f64>>,
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct EmulatorUnits {
    #[serde(default)]
    x: String,
    #[serde(default)]
    observables: BTreeMap<String, String>,
}

/// A model variant declared as a diagnose candidate: an emulator (folder
/// from `mdpipe train-emulator`, relative to the config) trained on runs with
/// extra physics switched on, e.g. the Grad shear δf.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CandidateDeclaration {
    pub name: String,
    /// What physics the variant adds, in a phrase.
    #[serde(default)]
    pub description: String,
    /// The variant emulator's folder. In a `[run]` study `mdpipe run` builds
    /// it and fills it in (the standalone commands find it the same way).
    #[serde(default)]
    pub emulator: Option<PathBuf>,
    /// Uniform priors of the variant's own parameters (beyond the model's θ).
    #[serde(default)]
    pub parameters: BTreeMap<String, ParamSpec>,
    /// How `mdpipe run` turns the physics on in the study's simulator:
    /// keys added to each point's parameter file,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub parameter_file: BTreeMap<String, toml::Value>,
    /// other values of the command's placeholders (`[run.simulator] placeholders`),
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub placeholders: BTreeMap<String, String>,
    /// or a command of its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    /// Or no variant at all: the model's output corrected by formulas of x,
    /// the observable itself, θ and the candidate's own parameters, the
    /// physics of the measurement (`{ rate = "rate/(1 + tau*rate)" }`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub correction: BTreeMap<String, String>,
}

impl CandidateDeclaration {
    /// A variant emulator's declaration (no simulator switches).
    pub fn of_emulator(
        name: &str,
        description: &str,
        emulator: PathBuf,
        parameters: BTreeMap<String, ParamSpec>,
    ) -> Self {
        CandidateDeclaration {
            name: name.into(),
            description: description.into(),
            emulator: Some(emulator),
            parameters,
            parameter_file: BTreeMap::new(),
            placeholders: BTreeMap::new(),
            command: None,
            correction: BTreeMap::new(),
        }
    }
}

impl CandidateDeclaration {
    /// Whether the candidate corrects the model's output instead of naming
    /// a variant of the simulator.
    pub fn is_correction(&self) -> bool {
        !self.correction.is_empty()
    }

    /// The declaration as a `[[candidates]]` table.
    pub fn to_table(&self) -> Result<toml::Table> {
        Ok(toml::Table::try_from(self)?)
    }
}

impl EmulatorFamily {
    /// A `[model]` table naming the emulator in `artifact`.
    pub fn model_table(artifact: &std::path::Path) -> toml::Table {
        toml::Table::from_iter([
            ("kind".to_string(), "emulator".into()),
            ("artifact".to_string(), artifact.display().to_string().into()),
        ])
    }
}

impl ModelFamily for EmulatorFamily {
    fn kind(&self) -> &'static str {
        "emulator"
    }

    fn open(&self, config: &Config) -> Result<Arc<dyn ModelSetup>> {
        let table: EmulatorModelTable = config.decode_family_table(&config.model, "model")?;
        let dir = config.resolve(&table.artifact);
        let model =
            EmulatedModel::load(&dir).with_context(|| format!("{}: [model] artifact", config.path.display()))?;
        let priors: Vec<(String, &str, &ParamSpec)> =
            config.parameters.iter().map(|(n, s)| (format!("[parameters.{n}]"), n.as_str(), s)).collect();
        check_priors_inside_box(
            &model,
            &priors,
            &format!("{}: the emulator {}", config.path.display(), dir.display()),
        )?;
        let units = Units { x: table.units.x, observables: table.units.observables, parameters: Default::default() };
        let model = Arc::new(model);
        let labels = super::labels::labels(&table.observable_labels, model.as_ref())
            .with_context(|| config.path.display().to_string())?;
        let discoverer = EmulatedDiscoverer { model: model.clone(), labels };
        Ok(Arc::new(EmulatorSetup { model, units, config: config.clone(), discoverer }))
    }
}

/// An emulator read from `[model] artifact`; its variants' emulators are
/// loaded only when `diagnose` asks for the candidates.
struct EmulatorSetup {
    model: Arc<EmulatedModel>,
    units: Units,
    config: Config,
    discoverer: EmulatedDiscoverer,
}

impl ModelSetup for EmulatorSetup {
    fn simulator(&self) -> Arc<dyn Simulator> {
        self.model.clone()
    }

    fn units(&self) -> Units {
        self.units.clone()
    }

    fn candidates(&self) -> Result<Vec<CandidateModel>> {
        declared_candidates(&self.config, &self.model)
    }

    fn discoverer(&self) -> Option<&dyn Discoverer> {
        Some(&self.discoverer)
    }
}

/// Every `[[candidates]]` table: a variant with its own emulator, or a
/// correction of the model's output.
fn declared_candidates(config: &Config, model: &Arc<EmulatedModel>) -> Result<Vec<CandidateModel>> {
    config
        .candidates
        .iter()
        .map(|t| {
            let c: CandidateDeclaration = config.decode(t, "[candidates]")?;
            if c.is_correction() {
                corrected_candidate(config, model.clone(), &c)
            } else {
                declared_candidate(config, &c)
            }
        })
        .collect()
}

/// A declared correction: the model's own emulator, its output corrected.
fn corrected_candidate(config: &Config, model: Arc<EmulatedModel>, c: &CandidateDeclaration) -> Result<CandidateModel> {
    let place = format!("{}: [[candidates]] {}", config.path.display(), c.name);
    if c.emulator.is_some() || !c.parameter_file.is_empty() || !c.placeholders.is_empty() || c.command.is_some() {
        bail!("{place}: a `correction` changes the model's output and needs no variant: leave out `emulator`, `parameter_file`, `placeholders` and `command`");
    }
    let mut extra = Vec::new();
    for (n, spec) in &c.parameters {
        spec.check(&format!("{place}: [candidates.parameters.{n}]"))?;
        if config.parameters.contains_key(n) {
            bail!("{place}: parameter '{n}' is already a parameter of the model");
        }
        extra.push((n.clone(), spec.clone()));
    }
    let names: Vec<String> = extra.iter().map(|(n, _)| n.clone()).collect();
    let simulator = CorrectedModel::new(model, &c.correction, &names, &place)?;
    Ok(CandidateModel {
        name: c.name.clone(),
        description: c.description.clone(),
        extra_parameters: extra,
        simulator: Arc::new(simulator),
        special_case_of: Vec::new(),
        own_emulator: false,
    })
}

/// A declared variant: its parameters must be the base θ plus the variant's
/// own, whose priors the declaration gives.
fn declared_candidate(config: &Config, c: &CandidateDeclaration) -> Result<CandidateModel> {
    let file = config.path.display();
    let switches = !c.parameter_file.is_empty() || !c.placeholders.is_empty() || c.command.is_some();
    if switches && config.run.is_none() {
        bail!("{file}: [[candidates]] {}: `parameter_file`, `placeholders` and `command` tell `mdpipe run` how to run the variant; this config has no [run] table, so nothing would run it", c.name);
    }
    let emulator = c.emulator.as_ref().ok_or_else(|| {
        anyhow!("{file}: [[candidates]] {}: no `emulator`: give the variant emulator's folder, or build it with `mdpipe run` (a [run] study's commands then find it in the study's outputs)", c.name)
    })?;
    let dir = config.resolve(emulator);
    let model = EmulatedModel::load(&dir).with_context(|| {
        format!("{file}: [[candidates]] {}: loading the variant emulator {}", c.name, dir.display())
    })?;
    let names = model.parameter_names();
    if let Some(missing) = config.parameters.keys().find(|p| !names.contains(p)) {
        bail!(
            "{file}: [[candidates]] {}: the variant emulator {} lacks the model parameter '{missing}' (it has {})",
            c.name,
            dir.display(),
            names.join(", ")
        );
    }
    let mut extra = Vec::new();
    for n in names.iter().filter(|n| !config.parameters.contains_key(*n)) {
        let spec = c.parameters.get(n).ok_or_else(|| anyhow!("{file}: [[candidates]] {}: give prior bounds for the variant's own parameter '{n}' in [candidates.parameters.{n}]", c.name))?;
        spec.check(&format!("{file}: [[candidates]] {}: [candidates.parameters.{n}]", c.name))?;
        extra.push((n.clone(), spec.clone()));
    }
    if let Some(unused) = c.parameters.keys().find(|k| !names.contains(k)) {
        bail!(
            "{file}: [[candidates]] {}: parameter '{unused}' is not one of the variant emulator's ({})",
            c.name,
            names.join(", ")
        );
    }
    let own = extra.iter().map(|(n, s)| (format!("[candidates.parameters.{n}]"), n.as_str(), s));
    let priors: Vec<(String, &str, &ParamSpec)> =
        config.parameters.iter().map(|(n, s)| (format!("[parameters.{n}]"), n.as_str(), s)).chain(own).collect();
    check_priors_inside_box(
        &model,
        &priors,
        &format!("{file}: [[candidates]] {}: the variant emulator {}", c.name, dir.display()),
    )?;
    Ok(CandidateModel {
        name: c.name.clone(),
        description: c.description.clone(),
        extra_parameters: extra,
        simulator: Arc::new(model),
        special_case_of: Vec::new(),
        own_emulator: true,
    })
}

/// Refuses priors that reach well beyond the emulator's training points:
/// there the GP falls back to its mean and the "model" is no model at all,
/// which a sampler would explore without a word. A Latin hypercube puts its
/// outermost point within one cell (range / points) of its box's edge, and a
/// random design rarely leaves more than two: a prior past the outermost
/// point by more than two cells gets a warning, and by more than a quarter
/// of the training range (a prior box that was never designed over) is
/// refused.
fn check_priors_inside_box(model: &EmulatedModel, priors: &[(String, &str, &ParamSpec)], what: &str) -> Result<()> {
    let parts = &model.emulator.parts;
    let cell = 1.0 / parts.design_ids.len().max(1) as f64;
    for (table, name, spec) in priors {
        let Some(p) = parts.parameter_names.iter().position(|n| n == name) else { continue };
        let (lo, hi) = (parts.input_lo[p], parts.input_hi[p]);
        let excess = (lo - spec.min).max(spec.max - hi).max(0.0) / (hi - lo);
        let said = format!(
            "{what} was trained on {name} in [{lo}, {hi}], but {table} gives a prior of [{}, {}], {:.0}% of the range beyond the outermost training point",
            spec.min,
            spec.max,
            100.0 * excess
        );
        if excess > 0.25 {
            bail!("{said}: out there the emulator returns its mean, not the model. Narrow the prior to the training box, or run design points out there and retrain");
        }
        if excess > 2.0 * cell {
            crate::base::messages::note!("warning: {said}; the emulator extrapolates there");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(extra: &str) -> Config {
        let text = format!(
            "name = \"t\"\n[model]\nkind = \"emulator\"\nartifact = \"e\"\n[data]\nmeasurements = \"d.csv\"\n[parameters.a]\nmin = 0.0\nmax = 1.0\n{extra}"
        );
        let mut c: Config = toml::from_str(&text).unwrap();
        c.path = "study.toml".into();
        c
    }

    /// A field that tells `mdpipe run` how to switch a candidate on means
    /// nothing without a [run] table: refused, not ignored.
    #[test]
    fn run_switches_without_a_run_table_are_refused() {
        let c = config("[[candidates]]\nname = \"x\"\ncommand = \"sim {point}\"\nemulator = \"v\"\n");
        let refusal = |c: &Config| {
            let d: CandidateDeclaration = c.decode(&c.candidates[0], "[candidates]").unwrap();
            match declared_candidate(c, &d) {
                Ok(_) => panic!("accepted"),
                Err(e) => format!("{e:#}"),
            }
        };
        let msg = refusal(&c);
        assert!(msg.contains("study.toml") && msg.contains("no [run] table"), "{msg}");
        let c = config("[[candidates]]\nname = \"x\"\n");
        let msg = refusal(&c);
        assert!(msg.contains("no `emulator`") && msg.contains("mdpipe run"), "{msg}");
    }
}
