//! How a model reaches the engine: a [`Simulator`] computes η(x, θ), and a
//! [`ModelFamily`] (registered by name in a [`Registry`]) reads a config's
//! `[model]` table once into a [`ModelSetup`]: the simulator, units and
//! candidate corrections for `diagnose` (and a `[truth]` table into the true
//! process of mock data).
//!
//! The engine calls only these traits; the families live in `crate::systems`.

pub mod fit;
pub mod observed;

use crate::base::config::{Config, ParamSpec};
use anyhow::{anyhow, bail, Result};
use std::collections::BTreeMap;
use std::sync::Arc;

pub use observed::{ObservedData, ObservedSeries};

/// A deterministic model `η(x, θ)` for a set of named observables.
///
/// `predict` writes into a caller buffer so that a likelihood evaluation does
/// not allocate.
pub trait Simulator: Send + Sync {
    /// Names of the calibration parameters θ, in order.
    fn parameter_names(&self) -> Vec<String>;
    /// Names of the observables this model predicts.
    fn observable_names(&self) -> Vec<String>;
    /// `η(x_i, θ)` for observable `observable` (an index into `observable_names`).
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]);

    /// Rejects measurement points the model cannot predict (an emulator knows only its bins).
    fn check_inputs(&self, _observable: usize, _x: &[f64]) -> anyhow::Result<()> {
        Ok(())
    }
    /// Tells the model one observable's measured values and errors before a
    /// fit, so that it computes no more precisely than they can tell apart
    /// (an ODE integrator's tolerance). Nothing by default.
    fn note_measurements(&self, _observable: usize, _values: &[f64], _errors: &[f64]) {}
    /// How the model computes where it chose from the data (a declared
    /// ODE's integrator tolerances), for the fit's record. None by default.
    fn numerics(&self) -> Option<String> {
        None
    }
    /// Whether `predict` works at any x (false for emulators: no prediction grid).
    fn predicts_any_x(&self) -> bool {
        true
    }
    /// Whether the model carries its own predictive covariance (emulators).
    fn has_model_covariance(&self) -> bool {
        false
    }
    /// How many times so far the model could not be computed at some θ (an
    /// ODE that failed to integrate): those θ got zero likelihood.
    fn failures(&self) -> u64 {
        0
    }
    /// Whether Σ ((y − η(θ))/σ)² over `data` is known to exceed `limit`
    /// sooner than by computing every prediction: a model that builds its
    /// predictions in order (an ODE integrated over the data's times) may
    /// stop once the points it has passed sum past the limit, and answer
    /// true. False means only "not known to exceed": `predict` then gives
    /// the predictions at θ as always. A sampler asks this where a θ that
    /// far from the data has no weight it could notice (`smc`'s floor).
    fn chi_square_exceeds(&self, _theta: &[f64], _data: &ObservedData, _limit: f64) -> bool {
        false
    }
    /// Adds `inv_scale2 ×` the model's predictive covariance at (x, θ) to the
    /// lower triangle of `lower` (column-major n × n).
    fn add_model_covariance(
        &self,
        _observable: usize,
        _x: &[f64],
        _theta: &[f64],
        _inv_scale2: f64,
        _lower: &mut [f64],
    ) {
    }
    /// Whether the model's covariance links different observables (an
    /// emulator's principal components are shared by all of its outputs).
    fn model_covariance_spans_observables(&self) -> bool {
        false
    }
    /// Adds the model's predictive covariance between every pair of `points`
    /// (observable index, x), the pair scaled by `inv_scales[i] × inv_scales[j]`,
    /// to the lower triangle of `lower` (column-major N × N, N = points.len()).
    /// Only called when `model_covariance_spans_observables`.
    fn add_joint_model_covariance(
        &self,
        _points: &[(usize, f64)],
        _inv_scales: &[f64],
        _theta: &[f64],
        _lower: &mut [f64],
    ) {
    }
    /// The covariance of `add_joint_model_covariance` in a form exact
    /// algebra can use (see [`LowRankModelCovariance`]); `None` when the
    /// model has no such form, and the likelihood factorizes it densely.
    /// `offsets`: block b holds points `offsets[b]..offsets[b + 1]`.
    fn joint_model_low_rank(&self, _points: &[(usize, f64)], _offsets: &[usize]) -> Option<LowRankModelCovariance> {
        None
    }
    /// The θ-dependent factors of `joint_model_low_rank` at `points`: the
    /// diagonal `g` (N, `inv_scales` included) and the weights `w` (K).
    fn joint_model_factors(
        &self,
        _points: &[(usize, f64)],
        _inv_scales: &[f64],
        _theta: &[f64],
        _g: &mut [f64],
        _w: &mut [f64],
    ) {
    }
}

/// A model's covariance across observables at N points as
/// `G(θ) [blockdiag(D_b) + F S(θ) Fᵀ] G(θ)`: `D_b` within each block of
/// points, `F` (N × p) fixed, `S` a small symmetric p × p matrix (not
/// necessarily positive) whose diagonal entries at `weighted` get the
/// θ-dependent weights `w(θ)`, and `G` diagonal; `G` and `w` come from
/// `Simulator::joint_model_factors`. An emulator's is so: its kept principal
/// components are the weighted columns, its truncation and the noise left in
/// its PCA are `D_b` and the rest of `F S Fᵀ`.
#[derive(Clone, Debug)]
pub struct LowRankModelCovariance {
    /// Per block (in the order of `offsets`), `D_b` (full, column-major).
    pub blocks: Vec<Vec<f64>>,
    /// `F`, column-major N × p.
    pub columns: Vec<f64>,
    /// `S` without the weights, column-major p × p.
    pub weights: Vec<f64>,
    /// The column of `F` each weight `w_k` belongs to.
    pub weighted: Vec<usize>,
}

impl LowRankModelCovariance {
    /// p, the number of columns of `F`.
    pub fn rank(&self) -> usize {
        (self.weights.len() as f64).sqrt().round() as usize
    }
}

/// Units of the discrepancy input x, of each observable and of each parameter,
/// for tables and plots. An empty string means "no unit known".
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Units {
    pub x: String,
    pub observables: BTreeMap<String, String>,
    pub parameters: BTreeMap<String, String>,
}

impl Units {
    pub fn observable(&self, name: &str) -> &str {
        self.observables.get(name).map(String::as_str).unwrap_or("")
    }

    pub fn parameter(&self, name: &str) -> &str {
        self.parameters.get(name).map(String::as_str).unwrap_or("")
    }

    /// These units, with what they leave empty taken from `other`.
    pub fn or(mut self, other: &Units) -> Units {
        if self.x.is_empty() {
            self.x = other.x.clone();
        }
        for (mine, theirs) in [(&mut self.observables, &other.observables), (&mut self.parameters, &other.parameters)] {
            for (k, v) in theirs {
                if mine.get(k).is_none_or(|u| u.is_empty()) && !v.is_empty() {
                    mine.insert(k.clone(), v.clone());
                }
            }
        }
        self
    }
}

/// One candidate correction as `diagnose` sees it: a model that adds named
/// physics (and possibly parameters) to the base model.
#[derive(Clone)]
pub struct CandidateModel {
    pub name: String,
    /// What physics the candidate adds, in a phrase.
    pub description: String,
    /// Parameters the candidate adds to θ, with their uniform priors.
    pub extra_parameters: Vec<(String, ParamSpec)>,
    pub simulator: Arc<dyn Simulator>,
    /// Other candidates this one is a special case of, on the data's domain.
    pub special_case_of: Vec<SpecialCase>,
    /// Whether the candidate is a variant emulator of its own, trained on
    /// runs with its physics on (to refine when a verdict rests on it); a
    /// correction of the output shares the model's emulator.
    pub own_emulator: bool,
}

/// This candidate is candidate `of` with its parameter `parameter` fixed
/// at `value`: `c*v*abs(v)` is `c*abs(v)^p` at p = 2 where v keeps one
/// sign. Where the data leave `value` inside that parameter's interval,
/// the two are one explanation and the simpler is named (Occam).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SpecialCase {
    pub of: String,
    pub parameter: String,
    pub value: f64,
}

/// What a family read from a config's `[model]` (or `[truth]`) table, once:
/// the simulator, its units and the candidate corrections `diagnose` weighs.
pub trait ModelSetup: Send + Sync {
    fn simulator(&self) -> Arc<dyn Simulator>;

    /// Units of x, of the observables and of the parameters.
    fn units(&self) -> Units {
        Units::default()
    }

    /// The candidate corrections `diagnose` weighs: the family's own library,
    /// or what the config declares in `[[candidates]]`.
    fn candidates(&self) -> Result<Vec<CandidateModel>> {
        Ok(Vec::new())
    }

    /// Terms built from the model's own symbols that `diagnose` may try when
    /// no candidate explains the data (declared models); None for a model
    /// with no formulas to extend.
    fn discoverer(&self) -> Option<&dyn Discoverer> {
        None
    }
}

/// The data a screening fits, one block per observable, and where the base
/// model's posterior lies.
pub struct ScreeningData<'a> {
    pub blocks: Vec<ScreeningBlock<'a>>,
    /// The base fit's posterior median of θ, in the simulator's order.
    pub theta: Vec<f64>,
    /// θ's prior box.
    pub bounds: Vec<(f64, f64)>,
}

pub struct ScreeningBlock<'a> {
    /// Index of the observable in the simulator's `observable_names`.
    pub model_index: usize,
    pub x: &'a [f64],
    pub y: &'a [f64],
    /// 1σ measurement errors.
    pub error: &'a [f64],
    /// Lower Cholesky factor (column-major n × n) of the measurements'
    /// covariance, errors² plus `[data] covariance` within the observable,
    /// when the data have one.
    pub covariance_factor: Option<Vec<f64>>,
}

/// Standardizes differences from the data of several blocks, all in a row,
/// each part by its own block (`ScreeningBlock::standardize`).
pub fn standardize_blocks(blocks: &[ScreeningBlock], d: &mut [f64], scale: f64) {
    let mut offset = 0;
    for b in blocks {
        b.standardize(&mut d[offset..offset + b.x.len()], scale);
        offset += b.x.len();
    }
}

impl ScreeningBlock<'_> {
    /// Standardizes differences from the data (`d`, divided by `scale`) in
    /// place, so that their squares sum to the χ² the measurements'
    /// covariance gives: `d / (scale σ)` point by point without a covariance,
    /// `L⁻¹ d / scale` with one (forward substitution).
    pub fn standardize(&self, d: &mut [f64], scale: f64) {
        let Some(l) = &self.covariance_factor else {
            for (v, e) in d.iter_mut().zip(self.error) {
                *v /= scale * e;
            }
            return;
        };
        let n = d.len();
        for k in 0..n {
            let z = d[k] / l[k * n + k];
            d[k] = z;
            for i in k + 1..n {
                d[i] -= l[k * n + i] * z;
            }
        }
        for v in d.iter_mut() {
            *v /= scale;
        }
    }
}

/// One term (or pair of terms) the screening found worth a full calibration.
#[derive(Clone)]
pub struct Proposal {
    pub candidate: CandidateModel,
    /// The term as a physicist would write it, and where it joins the model.
    pub formula: String,
    /// What the term is to a physicist, in a line.
    pub meaning: String,
    /// The `[[candidates]]` block that declares it.
    pub toml: String,
    /// χ² of the base model's best fit minus that of the model with the term.
    pub delta_chi2: f64,
    /// `delta_chi2` less the term's parameters times ln(number of data).
    pub delta_bic: f64,
    /// Prior log odds against the base model, paying for the search: the
    /// term's share of a prior over every term searched (or pair of them).
    pub prior_log_odds: f64,
    /// The screening's least-squares fit: θ and the term's parameters, by name.
    pub best_fit: Vec<(String, f64)>,
    /// The terms merged into this one because the data could not tell them
    /// apart (`discover::distinct`), each as it reads: one explanation,
    /// each reading named.
    pub readings: Vec<String>,
}

/// What a screening tried and what it proposes, best first.
pub struct Screening {
    /// Single terms the grammar made for this model.
    pub searched: usize,
    /// The grammar's forms, for "which forms were tried".
    pub forms: Vec<String>,
    pub proposals: Vec<Proposal>,
    /// What the search decided about the model itself, in words (a rate
    /// read as a law though it looks like a definition).
    pub notes: Vec<String>,
}

/// A grammar of terms and a cheap screening of them against the data.
pub trait Discoverer: Send + Sync {
    fn screen(&self, data: &ScreeningData) -> Result<Screening>;
}

/// A setup with nothing left to read: a simulator, its units and candidates.
#[derive(Clone)]
pub struct PlainSetup {
    pub simulator: Arc<dyn Simulator>,
    pub units: Units,
    pub candidates: Vec<CandidateModel>,
}

impl PlainSetup {
    pub fn shared(simulator: Arc<dyn Simulator>, units: Units) -> Arc<dyn ModelSetup> {
        Arc::new(PlainSetup { simulator, units, candidates: Vec::new() })
    }
}

impl ModelSetup for PlainSetup {
    fn simulator(&self) -> Arc<dyn Simulator> {
        self.simulator.clone()
    }
    fn units(&self) -> Units {
        self.units.clone()
    }
    fn candidates(&self) -> Result<Vec<CandidateModel>> {
        Ok(self.candidates.clone())
    }
}

/// A kind of model, named by `kind` in a config's `[model]` (and `[truth]`)
/// table. A family holds no state: it reads its table once into a
/// [`ModelSetup`], so one registered value serves every analysis.
pub trait ModelFamily: Send + Sync {
    /// The name configs use: `[model] kind = "<kind>"`.
    fn kind(&self) -> &'static str;

    /// The model to calibrate, from the config's `[model]` table. Its
    /// parameters must be the config's `[parameters]`.
    fn open(&self, config: &Config) -> Result<Arc<dyn ModelSetup>>;

    /// The process that made mock data, from a `[truth]` table of this kind: a
    /// simulator over the config's θ names, evaluated at their `truth` values.
    fn open_truth(&self, config: &Config, _truth: &toml::Table) -> Result<Arc<dyn ModelSetup>> {
        bail!(
            "{}: [truth]: model family '{}' has no true process to draw mock data from",
            config.path.display(),
            self.kind()
        )
    }
}

/// The model families a program knows, by name.
#[derive(Clone, Default)]
pub struct Registry {
    families: Vec<Arc<dyn ModelFamily>>,
}

impl Registry {
    pub fn new() -> Self {
        Registry::default()
    }

    /// Adds a family; a later family of the same kind replaces an earlier one.
    pub fn register(&mut self, family: Arc<dyn ModelFamily>) -> &mut Self {
        self.families.retain(|f| f.kind() != family.kind());
        self.families.push(family);
        self
    }

    pub fn kinds(&self) -> Vec<&'static str> {
        self.families.iter().map(|f| f.kind()).collect()
    }

    /// The family of `kind`; `table` names where the kind was given, for the error.
    pub fn get(&self, kind: &str, config: &Config, table: &str) -> Result<Arc<dyn ModelFamily>> {
        self.families.iter().find(|f| f.kind() == kind).cloned().ok_or_else(|| {
            anyhow!(
                "{}: [{table}] kind = {kind:?}: unknown model family (known: {})",
                config.path.display(),
                self.kinds().join(", ")
            )
        })
    }
}
