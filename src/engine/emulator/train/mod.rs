//! Training: transform, standardize, PCA by SVD, then one GP per component
//! with hyperparameters from L-BFGS (argmin) over several parallel restarts.

use super::nugget::ExcessScatterTest;
use super::{Emulator, EmulatorParts, TrainingTable};
use crate::engine::gp::{ard_log_marginal_likelihood, ArdHyper, ArdKernel};
use anyhow::{anyhow, bail, Context, Result};
use argmin::core::{CostFunction, Executor, Gradient, State, TerminationReason};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::cell::RefCell;
use std::path::Path;

mod optimize;

use optimize::*;

/// The `[emulator]` table of a pipeline config.
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct EmulatorSettings {
    /// Design parameters, in the order θ is passed to the emulator.
    pub parameters: Vec<String>,
    /// "matern52" (default) or "se".
    #[serde(default = "default_kernel")]
    pub kernel: String,
    /// Number of principal components; if absent, the fewest explaining
    /// `variance_fraction` of the standardized variance.
    pub components: Option<usize>,
    #[serde(default = "default_fraction")]
    pub variance_fraction: f64,
    /// Optimizer starts per component (the first from a fixed default).
    #[serde(default = "default_restarts")]
    pub restarts: usize,
    #[serde(default = "default_iters")]
    pub max_iters: u64,
    /// Observables emulated in log space (spectra).
    #[serde(default)]
    pub log_observables: Vec<String>,
    /// Observables to emulate (default: every observable in the training table).
    #[serde(default)]
    pub observables: Vec<String>,
}

fn default_kernel() -> String {
    "matern52".into()
}
fn default_fraction() -> f64 {
    0.99
}
fn default_restarts() -> usize {
    8
}
fn default_iters() -> u64 {
    200
}

impl EmulatorSettings {
    /// Reads the `[emulator]` table of a TOML file, ignoring other tables.
    pub fn load(path: &Path) -> Result<EmulatorSettings> {
        #[derive(serde::Deserialize)]
        struct File {
            emulator: Option<EmulatorSettings>,
        }
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let file: File = toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        let s = file.emulator.ok_or_else(|| anyhow!("{}: no [emulator] table", path.display()))?;
        s.kernel().with_context(|| path.display().to_string())?;
        if s.parameters.is_empty() {
            bail!("{}: [emulator] parameters is empty", path.display());
        }
        if !(s.variance_fraction > 0.0 && s.variance_fraction <= 1.0) {
            bail!("{}: [emulator] variance_fraction must be in (0, 1], got {}", path.display(), s.variance_fraction);
        }
        if s.restarts == 0 {
            bail!("{}: [emulator] restarts must be at least 1", path.display());
        }
        Ok(s)
    }

    pub fn kernel(&self) -> Result<ArdKernel> {
        ArdKernel::parse(&self.kernel)
            .ok_or_else(|| anyhow!("[emulator] kernel: unknown kernel {:?} (use matern52 or se)", self.kernel))
    }
}

/// Search box for the log-hyperparameters (inputs are on the unit cube and
/// component scores have unit variance, so one box fits every problem).
/// The same bounds are used by `bench/emulator_vs_sklearn.py`.
pub const SIGNAL_VAR_BOUNDS: (f64, f64) = (1e-4, 1e4);
pub const LENGTH_BOUNDS: (f64, f64) = (1e-2, 1e3);
pub const CONSTANT_BOUNDS: (f64, f64) = (1e-6, 1e4);
pub const NOISE_BOUNDS: (f64, f64) = (1e-8, 1e1);
/// The first optimizer start: σ_f² = 1, ℓ = 0.5, c = 0.1, σ_n² = 1e-3.
pub const DEFAULT_START: (f64, f64, f64, f64) = (1.0, 0.5, 0.1, 1e-3);

/// How one optimizer start ended.
#[derive(Clone, Debug, serde::Serialize)]
pub struct OptimizerRun {
    pub component: usize,
    pub restart: usize,
    pub log_marginal_likelihood: f64,
    pub iterations: u64,
    /// Marginal-likelihood evaluations (each with its gradient).
    pub evaluations: u64,
    /// "converged", "max_iters", or the failure.
    pub outcome: String,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct TrainingReport {
    pub n_points: usize,
    pub n_outputs: usize,
    pub n_components: usize,
    /// Fraction of the standardized variance each kept component explains.
    pub explained_variance: Vec<f64>,
    pub kernel: ArdKernel,
    pub restarts: usize,
    pub runs: Vec<OptimizerRun>,
    pub failures: usize,
    /// Best log marginal likelihood per component.
    pub log_marginal_likelihood: Vec<f64>,
    /// Per kept component whose fitted white noise exceeds its runs'
    /// reported noise: whether the runs show that excess ([`super::nugget`]).
    pub excess_scatter: Vec<ExcessScatterTest>,
    pub training_seconds: f64,
}

/// Tests each kept component's white noise against what its runs report
/// ([`super::nugget`]) and gives a component whose excess the runs do not
/// show its fit with the noise held at the reported level.
fn drop_unsupported_excess(
    kernel: ArdKernel,
    unit: &[f64],
    parts: &mut EmulatorParts,
    free_lml: &mut [f64],
    max_iters: u64,
) -> Vec<ExcessScatterTest> {
    let n = parts.design_ids.len();
    let kept = parts.n_components;
    let component_sd: Vec<f64> = parts.singular_values.iter().map(|s| s / (n as f64).sqrt()).collect();
    let reported = super::run_noise::removed_per_component(parts, &component_sd, &vec![f64::INFINITY; kept]);
    let jobs: Vec<usize> =
        (0..kept).filter(|&k| super::nugget::has_excess(parts.hypers[k].noise_var(), reported[k])).collect();
    let null_fits: Vec<(usize, Result<Optimum>)> = jobs
        .par_iter()
        .map(|&k| {
            let mut start = parts.hypers[k].log_params.clone();
            start.pop();
            let log_noise = reported[k].max(NOISE_BOUNDS.0).ln();
            (k, optimize_fixed_noise(kernel, unit, &parts.scores[k * n..(k + 1) * n], start, log_noise, max_iters))
        })
        .collect();
    let mut tested: Vec<(ExcessScatterTest, Vec<f64>, f64)> = Vec::new();
    for (k, fit) in null_fits {
        // A null fit that fails leaves the free fit, and its excess, in place.
        let Ok(null) = fit.map_err(|e| {
            crate::base::messages::note!(
                "warning: component {k}: the fit with the reported run noise failed ({e}); its fitted excess is kept"
            )
        }) else {
            continue;
        };
        let test = ExcessScatterTest::new(
            k,
            parts.hypers[k].noise_var(),
            reported[k],
            free_lml[k],
            null.log_marginal_likelihood,
        );
        tested.push((test, null.log_params, null.log_marginal_likelihood));
    }
    let mut tests: Vec<ExcessScatterTest> = tested.iter().map(|t| t.0.clone()).collect();
    super::nugget::decide_by_holm(&mut tests);
    for (test, (_, null_params, null_lml)) in tests.iter().zip(tested) {
        if !test.excess_kept {
            parts.hypers[test.component] = ArdHyper { log_params: null_params };
            free_lml[test.component] = null_lml;
        }
    }
    tests
}

/// The design's input box; every parameter must vary over it.
fn input_box(table: &TrainingTable) -> Result<(Vec<f64>, Vec<f64>)> {
    let d = table.parameter_names.len();
    let mut lo = vec![f64::INFINITY; d];
    let mut hi = vec![f64::NEG_INFINITY; d];
    for i in 0..table.n_points() {
        for (p, &v) in table.input(i).iter().enumerate() {
            lo[p] = lo[p].min(v);
            hi[p] = hi[p].max(v);
        }
    }
    for p in 0..d {
        if lo[p] >= hi[p] {
            bail!(
                "{}: parameter '{}' is constant ({}) over the design; drop it from [emulator] parameters",
                table.path.display(),
                table.parameter_names[p],
                lo[p]
            );
        }
    }
    Ok((lo, hi))
}

/// Outputs transformed (log for `log_observables`) and standardized per
/// output: row-major `n × m`, with each output's transform, mean and sd.
struct Standardized {
    z: Vec<f64>,
    log_transform: Vec<bool>,
    mean: Vec<f64>,
    std: Vec<f64>,
}

fn standardize(table: &TrainingTable, settings: &EmulatorSettings) -> Result<Standardized> {
    let file = table.path.display();
    let (n, m) = (table.n_points(), table.n_outputs());
    let mut log_transform: Vec<bool> =
        table.outputs.iter().map(|o| settings.log_observables.contains(&o.observable)).collect();
    let mut z = vec![0.0; n * m];
    let (mut mean, mut std) = (vec![0.0; m], vec![0.0; m]);
    for j in 0..m {
        let first = table.values[j];
        if (0..n).all(|i| table.values[i * m + j] == first) {
            // Constant over the design (an observable at x = 0, say): emulated
            // exactly, as that value with no uncertainty (std 0, z 0, untransformed).
            log_transform[j] = false;
            mean[j] = first;
            continue;
        }
        for i in 0..n {
            let v = table.values[i * m + j];
            z[i * m + j] = if log_transform[j] {
                if v <= 0.0 {
                    bail!(
                        "{file}: design point {}, output {}: value {v} is not positive, but '{}' is in log_observables",
                        table.design_ids[i],
                        table.outputs[j],
                        table.outputs[j].observable
                    );
                }
                v.ln()
            } else {
                v
            };
        }
        mean[j] = (0..n).map(|i| z[i * m + j]).sum::<f64>() / n as f64;
        std[j] = ((0..n).map(|i| (z[i * m + j] - mean[j]).powi(2)).sum::<f64>() / n as f64).sqrt();
        if !(std[j] > 1e-12 * mean[j].abs().max(1e-300)) {
            bail!("{file}: output {} varies over the design only by rounding ({} ± {:e}); make it exactly constant or remove it", table.outputs[j], mean[j], std[j]);
        }
        for i in 0..n {
            z[i * m + j] = (z[i * m + j] - mean[j]) / std[j];
        }
    }
    if std.iter().all(|&s| s == 0.0) {
        bail!("{file}: every output is constant over the design; there is nothing to emulate");
    }
    Ok(Standardized { z, log_transform, mean, std })
}

/// Principal components of the standardized outputs (thin SVD).
struct Pca {
    singular_values: Vec<f64>,
    /// Every component's loadings, `component × output`.
    basis: Vec<f64>,
    n_components: usize,
    /// Whitened scores √n U_k of the kept components, `component × point`.
    scores: Vec<f64>,
    total_variance: f64,
}

fn pca(z: &[f64], n: usize, m: usize, settings: &EmulatorSettings) -> Result<Pca> {
    let zmat = faer::Mat::<f64>::from_fn(n, m, |i, j| z[i * m + j]);
    let svd = zmat.thin_svd().map_err(|e| anyhow!("SVD of the standardized outputs failed: {e:?}"))?;
    let r = n.min(m);
    let sv: Vec<f64> = (0..r).map(|k| svd.S().column_vector()[k]).collect();
    let total: f64 = sv.iter().map(|s| s * s).sum();
    let n_components = match settings.components {
        Some(k) => {
            if k == 0 || k > r {
                bail!(
                    "[emulator] components = {k}, but at most {r} are possible with {n} design points and {m} outputs"
                );
            }
            if k >= n {
                bail!("[emulator] components = {k} must be fewer than the {n} design points");
            }
            k
        }
        None => {
            let mut acc = 0.0;
            let mut k = 0;
            while k < r && acc / total < settings.variance_fraction {
                acc += sv[k] * sv[k];
                k += 1;
            }
            k.min(n - 1).max(1)
        }
    };
    let mut basis = vec![0.0; m * r];
    for k in 0..r {
        for j in 0..m {
            basis[k * m + j] = svd.V()[(j, k)];
        }
    }
    // Unit variance by construction.
    let mut scores = vec![0.0; n_components * n];
    for k in 0..n_components {
        for i in 0..n {
            scores[k * n + i] = svd.U()[(i, k)] * (n as f64).sqrt();
        }
    }
    Ok(Pca { singular_values: sv, basis, n_components, scores, total_variance: total })
}

/// Each component's GP hyperparameters: the best of `restarts` optimizer
/// runs (the first from a fixed default start), with every run's record.
struct Fitted {
    hypers: Vec<ArdHyper>,
    log_marginal_likelihood: Vec<f64>,
    runs: Vec<OptimizerRun>,
    failures: usize,
}

fn fit_components(
    kernel: ArdKernel,
    unit: &[f64],
    pca: &Pca,
    n: usize,
    settings: &EmulatorSettings,
    seed: u64,
) -> Result<Fitted> {
    let d = unit.len() / n;
    // Every (component, restart) is independent work.
    let jobs: Vec<(usize, usize)> =
        (0..pca.n_components).flat_map(|k| (0..settings.restarts).map(move |r| (k, r))).collect();
    let bar = crate::base::progress::bar(jobs.len() as u64, "training GP emulators");
    let results: Vec<(usize, usize, Result<Optimum>)> = jobs
        .par_iter()
        .map(|&(k, restart)| {
            let start = if restart == 0 {
                default_start(d)
            } else {
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ ((k as u64) << 32) ^ restart as u64);
                random_start(d, &mut rng)
            };
            let out = optimize(kernel, unit, &pca.scores[k * n..(k + 1) * n], start, settings.max_iters);
            bar.inc(1);
            (k, restart, out)
        })
        .collect();
    bar.finish_and_clear();

    let mut runs = Vec::new();
    let mut best: Vec<Option<(f64, Vec<f64>)>> = vec![None; pca.n_components];
    let mut failures = 0;
    for (k, restart, out) in results {
        match out {
            Ok(o) if o.log_marginal_likelihood.is_finite() && !o.outcome.starts_with("exit") => {
                let lml = o.log_marginal_likelihood;
                if best[k].as_ref().is_none_or(|(b, _)| lml > *b) {
                    best[k] = Some((lml, o.log_params));
                }
                runs.push(OptimizerRun {
                    component: k,
                    restart,
                    log_marginal_likelihood: lml,
                    iterations: o.iterations,
                    evaluations: o.evaluations,
                    outcome: o.outcome,
                });
            }
            Ok(o) => {
                failures += 1;
                let outcome = format!("failed: {} (log L {})", o.outcome, o.log_marginal_likelihood);
                runs.push(OptimizerRun {
                    component: k,
                    restart,
                    log_marginal_likelihood: f64::NAN,
                    iterations: o.iterations,
                    evaluations: o.evaluations,
                    outcome,
                });
            }
            Err(e) => {
                failures += 1;
                runs.push(OptimizerRun {
                    component: k,
                    restart,
                    log_marginal_likelihood: f64::NAN,
                    iterations: 0,
                    evaluations: 0,
                    outcome: format!("failed: {e}"),
                });
            }
        }
    }
    if failures > 0 {
        crate::base::messages::note!("warning: {failures} of {} optimizer runs failed (see the emulator report); the best successful run is used per component", runs.len());
    }
    let mut hypers = Vec::with_capacity(pca.n_components);
    let mut lmls = Vec::with_capacity(pca.n_components);
    for (k, b) in best.into_iter().enumerate() {
        let (lml, p) = b.ok_or_else(|| anyhow!("every optimizer run failed for principal component {k}"))?;
        hypers.push(ArdHyper { log_params: p });
        lmls.push(lml);
    }
    Ok(Fitted { hypers, log_marginal_likelihood: lmls, runs, failures })
}

/// Trains the emulator. Deterministic for a given seed (restarts run in
/// parallel but each has its own seeded start).
pub fn train(table: &TrainingTable, settings: &EmulatorSettings, seed: u64) -> Result<(Emulator, TrainingReport)> {
    let started = std::time::Instant::now();
    let kernel = settings.kernel()?;
    let (n, m, d) = (table.n_points(), table.n_outputs(), table.parameter_names.len());
    if n < 3 {
        bail!("{}: {n} design point(s); an emulator needs at least 3", table.path.display());
    }
    let (lo, hi) = input_box(table)?;
    let st = standardize(table, settings)?;
    let pca = pca(&st.z, n, m, settings)?;
    let mut unit = vec![0.0; n * d];
    for i in 0..n {
        for p in 0..d {
            unit[i * d + p] = (table.input(i)[p] - lo[p]) / (hi[p] - lo[p]);
        }
    }
    let mut fitted = fit_components(kernel, &unit, &pca, n, settings, seed)?;
    let n_components = pca.n_components;
    let explained_variance = pca.singular_values[..n_components].iter().map(|s| s * s / pca.total_variance).collect();
    let mut parts = EmulatorParts {
        parameter_names: table.parameter_names.clone(),
        design_ids: table.design_ids.clone(),
        train_inputs: table.inputs.clone(),
        train_values: table.values.clone(),
        train_errors: table.errors.clone(),
        noise_correlation: table.noise_correlation.clone().unwrap_or_default(),
        input_lo: lo,
        input_hi: hi,
        kernel,
        outputs: table.outputs.clone(),
        log_transform: st.log_transform,
        output_mean: st.mean,
        output_std: st.std,
        singular_values: pca.singular_values,
        basis: pca.basis,
        n_components,
        scores: pca.scores,
        hypers: fitted.hypers,
    };
    let excess_scatter =
        drop_unsupported_excess(kernel, &unit, &mut parts, &mut fitted.log_marginal_likelihood, settings.max_iters);
    let report = TrainingReport {
        n_points: n,
        n_outputs: m,
        n_components,
        explained_variance,
        kernel,
        restarts: settings.restarts,
        runs: fitted.runs,
        failures: fitted.failures,
        log_marginal_likelihood: fitted.log_marginal_likelihood,
        excess_scatter,
        training_seconds: 0.0,
    };
    let emulator = Emulator::from_parts(parts)?;
    Ok((emulator, TrainingReport { training_seconds: started.elapsed().as_secs_f64(), ..report }))
}
