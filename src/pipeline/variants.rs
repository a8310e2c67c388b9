//! Candidate physics as variants of the study's simulator (built by the
//! candidates stage, `stage::candidates`).
//!
//! A `[[candidates]]` table says how the simulator turns its physics on, in
//! any of three ways: keys added to each point's parameter file
//! (`parameter_file`), other values of the command's own placeholders
//! (`placeholders`, declared in `[run.simulator] placeholders`), or a command
//! of its own (`command`). Its `parameters` join θ in its design and are the
//! priors of its fit. A system's own library (a table of its own in `[run]`)
//! gives variants of the same kind (`study::StudySystem::library_variants`).

use crate::base::config::{Config, ParamSpec};
use crate::engine::design::{DesignParameter, DesignSpec};
use crate::engine::emulator::family::CandidateDeclaration;
use crate::engine::execute::{spec::placeholders_of, SimulatorSpec};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;

/// A candidate physics as a variant of the simulator.
#[derive(Clone, Debug, serde::Serialize)]
pub(crate) struct Variant {
    pub name: String,
    /// Its `[[candidates]]` table for diagnose, `emulator` filled in.
    pub declaration: toml::Table,
    /// Its own parameters, as design dimensions.
    pub parameters: Vec<DesignParameter>,
    /// Keys added to (or replacing) the design's `fixed` keys in every parameter file.
    pub parameter_file: BTreeMap<String, toml::Value>,
    /// What runs at each point.
    pub simulator: SimulatorSpec,
    pub design_seed: u64,
}

impl Variant {
    /// The design spec of its runs: the study's, with its parameters and keys added.
    pub fn design_spec(&self, base: &DesignSpec) -> DesignSpec {
        let mut spec = base.clone();
        spec.parameters.extend(self.parameters.iter().cloned());
        spec.fixed.extend(self.parameter_file.clone());
        spec
    }
}

/// A declared candidate's switch and parameters checked against the study's
/// design and simulator, before anything runs; returns its simulator.
pub(super) fn check_declaration(
    c: &CandidateDeclaration,
    spec: &DesignSpec,
    base: &SimulatorSpec,
) -> Result<SimulatorSpec> {
    let folder_safe = !c.name.is_empty() && c.name.chars().all(|ch| ch.is_alphanumeric() || ch == '_' || ch == '-');
    if !folder_safe {
        bail!("name {:?}: use letters, digits, '_' and '-' (it names the variant's folder)", c.name);
    }
    if c.command.is_none() && c.placeholders.is_empty() && c.parameter_file.is_empty() && c.parameters.is_empty() {
        bail!("says nothing of how the simulator turns this physics on: give `parameter_file` keys, `placeholders` values or a `command` of its own (and its `parameters`)");
    }
    let mut simulator = base.clone();
    if let Some(command) = &c.command {
        simulator.command = command.clone();
    }
    let used = placeholders_of(&simulator.command);
    for (name, value) in &c.placeholders {
        if !used.contains(name) {
            bail!("placeholders: {{{name}}} is not in the command `{}`", simulator.command);
        }
        simulator.placeholders.insert(name.clone(), value.clone());
    }
    let design: Vec<&DesignParameter> = spec.parameters.iter().collect();
    for key in c.parameter_file.keys() {
        if let Some(p) = design.iter().find(|p| p.file_key() == key || &p.name == key) {
            bail!("parameter_file: key '{key}' is the design parameter '{}' of every point; a candidate may not overwrite it", p.name);
        }
    }
    if !c.parameter_file.is_empty() && !used.iter().any(|u| u == "param_file") {
        bail!(
            "parameter_file: the command `{}` does not read the parameter file (no {{param_file}})",
            simulator.command
        );
    }
    for (name, prior) in &c.parameters {
        prior.check(&format!("[candidates.parameters.{name}]"))?;
        if design.iter().any(|p| &p.name == name || p.file_key() == name) {
            bail!("parameter '{name}' is already a design parameter of the model");
        }
        if !used.iter().any(|u| u == name || u == "param_file") {
            bail!(
                "parameter '{name}' is used nowhere: the command `{}` has neither {{{name}}} nor {{param_file}}",
                simulator.command
            );
        }
        if let Some(t) = prior.truth.filter(|t| !(prior.min..=prior.max).contains(t)) {
            bail!("[candidates.parameters.{name}] truth {t} lies outside its prior [{}, {}]", prior.min, prior.max);
        }
    }
    let names: Vec<String> = design.iter().map(|p| p.name.clone()).chain(c.parameters.keys().cloned()).collect();
    simulator.validate(&names).context("its simulator")?;
    Ok(simulator)
}

/// Each θ's prior must lie inside the range the design's runs cover: an
/// emulator is not asked where it has never seen a run.
pub(super) fn check_priors_inside_design(config: &Config, spec: &DesignSpec) -> Result<()> {
    for (name, prior) in &config.parameters {
        let Some(p) = spec.parameters.iter().find(|p| &p.name == name) else {
            bail!(
                "[parameters.{name}] is not a parameter of the design spec (it has {})",
                spec.parameters.iter().map(|p| p.name.as_str()).collect::<Vec<_>>().join(", ")
            );
        };
        if prior.min < p.min || prior.max > p.max {
            bail!(
                "[parameters.{name}]: the prior [{}, {}] reaches outside what the design's runs cover [{}, {}]",
                prior.min,
                prior.max,
                p.min,
                p.max
            );
        }
    }
    Ok(())
}

pub(super) fn design_parameter(name: &str, prior: &ParamSpec) -> DesignParameter {
    DesignParameter {
        name: name.into(),
        min: prior.min,
        max: prior.max,
        log: false,
        key: String::new(),
        units: prior.units.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> DesignSpec {
        toml::from_str(
            "name = \"d\"\n[[parameter]]\nname = \"activity\"\nmin = 1.0\nmax = 2.0\n[[parameter]]\nname = \"half_life\"\nmin = 1.0\nmax = 4.0\nkey = \"T_half\"\n",
        )
        .unwrap()
    }

    fn simulator() -> SimulatorSpec {
        toml::from_str(
            "command = \"sim {param_file} {point} --background {background}\"\noutput = \"table\"\nplaceholders = { background = \"off\" }",
        )
        .unwrap()
    }

    fn refusal(candidate: &str) -> String {
        let c: CandidateDeclaration = toml::from_str(candidate).unwrap();
        format!("{:#}", check_declaration(&c, &spec(), &simulator()).expect_err("accepted"))
    }

    #[test]
    fn bad_declarations_are_refused_with_the_field_at_fault() {
        let cases = [
            // A placeholder the command does not have.
            ("name = \"a\"\nplaceholders = { radiation = \"on\" }", "{radiation} is not in the command"),
            // A key that would overwrite a design parameter, by name or by file key.
            ("name = \"a\"\nparameter_file = { T_half = 3 }", "design parameter 'half_life'"),
            ("name = \"a\"\nparameter_file = { activity = 3 }", "design parameter 'activity'"),
            // A parameter the simulator never sees.
            (
                "name = \"a\"\ncommand = \"sim {point} --background {background}\"\n[parameters.eps]\nmin = 0.0\nmax = 1.0",
                "parameter 'eps' is used nowhere",
            ),
            // Parameter-file keys with a command that reads no parameter file.
            ("name = \"a\"\ncommand = \"sim {point} {background}\"\nparameter_file = { x = 1 }", "does not read the parameter file"),
            // Nothing said of how the physics is switched on.
            ("name = \"a\"", "says nothing of how"),
            // A parameter that is θ already, and a bad prior.
            ("name = \"a\"\n[parameters.activity]\nmin = 0.0\nmax = 1.0", "already a design parameter"),
            ("name = \"a\"\n[parameters.eps]\nmin = 1.0\nmax = 0.0", "min < max"),
            ("name = \"a\"\n[parameters.eps]\nmin = 0.0\nmax = 1.0\ntruth = 2.0", "outside its prior"),
            ("name = \"a b\"\nplaceholders = { background = \"on\" }", "name \"a b\""),
        ];
        for (candidate, expected) in cases {
            let msg = refusal(candidate);
            assert!(msg.contains(expected), "{candidate:?}: expected {expected:?} in {msg:?}");
        }
        let good: CandidateDeclaration = toml::from_str(
            "name = \"bg\"\nplaceholders = { background = \"on\" }\n[parameters.rate]\nmin = 0.0\nmax = 1.0",
        )
        .unwrap();
        let s = check_declaration(&good, &spec(), &simulator()).unwrap();
        assert_eq!(s.placeholders["background"], "on");
    }

    #[test]
    fn a_prior_beyond_the_design_is_refused_before_any_run() {
        let text = "name = \"t\"\n[model]\nkind = \"emulator\"\n[data]\nmeasurements = \"d.csv\"\n[parameters.activity]\nmin = 0.5\nmax = 2.0\n[parameters.half_life]\nmin = 1.0\nmax = 4.0\n";
        let config: Config = toml::from_str(text).unwrap();
        let msg = format!("{:#}", check_priors_inside_design(&config, &spec()).unwrap_err());
        assert!(msg.contains("[parameters.activity]") && msg.contains("[1, 2]"), "{msg}");
    }
}
