//! What a config declares of a model: the `[model]` table of kind
//! "expression" or "ode", the `[[candidates]]` it may be missing, and the
//! `[truth]` that made mock data; and [`Declared`], one model with a chosen
//! set of candidate terms switched on, ready to compile.

use crate::base::config::{Config, ParamSpec};
use anyhow::{anyhow, bail, Result};
use std::collections::BTreeMap;

/// `[model]` of kind "expression" or "ode".
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelTable {
    /// The independent variable's name in formulas (default `x`; `t` for an ODE).
    pub input: Option<String>,
    /// Known values, by name, usable in every formula.
    #[serde(default)]
    pub constants: BTreeMap<String, f64>,
    /// Each observable's prediction: a formula of the input, θ and constants
    /// (and, for an ODE, the state variables and their rates `d_<state>`).
    pub observables: BTreeMap<String, String>,
    #[serde(default)]
    pub units: UnitsTable,
    /// ODE only: each state variable's value at `t0`, a formula of θ and constants.
    #[serde(default)]
    pub initial: BTreeMap<String, String>,
    /// ODE only: each state variable's rate d(state)/dt, a formula of t, θ,
    /// constants and the state.
    #[serde(default)]
    pub rates: BTreeMap<String, String>,
    /// ODE only: where the initial conditions hold (default 0).
    pub t0: Option<f64>,
    #[serde(default)]
    pub solver: SolverSettings,
    /// Whether `diagnose` also tries every pair of candidates (default true).
    #[serde(default = "yes")]
    pub candidate_pairs: bool,
    /// What `diagnose` may discover beyond the candidates.
    #[serde(default)]
    pub discover: DiscoverTable,
}

/// `[model.discover]`.
#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscoverTable {
    /// A grammar file of more term forms (the bundled grammar's format), relative to the config.
    pub grammar: Option<std::path::PathBuf>,
}

fn yes() -> bool {
    true
}

#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnitsTable {
    #[serde(default)]
    pub x: String,
    #[serde(default)]
    pub observables: BTreeMap<String, String>,
}

/// Error control of the ODE integrator. Tolerances left unset follow the
/// data's precision (`ode::tolerance`).
#[derive(Clone, Copy, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSettings {
    #[serde(default)]
    pub rtol: Option<f64>,
    #[serde(default)]
    pub atol: Option<f64>,
    /// Steps before an integration is given up (and its θ given zero likelihood).
    #[serde(default = "default_max_steps")]
    pub max_steps: u32,
}

fn default_max_steps() -> u32 {
    20_000
}

impl Default for SolverSettings {
    fn default() -> Self {
        SolverSettings { rtol: None, atol: None, max_steps: default_max_steps() }
    }
}

/// One `[[candidates]]` entry: physics the model may be missing, as terms
/// added to observables and (ODE) to rates, with its own parameters.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CandidateTable {
    pub name: String,
    /// What the candidate adds, in one line.
    pub description: String,
    #[serde(default)]
    pub observables: BTreeMap<String, String>,
    #[serde(default)]
    pub rates: BTreeMap<String, String>,
    /// Parameters that vary: a parameter of the model → the formula that
    /// replaces it in every rate and observable (`k = "k*(1 + c*T)"`).
    #[serde(default)]
    pub vary: BTreeMap<String, String>,
    /// Uniform priors of the candidate's own parameters.
    #[serde(default)]
    pub parameters: BTreeMap<String, ParamSpec>,
}

/// `[truth]` of kind "expression" or "ode": the declared model with
/// candidates switched on at fixed values of their parameters, and terms
/// from outside the library (out-of-library effects for blind tests).
#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruthTable {
    /// Candidate name → its parameters' values.
    #[serde(default)]
    pub candidates: BTreeMap<String, BTreeMap<String, f64>>,
    /// Values of names used only in the terms below.
    #[serde(default)]
    pub constants: BTreeMap<String, f64>,
    #[serde(default)]
    pub observables: BTreeMap<String, String>,
    #[serde(default)]
    pub rates: BTreeMap<String, String>,
}

/// A formula and where it was written, for errors.
#[derive(Clone, Debug)]
pub struct Written {
    pub text: String,
    pub place: String,
}

impl Written {
    fn plus(&self, term: &str, place: &str) -> Written {
        Written { text: crate::engine::formula::plus(&self.text, term), place: format!("{} + {place}", self.place) }
    }
}

/// An ODE state variable.
#[derive(Clone, Debug)]
pub struct State {
    pub name: String,
    pub initial: Written,
    pub rate: Written,
    /// A rate that reads as a kinematic identity (`dx/dt = v`) which the
    /// data contradict: a law written short, not a definition
    /// (`discover::identities`).
    pub law_by_data: bool,
}

/// One model ready to compile: θ with its prior box, constants, and every
/// formula with the chosen candidates' terms added.
#[derive(Clone, Debug)]
pub struct Declared {
    pub input: String,
    pub parameters: Vec<String>,
    /// Where each parameter was declared, for errors: `[parameters.g]` or
    /// `[[candidates]] drag: [candidates.parameters.k]`.
    pub declared_at: Vec<String>,
    /// Prior box of each parameter, for the checks at its corners.
    pub bounds: Vec<(f64, f64)>,
    pub constants: Vec<(String, f64)>,
    pub observables: Vec<(String, Written)>,
    /// Empty for an expression model.
    pub states: Vec<State>,
    pub t0: f64,
    pub solver: SolverSettings,
    /// Multiple shooting from the data every this long in t (`ode::shooting`):
    /// how discovery screens a flow one trajectory cannot follow. None: one
    /// trajectory from t0, as every calibration is.
    pub shooting: Option<f64>,
}

impl Declared {
    /// The base model of `config`'s `[model]` table.
    pub fn base(config: &Config, table: &ModelTable, ode: bool) -> Result<Declared> {
        let file = config.path.display().to_string();
        let kind = if ode { "ode" } else { "expression" };
        if !ode && (!table.initial.is_empty() || !table.rates.is_empty() || table.t0.is_some()) {
            bail!("{file}: [model] kind = \"expression\" has no state: `initial`, `rates` and `t0` belong to kind = \"ode\"");
        }
        if table.observables.is_empty() {
            bail!("{file}: [model.observables]: declare at least one observable as a formula");
        }
        let states = if ode { states(&file, table)? } else { Vec::new() };
        let observables = table
            .observables
            .iter()
            .map(|(name, text)| {
                (name.clone(), Written { text: text.clone(), place: format!("{file}: [model.observables] {name}") })
            })
            .collect();
        let mut parameters = Vec::new();
        let mut bounds = Vec::new();
        for (name, spec) in &config.parameters {
            spec.check(&format!("{file}: [parameters.{name}]"))?;
            parameters.push(name.clone());
            bounds.push((spec.min, spec.max));
        }
        let declared = Declared {
            input: table.input.clone().unwrap_or_else(|| if ode { "t".into() } else { "x".into() }),
            declared_at: parameters.iter().map(|n| format!("[parameters.{n}]")).collect(),
            parameters,
            bounds,
            constants: table.constants.iter().map(|(k, v)| (k.clone(), *v)).collect(),
            observables,
            states,
            t0: table.t0.unwrap_or(0.0),
            solver: table.solver,
            shooting: None,
        };
        declared.check_names(&file, kind)?;
        check_solver(&file, &table.solver)?;
        Ok(declared)
    }

    /// Whether `name` is already the input, a parameter, a constant, a state or an observable.
    pub fn knows(&self, name: &str) -> bool {
        self.input == name
            || self.parameters.iter().any(|p| p == name)
            || self.constants.iter().any(|(c, _)| c == name)
            || self.states.iter().any(|s| s.name == name)
            || self.observables.iter().any(|(o, _)| o == name)
    }

    /// Every name once: the input, θ, constants and states may not share one.
    fn check_names(&self, file: &str, kind: &str) -> Result<()> {
        let mut seen: BTreeMap<&str, &str> = BTreeMap::new();
        let rates: Vec<String> = self.states.iter().map(|s| format!("d_{}", s.name)).collect();
        let named = std::iter::once((self.input.as_str(), "the input"))
            .chain(self.parameters.iter().map(|p| (p.as_str(), "a parameter")))
            .chain(self.constants.iter().map(|(c, _)| (c.as_str(), "a constant")))
            .chain(self.states.iter().map(|s| (s.name.as_str(), "a state variable")))
            .chain(rates.iter().map(|r| (r.as_str(), "a state's rate")));
        for (name, what) in named {
            if let Some(before) = seen.insert(name, what) {
                bail!("{file}: [model] (kind = \"{kind}\"): '{name}' is both {before} and {what}; give them different names");
            }
        }
        Ok(())
    }

    /// This model with `candidate`'s terms added and its parameters joining θ.
    pub fn with_candidate(&self, file: &str, candidate: &CandidateTable) -> Result<Declared> {
        let mut d = self.add_terms(
            file,
            &format!("[[candidates]] {}", candidate.name),
            &candidate.observables,
            &candidate.rates,
        )?;
        d.vary(file, &format!("[[candidates]] {}", candidate.name), &candidate.vary)?;
        for (name, spec) in &candidate.parameters {
            spec.check(&format!("{file}: [[candidates]] {}: [candidates.parameters.{name}]", candidate.name))?;
            if d.parameters.contains(name) || d.constants.iter().any(|(c, _)| c == name) {
                bail!(
                    "{file}: [[candidates]] {}: parameter '{name}' is already a parameter or constant of the model",
                    candidate.name
                );
            }
            d.parameters.push(name.clone());
            d.declared_at.push(format!("[[candidates]] {}: [candidates.parameters.{name}]", candidate.name));
            d.bounds.push((spec.min, spec.max));
        }
        Ok(d)
    }

    /// This model with the true process's candidates on at fixed values and
    /// its out-of-library terms added.
    pub fn with_truth(&self, file: &str, truth: &TruthTable, library: &[CandidateTable]) -> Result<Declared> {
        let mut d = self.clone();
        for (name, values) in &truth.candidates {
            let c = library.iter().find(|c| &c.name == name).ok_or_else(|| {
                anyhow!("{file}: [truth.candidates] {name}: no candidate of that name in [[candidates]]")
            })?;
            d = d.add_terms(file, &format!("[truth.candidates] {name}"), &c.observables, &c.rates)?;
            for p in c.parameters.keys() {
                let v = values.get(p).ok_or_else(|| {
                    anyhow!("{file}: [truth.candidates] {name}: give the true value of its parameter '{p}'")
                })?;
                d.constants.push((p.clone(), *v));
            }
        }
        for (name, value) in &truth.constants {
            // A name already in the scope would shadow this value silently.
            if d.parameters.contains(name)
                || d.constants.iter().any(|(c, _)| c == name)
                || d.states.iter().any(|s| &s.name == name)
            {
                bail!("{file}: [truth.constants] {name}: the model already has a parameter, constant or state of that name");
            }
            d.constants.push((name.clone(), *value));
        }
        d.add_terms(file, "[truth]", &truth.observables, &truth.rates)
    }

    /// Each parameter of `vary` replaced, in every rate and observable, by
    /// its formula (which may use the parameter itself: `k*(1 + c*T)`).
    /// Initial values keep the parameter as declared: they hold at one time.
    fn vary(&mut self, file: &str, from: &str, vary: &BTreeMap<String, String>) -> Result<()> {
        for (name, by) in vary {
            if !self.parameters.contains(name) {
                bail!("{file}: {from}: vary.{name}: the model has no parameter '{name}' (vary replaces one of [parameters])");
            }
            let place = format!("{from}: vary.{name}");
            let replace = |w: &mut Written| {
                let text = crate::engine::formula::notation::rename(&w.text, name, by);
                if text != w.text {
                    *w = Written { text, place: format!("{} with {place}", w.place) };
                }
            };
            self.observables.iter_mut().for_each(|(_, w)| replace(w));
            self.states.iter_mut().for_each(|s| replace(&mut s.rate));
        }
        Ok(())
    }

    fn add_terms(
        &self,
        file: &str,
        from: &str,
        observables: &BTreeMap<String, String>,
        rates: &BTreeMap<String, String>,
    ) -> Result<Declared> {
        let mut d = self.clone();
        for (name, term) in observables {
            let (_, w) =
                d.observables.iter_mut().find(|(o, _)| o == name).ok_or_else(|| {
                    anyhow!("{file}: {from}: observables.{name}: the model has no observable '{name}'")
                })?;
            *w = w.plus(term, &format!("{from}: observables.{name}"));
        }
        if !rates.is_empty() && d.states.is_empty() {
            bail!("{file}: {from}: `rates` add to equations of motion, which only a model of kind = \"ode\" has");
        }
        for (name, term) in rates {
            let s = d
                .states
                .iter_mut()
                .find(|s| &s.name == name)
                .ok_or_else(|| anyhow!("{file}: {from}: rates.{name}: the model has no state variable '{name}'"))?;
            s.rate = s.rate.plus(term, &format!("{from}: rates.{name}"));
        }
        Ok(d)
    }
}

fn states(file: &str, table: &ModelTable) -> Result<Vec<State>> {
    if table.initial.is_empty() {
        bail!("{file}: [model] kind = \"ode\": declare the state variables' initial values in [model.initial] and their rates in [model.rates]");
    }
    if let Some(s) = table.rates.keys().find(|s| !table.initial.contains_key(*s)) {
        bail!("{file}: [model.rates] {s}: no initial value for '{s}' in [model.initial]");
    }
    table
        .initial
        .iter()
        .map(|(name, initial)| {
            let rate = table
                .rates
                .get(name)
                .ok_or_else(|| anyhow!("{file}: [model.initial] {name}: no rate for '{name}' in [model.rates]"))?;
            Ok(State {
                name: name.clone(),
                initial: Written { text: initial.clone(), place: format!("{file}: [model.initial] {name}") },
                rate: Written { text: rate.clone(), place: format!("{file}: [model.rates] {name}") },
                law_by_data: false,
            })
        })
        .collect()
}

fn check_solver(file: &str, s: &SolverSettings) -> Result<()> {
    let rtol_ok = s.rtol.is_none_or(|r| r > 0.0 && r < 1.0);
    let atol_ok = s.atol.is_none_or(|a| a > 0.0 && a.is_finite());
    if !(rtol_ok && atol_ok) {
        let shown = |v: Option<f64>| v.map_or("unset".to_string(), |v| v.to_string());
        bail!(
            "{file}: [model.solver]: rtol must be in (0, 1) and atol positive (got rtol = {}, atol = {})",
            shown(s.rtol),
            shown(s.atol)
        );
    }
    if s.max_steps == 0 {
        bail!("{file}: [model.solver] max_steps must be at least 1");
    }
    Ok(())
}

/// Every θ must appear in some formula: a parameter that none uses would
/// come back with its prior as its posterior, and is most likely a typo.
pub fn check_parameters_used(file: &str, d: &Declared, formulas: &[&crate::engine::formula::Formula]) -> Result<()> {
    for (i, (name, place)) in d.parameters.iter().zip(&d.declared_at).enumerate() {
        if !formulas.iter().any(|f| f.uses(1 + i)) {
            bail!("{file}: {place}: the model has no parameter '{name}': no formula uses it (remove it, or use it in a formula)");
        }
    }
    Ok(())
}

/// Corners of a box (all of them up to 10 dimensions, 1024 spread over
/// them beyond), then its centre: where a formula is checked to be finite.
pub fn corners(bounds: &[(f64, f64)]) -> Vec<Vec<f64>> {
    let d = bounds.len();
    let count: u64 = if d <= 10 { 1 << d } else { 1024 };
    let mut out: Vec<Vec<f64>> = (0..count)
        .map(|k| {
            // Beyond 10 dimensions, a multiplicative hash spreads the patterns.
            let bits = if d <= 10 { k } else { k.wrapping_mul(0x9E37_79B9_7F4A_7C15) };
            bounds.iter().enumerate().map(|(i, &(lo, hi))| if (bits >> (i % 64)) & 1 == 1 { hi } else { lo }).collect()
        })
        .collect();
    out.push(bounds.iter().map(|&(lo, hi)| 0.5 * (lo + hi)).collect());
    out
}

/// "g = 0, v0 = -2": a point of θ, for errors.
pub fn describe(names: &[String], theta: &[f64]) -> String {
    names.iter().zip(theta).map(|(n, v)| format!("{n} = {v}")).collect::<Vec<_>>().join(", ")
}

/// The most names a model's formulas may see at once (input, θ, constants,
/// states and rates): the size of the stack buffer they are evaluated from.
pub const MAX_NAMES: usize = 64;

/// Where each name sits in the value vector formulas are evaluated against:
/// `[input, θ…, constants…, states…, d_<state>…]`. Narrower scopes (initial
/// conditions see no state) are prefixes of it.
#[derive(Clone, Debug)]
pub struct Variables {
    pub n_theta: usize,
    pub state_at: usize,
    pub rate_at: usize,
    pub len: usize,
    /// Input, θ and constants filled in; the rest zero.
    template: [f64; MAX_NAMES],
    names: Vec<String>,
}

impl Variables {
    pub fn of(file: &str, d: &Declared) -> Result<Variables> {
        let mut names = vec![d.input.clone()];
        names.extend(d.parameters.iter().cloned());
        names.extend(d.constants.iter().map(|(c, _)| c.clone()));
        let state_at = names.len();
        names.extend(d.states.iter().map(|s| s.name.clone()));
        let rate_at = names.len();
        names.extend(d.states.iter().map(|s| format!("d_{}", s.name)));
        // PI, E, e, TAU and their Greek spellings are constants in every
        // formula; a variable of that name would be silently shadowed.
        if let Some(n) = names.iter().find(|n| crate::engine::formula::tape::Tape::constant(n).is_some()) {
            bail!("{file}: [model]: '{n}' is a mathematical constant in formulas (PI, π, E, e, TAU, τ); give the variable another name");
        }
        if names.len() > MAX_NAMES {
            bail!("{file}: [model]: {} names (input, parameters, constants, states and rates); at most {MAX_NAMES} are supported", names.len());
        }
        let mut template = [0.0; MAX_NAMES];
        for (k, (_, v)) in d.constants.iter().enumerate() {
            template[1 + d.parameters.len() + k] = *v;
        }
        Ok(Variables { n_theta: d.parameters.len(), state_at, rate_at, len: names.len(), template, names })
    }

    /// The names formulas of `upto` variables may use (a prefix of all).
    pub fn scope(&self, upto: usize) -> crate::engine::formula::Scope {
        crate::engine::formula::Scope::new(self.names[..upto].iter().cloned())
    }

    /// Sets θ and the constants of `v` in place, leaving its other slots as
    /// they are: for a vector reused across θs whose input, states and rates
    /// are written before every read (the copy of all of `at`'s 512 bytes
    /// showed as 4% of a profile of the ball drop's likelihood; removing it
    /// alone moved the rate by less than the machine's noise).
    #[inline]
    pub fn set_theta(&self, theta: &[f64], v: &mut [f64; MAX_NAMES]) {
        v[..self.state_at].copy_from_slice(&self.template[..self.state_at]);
        v[1..1 + self.n_theta].copy_from_slice(&theta[..self.n_theta]);
    }

    /// The value vector at θ, with the input and state still to be set.
    #[inline]
    pub fn at(&self, theta: &[f64]) -> [f64; MAX_NAMES] {
        let mut v = self.template;
        v[1..1 + self.n_theta].copy_from_slice(&theta[..self.n_theta]);
        v
    }
}
