//! A calibration problem built from an analysis and its data: the
//! observable blocks, the data's covariance attached to them, the
//! likelihood in its form, and the prior box.

use super::analysis::Analysis;
use super::likelihood::MdLikelihood;
use super::likelihood::{data_covariance, ObservableBlock};
use super::sampler::settings::SamplerKind;
use super::sampler::uniform_prior::UniformPrior;
use crate::base::artifacts::{self, Measurement, Provenance};
use crate::base::choices::Kernel;
use crate::base::config::KernelInput;
use crate::base::systematics::Scope;
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::Simulator;
use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Choices that override the config from the command line.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    pub data: Option<PathBuf>,
    /// The kernel, `Kernel::None` for the fit without MD; `None` keeps the config's.
    pub kernel: Option<Kernel>,
    pub observables: Option<Vec<String>>,
    pub sampler: Option<SamplerKind>,
}

/// A fully specified calibration: the analysis, its data, likelihood and prior.
pub struct Problem {
    /// The analysis as resolved from its config (without `truth` when
    /// `--data` replaced the data the truth describes).
    pub analysis: Analysis,
    pub data_path: PathBuf,
    pub measurements: Vec<Measurement>,
    pub simulator: Arc<dyn Simulator>,
    pub likelihood: MdLikelihood,
    pub prior: UniformPrior,
    pub sampler: SamplerKind,
}

/// The HEPData record `data_path` names, read as `[data.hepdata]` says
/// (bins without a value skipped, and said so); `None` for other formats.
fn hepdata_record(analysis: &Analysis, data_path: &Path) -> Result<Option<crate::base::hepdata::Record>> {
    if !crate::base::hepdata::is_hepdata(data_path) {
        return Ok(None);
    }
    if let Some(covariance) = &analysis.covariance {
        bail!(
            "{}: [data] covariance ({}) with HEPData measurements: their systematics already make the covariance; give one or the other",
            analysis.config_path.display(),
            covariance.display()
        );
    }
    let mut record = crate::base::hepdata::read(data_path, &analysis.hepdata)?;
    // A published record holds every class; the model predicts some of them.
    let predicted = analysis.simulator.observable_names();
    let mut unused: Vec<String> =
        record.points.iter().map(|p| p.observable.clone()).filter(|o| !predicted.contains(o)).collect();
    unused.dedup();
    if !unused.is_empty() {
        record.points.retain(|p| predicted.contains(&p.observable));
        crate::base::messages::note!(
            "note: {}: not predicted by the model, so not used: {} (name them in [data.hepdata] observables to use them)",
            data_path.display(),
            unused.join(", ")
        );
    }
    if record.points.is_empty() {
        bail!("{}: none of its dependent variables is an observable of the model", data_path.display());
    }
    let labels: Vec<&str> = record.points.iter().flat_map(|p| p.systematics.iter().map(|(l, _)| l.as_str())).collect();
    if let Some(unknown) = analysis.systematics.keys().find(|n| !labels.contains(&n.as_str())) {
        bail!("[data] systematics: {unknown:?} is not an error label of {}", data_path.display());
    }
    if !record.skipped.is_empty() {
        crate::base::messages::note!(
            "note: {}: {} bin(s) without a value (null or '-') skipped",
            data_path.display(),
            record.skipped.len()
        );
    }
    Ok(Some(record))
}

impl Problem {
    pub fn new(analysis: &Analysis, overrides: &Overrides) -> Result<Problem> {
        let simulator = analysis.simulator.clone();
        let data_path = overrides.data.clone().unwrap_or_else(|| analysis.data.clone());
        let hepdata = hepdata_record(analysis, &data_path)?;
        let (measurements, sources) = match &hepdata {
            Some(record) => (record.measurements(), Vec::new()),
            None => artifacts::read_measurements_with_sources(&data_path, &analysis.systematics)?,
        };
        let kernel = overrides.kernel.map_or(analysis.kernel, DiscrepancyKernel::of);
        check_observables_known(analysis, &simulator, &measurements, &data_path)?;
        let selected: Vec<String> = match (&overrides.observables, &analysis.observables) {
            (Some(o), _) | (None, Some(o)) => o.clone(),
            (None, None) => simulator
                .observable_names()
                .into_iter()
                .filter(|o| measurements.iter().any(|m| &m.observable == o))
                .collect(),
        };
        let mut blocks: Vec<ObservableBlock> = observable_blocks(&simulator, &selected, &measurements, &data_path)?
            .into_iter()
            .map(|b| {
                let input =
                    analysis.kernel_inputs.get(&b.name).copied().unwrap_or_else(|| KernelInput::scaled_to(&b.x));
                b.with_kernel_input(input)
            })
            .collect();
        let with_sources = sources.iter().any(|p| !p.systematics.is_empty());
        let across = match (&analysis.covariance, &overrides.data) {
            _ if hepdata.is_some() => {
                let entries = hepdata
                    .as_ref()
                    .map(|r| r.covariance(&analysis.hepdata, &analysis.systematics))
                    .unwrap_or_default();
                data_covariance::attach(&mut blocks, &entries, &measurements, &data_path, &data_path)?
            }
            (Some(path), None) if with_sources => bail!(
                "{}: [data] covariance ({}) with systematics as columns of {}: give one or the other",
                analysis.config_path.display(),
                path.display(),
                data_path.display()
            ),
            _ if with_sources => {
                let scope = |name: &str| analysis.systematics.get(name).copied().unwrap_or(Scope::Table);
                let entries = crate::base::systematics::covariance(&sources, scope);
                data_covariance::attach(&mut blocks, &entries, &measurements, &data_path, &data_path)?
            }
            (Some(path), None) => {
                let entries = data_covariance::read(path)
                    .with_context(|| format!("{}: [data] covariance", analysis.config_path.display()))?;
                data_covariance::attach(&mut blocks, &entries, &measurements, path, &data_path)?
            }
            (Some(path), Some(_)) => {
                crate::base::messages::note!("warning: --data replaces the config's measurements; the config's [data] covariance ({}) describes those and is not used", path.display());
                Vec::new()
            }
            (None, _) => Vec::new(),
        };
        if !across.is_empty() && analysis.between_observables == crate::base::config::BetweenObservables::Independent {
            crate::base::messages::note!("warning: {} covariance entries between observables are not used: [data] between_observables = \"independent\"", across.len());
        }
        let likelihood = MdLikelihood::linked(simulator.clone(), blocks, kernel, analysis.between_observables, &across);
        note_rounding_left(&likelihood, analysis.covariance.as_deref().unwrap_or(&data_path));
        let prior = prior_of(analysis, &likelihood)?;
        let sampler = overrides.sampler.unwrap_or(analysis.sampler.kind);
        let mut analysis = analysis.clone();
        if overrides.data.is_some() {
            // `[truth]` describes the config's own data file, not a --data replacement.
            analysis.truth = None;
        }
        Ok(Problem { analysis, data_path, measurements, simulator, likelihood, prior, sampler })
    }

    pub fn observables(&self) -> Vec<String> {
        self.likelihood.blocks.iter().map(|b| b.name.clone()).collect()
    }

    pub fn provenance(&self, seed: u64, command: &str) -> Provenance {
        Provenance::new(
            self.analysis.config_hash.clone(),
            artifacts::measurements_hash(&self.measurements),
            seed,
            command,
        )
    }
}

/// Every row must belong to an observable the model knows, so that a
/// misspelt name is an error, never silently dropped data.
fn check_observables_known(
    analysis: &Analysis,
    simulator: &Arc<dyn Simulator>,
    measurements: &[Measurement],
    data_path: &Path,
) -> Result<()> {
    let model_obs = simulator.observable_names();
    if let Some(m) = measurements.iter().find(|m| !model_obs.contains(&m.observable)) {
        let problem = format!(
            "unknown observable '{}' (model '{}' predicts: {})",
            m.observable,
            analysis.name,
            model_obs.join(", ")
        );
        return Err(m.field_error(data_path, "observable", problem));
    }
    Ok(())
}

/// One standardized block per selected observable, checked against the model.
fn observable_blocks(
    simulator: &Arc<dyn Simulator>,
    selected: &[String],
    measurements: &[Measurement],
    data_path: &Path,
) -> Result<Vec<ObservableBlock>> {
    if selected.is_empty() {
        bail!("no observables selected");
    }
    let model_obs = simulator.observable_names();
    let mut blocks = Vec::new();
    for name in selected {
        let idx = model_obs.iter().position(|o| o == name).ok_or_else(|| {
            anyhow!("unknown observable '{name}' requested (model predicts: {})", model_obs.join(", "))
        })?;
        let rows: Vec<&Measurement> = measurements.iter().filter(|m| &m.observable == name).collect();
        if rows.is_empty() {
            bail!("{}: no measurements of observable '{name}'", data_path.display());
        }
        let block = ObservableBlock::new(name, idx, &rows).with_context(|| data_path.display().to_string())?;
        simulator.check_inputs(idx, &block.x).with_context(|| data_path.display().to_string())?;
        simulator.note_measurements(idx, &block.y, &block.error);
        blocks.push(block);
    }
    Ok(blocks)
}

/// Uniform prior over θ (the analysis' bounds, in the model's order) and
/// each block's discrepancy hyperparameters.
fn prior_of(analysis: &Analysis, likelihood: &MdLikelihood) -> Result<UniformPrior> {
    let file = analysis.config_path.display();
    let theta_names = likelihood.simulator.parameter_names();
    let (mut lower, mut upper) = (Vec::new(), Vec::new());
    for name in &theta_names {
        let spec = analysis
            .parameters
            .get(name)
            .ok_or_else(|| anyhow!("{file}: [parameters] has no bounds for model parameter '{name}'"))?;
        lower.push(spec.min);
        upper.push(spec.max);
    }
    if let Some(name) = analysis.parameters.keys().find(|n| !theta_names.contains(n)) {
        bail!("{file}: [parameters.{name}]: the model has no parameter '{name}' (it has: {})", theta_names.join(", "));
    }
    if let Some(k) = likelihood.kernel {
        for _ in &likelihood.blocks {
            for h in k.hyper_names() {
                let b = analysis.hyper_bounds(h)?;
                lower.push(b[0]);
                upper.push(b[1]);
            }
        }
    }
    UniformPrior::new(likelihood.parameter_names(), lower, upper)
}

/// Identifies a calibration for its checkpoints: config, data, kernel,
/// observables, prior, sampler settings and seed.
pub fn checkpoint_key(problem: &Problem, seed: u64) -> String {
    key_of(problem, seed, &problem.analysis.config_hash)
}

/// As `checkpoint_key` without the seed, and with only the config's tables
/// a fit can depend on: what a stored fit of this problem is found by.
pub fn fit_key(problem: &Problem) -> String {
    key_of(problem, 0, &problem.analysis.fit_config_hash)
}

fn key_of(problem: &Problem, seed: u64, config_hash: &str) -> String {
    let material = format!(
        "{}|{}|{seed}|{}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}",
        config_hash,
        artifacts::measurements_hash(&problem.measurements),
        DiscrepancyKernel::label(problem.likelihood.kernel),
        problem.observables(),
        problem.prior.names,
        problem.prior.lower,
        problem.prior.upper,
        problem.analysis.sampler.smc,
        // The data's covariance beyond the errors, the joint form and the
        // discrepancy's inputs change the likelihood too.
        (
            problem
                .likelihood
                .blocks
                .iter()
                .map(|b| (b.input.shift.to_bits(), b.input.scale.to_bits()))
                .collect::<Vec<_>>(),
            problem
                .likelihood
                .blocks
                .iter()
                .map(|b| b.covariance.as_ref().map(|c| c.iter().map(|v| v.to_bits()).collect::<Vec<u64>>()))
                .collect::<Vec<_>>(),
            problem
                .likelihood
                .layout()
                .map(|j| (j.data.iter().map(|v| v.to_bits()).collect::<Vec<u64>>(), j.model_spans))
        )
    );
    artifacts::sha256_hex(material.as_bytes())
}

/// Says, once per covariance file in a process, how far the structured
/// split of a covariance written to few digits is from its numbers as
/// written, when that is a noticeable share of the smallest error²
/// (`Structure::rounding_share`).
fn note_rounding_left(likelihood: &MdLikelihood, data_path: &std::path::Path) {
    use crate::engine::calibrate::likelihood::structured::NOTED_ROUNDING_SHARE;
    static NOTED: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());
    let Some(structure) = likelihood.form.structure() else { return };
    if structure.rounding_share <= NOTED_ROUNDING_SHARE {
        return;
    }
    let Ok(mut noted) = NOTED.lock() else { return };
    if noted.iter().any(|p| p == data_path) {
        return;
    }
    noted.push(data_path.to_path_buf());
    crate::base::messages::note!(
        "note: {}: the covariance is written to too few digits for its size: its systematics were found to the precision printed, and the covariance used differs from the numbers as written by up to {:.0}% of the smallest error² (in the pattern of their rounding); more digits in the file would tell them apart",
        data_path.display(),
        100.0 * structure.rounding_share
    );
}
