//! The one adapter from a config to what a calibration needs: an [`Analysis`]
//! holds resolved values (the model family and its simulator, θ priors,
//! kernel, sampler settings, units, the true process), built once.

use super::sampler::settings::SamplerConfig;
use crate::base::config::{BetweenObservables, Config, KernelInput, ParamSpec, PredictionConfig};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::{CandidateModel, ModelSetup, Registry, Simulator, Units};
use anyhow::{anyhow, bail, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What an analysis means beyond its text: the defaults a config without
/// the key gets. Stored results keyed on a config's text (a study's stages)
/// include it, so a change of a default re-runs them instead of reusing
/// results that meant something else.
pub const CONVENTIONS: &str = "discrepancy inputs x / max|x| per observable unless [discrepancy.inputs] gives them";

#[derive(Clone)]
pub struct Analysis {
    pub name: String,
    /// SHA-256 of the config file, for provenance.
    pub config_hash: String,
    /// SHA-256 of the config's tables a fit can depend on (`Config::fit_hash`):
    /// what a stored fit's key holds of the config.
    pub fit_config_hash: String,
    pub config_path: PathBuf,
    /// What the model's family read from `[model]`.
    pub setup: Arc<dyn ModelSetup>,
    pub simulator: Arc<dyn Simulator>,
    pub units: Units,
    /// The process that made the data, when the config names one (`[truth]`).
    pub truth: Option<Arc<dyn Simulator>>,
    /// θ with uniform priors (and true values, when known).
    pub parameters: BTreeMap<String, ParamSpec>,
    pub kernel: Option<DiscrepancyKernel>,
    /// Uniform prior bounds per discrepancy hyperparameter name.
    pub hyper_bounds: BTreeMap<String, [f64; 2]>,
    /// Per observable, the discrepancy kernel's input `(x + shift) / scale`.
    pub kernel_inputs: BTreeMap<String, KernelInput>,
    pub sampler: SamplerConfig,
    pub predictions: PredictionConfig,
    /// Measurements file.
    pub data: PathBuf,
    /// Covariance of those measurements beyond their errors (`[data] covariance`).
    pub covariance: Option<PathBuf>,
    /// Whether the likelihood carries correlations between observables (`[data] between_observables`).
    pub between_observables: BetweenObservables,
    /// How HEPData measurements are read (`[data.hepdata]`).
    pub hepdata: crate::base::hepdata::HepdataOptions,
    /// How far each systematic source is correlated (`[data] systematics`).
    pub systematics: BTreeMap<String, crate::base::systematics::Scope>,
    /// Observables to calibrate on; all of the model's by default.
    pub observables: Option<Vec<String>>,
}

impl Analysis {
    pub fn resolve(config: &Config, registry: &Registry) -> Result<Analysis> {
        let file = config.path.display();
        let setup = registry.get(config.model_kind()?, config, "model")?.open(config)?;
        let simulator = setup.simulator();
        let truth_setup = match &config.truth {
            Some(t) => Some(registry.get(config.kind_of(t, "truth")?, config, "truth")?.open_truth(config, t)?),
            None => None,
        };
        let truth = truth_setup.as_ref().map(|t| t.simulator());
        let config_units = Units {
            parameters: config.parameters.iter().map(|(n, p)| (n.clone(), p.units.clone())).collect(),
            ..Units::default()
        };
        let mut units = setup.units();
        if let Some(t) = &truth_setup {
            units = units.or(&t.units());
        }
        let kernel = DiscrepancyKernel::of(config.discrepancy.kernel);
        let observables = simulator.observable_names();
        if let Some(name) = config.discrepancy.inputs.keys().find(|n| !observables.contains(n)) {
            bail!(
                "{file}: [discrepancy.inputs.{name}]: the model has no observable '{name}' (it has: {})",
                observables.join(", ")
            );
        }
        let sampler: SamplerConfig = config.decode(&config.sampler, "sampler")?;
        sampler.validate().map_err(|e| anyhow!("{file}: [sampler]: {e}"))?;
        Ok(Analysis {
            name: config.name.clone(),
            config_hash: config.hash.clone(),
            fit_config_hash: config.fit_hash.clone(),
            config_path: config.path.clone(),
            setup,
            simulator,
            units: units.or(&config_units),
            truth,
            parameters: config.parameters.clone(),
            kernel,
            hyper_bounds: config.discrepancy.bounds.clone(),
            kernel_inputs: config.discrepancy.inputs.clone(),
            sampler,
            predictions: config.predictions.clone(),
            data: config.resolve(&config.data.measurements),
            covariance: config.data.covariance.as_ref().map(|c| config.resolve(c)),
            between_observables: config.data.between_observables,
            hepdata: config.data.hepdata.clone(),
            systematics: config.data.systematics.clone(),
            observables: config.data.observables.clone(),
        })
    }

    /// The family's candidate corrections (variant emulators are loaded
    /// only when `diagnose` asks).
    pub fn candidates(&self) -> Result<Vec<CandidateModel>> {
        self.setup.candidates()
    }

    /// This analysis with the base model replaced by a candidate's, whose own
    /// parameters join θ.
    pub fn with_candidate(&self, candidate: &CandidateModel) -> Analysis {
        let mut a = self.clone();
        a.simulator = candidate.simulator.clone();
        for (name, spec) in &candidate.extra_parameters {
            a.parameters.insert(name.clone(), spec.clone());
            a.units.parameters.entry(name.clone()).or_insert_with(|| spec.units.clone());
        }
        a
    }

    /// This analysis on another measurements file made by the same process
    /// (drawn with independent errors: the config's covariance is not theirs).
    pub fn with_data(&self, path: &Path) -> Analysis {
        Analysis { data: path.to_path_buf(), covariance: None, ..self.clone() }
    }

    /// The same analysis on other measurements with their own covariance
    /// beyond the errors (real data's, e.g. a jackknife over their events).
    pub fn with_data_and_covariance(&self, path: &Path, covariance: &Path) -> Analysis {
        Analysis { data: path.to_path_buf(), covariance: Some(covariance.to_path_buf()), ..self.clone() }
    }

    /// Bounds of a discrepancy hyperparameter.
    pub fn hyper_bounds(&self, hyper: &str) -> Result<[f64; 2]> {
        self.hyper_bounds.get(hyper).copied().ok_or_else(|| {
            anyhow!("{}: [discrepancy.bounds] has no bounds for hyperparameter '{hyper}'", self.config_path.display())
        })
    }

    /// θ's true values, where the config gives them.
    pub fn truth_values(&self) -> BTreeMap<String, f64> {
        self.parameters.iter().filter_map(|(k, v)| v.truth.map(|t| (k.clone(), t))).collect()
    }

    /// The true curve of `observable` at `xs`: the `[truth]` process at the
    /// parameters' true values, when all are known.
    pub fn truth_curve(&self, observable: &str, xs: &[f64]) -> Option<Vec<f64>> {
        let truth = self.truth.as_ref()?;
        let values = self.truth_values();
        let theta: Vec<f64> = truth.parameter_names().iter().map(|n| values.get(n).copied()).collect::<Option<_>>()?;
        let k = truth.observable_names().iter().position(|o| o == observable)?;
        let mut out = vec![0.0; xs.len()];
        truth.predict(k, xs, &theta, &mut out);
        Some(out)
    }
}
