//! `mdpipe train-emulator` / `validate-emulator`: PCA plus one GP per
//! principal component, the standard surrogate for expensive heavy-ion
//! simulators (Bernhard et al.; JETSCAPE).
//!
//! Pipeline for outputs `Y` (n design points × m outputs):
//! 1. per-observable transform (log for spectra), then standardize each output;
//! 2. PCA of the standardized matrix `Z = U S Vᵀ` by faer's thin SVD; the
//!    first K components are kept, with whitened scores `√n U_k`;
//! 3. one GP per kept component on inputs scaled to the unit cube, kernel
//!    `σ_f² corr_ARD + c + σ_n²`, hyperparameters maximizing the marginal
//!    likelihood (argmin L-BFGS, analytic gradient, parallel restarts).
//!
//! A prediction is a mean and a **full covariance in observable space**:
//! the GP variances mapped through the basis, plus the variance of the
//! dropped components (`Σ_{k>K} S_k²/n V_k V_kᵀ`), then mapped back through
//! the standardization and, for log outputs, to first order through `exp`.
//! The prediction is of the simulator's **mean** output, what measurements
//! are compared with: the run noise the training runs report (their `error`
//! column) is taken out of the white-noise term and of the dropped
//! components (`run_noise`); any scatter beyond it stays. Validation against
//! held-out runs, which carry their own noise, adds it back
//! ([`Emulator::predict_run`]). Without run errors the two are the same.

pub mod run_noise;

pub mod budget;
pub mod correction;
pub mod discover;
pub mod family;
pub mod forms;
pub mod labels;
pub mod latent;
pub mod low_rank;
pub mod model;
pub mod nugget;
pub mod panels;
pub mod shared;
pub mod store;
pub mod table;
pub mod train;
pub mod validate;

mod arith;
use arith::{add_lower_product, add_outer, dot, scale_to_unit};

use crate::engine::gp::{scaled_sq_dist, ArdHyper, ArdKernel, CholeskyWorkspace};
use anyhow::{bail, Result};
pub use family::EmulatorFamily;
pub use model::EmulatedModel;
pub use table::{check_against_design, read_training_table, OutputKey, TrainingTable};
pub use train::{train, EmulatorSettings, TrainingReport};

/// What training decides and a stored artifact holds; everything else is
/// derived by [`Emulator::from_parts`], so a reloaded emulator is bit-identical.
#[derive(Clone, Debug)]
pub struct EmulatorParts {
    pub parameter_names: Vec<String>,
    pub design_ids: Vec<i64>,
    /// Raw training inputs, row-major n × d.
    pub train_inputs: Vec<f64>,
    /// Raw training outputs, row-major n × m (kept for cross-validation).
    pub train_values: Vec<f64>,
    /// Each training value's statistical error from its own run, row-major
    /// n × m (0 where unknown): what separates run noise from the emulator's
    /// uncertainty about the simulator's mean.
    pub train_errors: Vec<f64>,
    /// Those errors' correlation between outputs (m × m; empty: independent).
    pub noise_correlation: Vec<f64>,
    /// Unit-cube scaling of the inputs: `u = (θ - lo) / (hi - lo)`.
    pub input_lo: Vec<f64>,
    pub input_hi: Vec<f64>,
    pub kernel: ArdKernel,
    pub outputs: Vec<OutputKey>,
    pub log_transform: Vec<bool>,
    pub output_mean: Vec<f64>,
    pub output_std: Vec<f64>,
    /// All singular values of Z (n ∧ m of them) and the matching right
    /// singular vectors, column-major m × (n ∧ m).
    pub singular_values: Vec<f64>,
    pub basis: Vec<f64>,
    pub n_components: usize,
    /// Whitened PCA scores, component-major K × n.
    pub scores: Vec<f64>,
    pub hypers: Vec<ArdHyper>,
}

/// One component's GP, ready to predict.
#[derive(Clone, Debug)]
struct FittedGp {
    alpha: Vec<f64>,
    /// `L⁻¹` in panels of four rows, for single predictions.
    linv: panels::InversePanels,
    /// The Cholesky factor `L` (column-major), for batched predictions.
    factor: Vec<f64>,
    signal_var: f64,
    constant: f64,
    noise_var: f64,
    inv_l2: Vec<f64>,
}

#[derive(Clone, Debug)]
pub struct Emulator {
    pub parts: EmulatorParts,
    unit_inputs: Vec<f64>,
    /// The same, column-major d × n: one input's values over the design
    /// side by side, for the vectorized cross kernel.
    unit_columns: Vec<f64>,
    gps: Vec<FittedGp>,
    /// `σ_k = S_k/√n`, the standard deviation of component k's scores.
    component_sd: Vec<f64>,
    /// Covariance of the dropped components in standardized space, run
    /// noise removed, m × m.
    truncation_cov: Vec<f64>,
    /// Per dropped component (index K.. of the basis), its part of
    /// `truncation_cov`: `(1 − removed_k) σ_k²` (`low_rank`).
    dropped_weights: Vec<f64>,
    /// Per kept component, the run-noise variance taken out of its GP's
    /// white-noise term (whitened units).
    run_noise: Vec<f64>,
    /// The run noise removed from every component, in standardized space
    /// (m × m): what a single held-out run adds to the prediction.
    run_noise_cov: Vec<f64>,
}

/// Mean and covariance (row-major m × m) in observable space.
#[derive(Clone, Debug)]
pub struct Prediction {
    pub mean: Vec<f64>,
    pub cov: Vec<f64>,
}

impl Prediction {
    pub fn sd(&self, j: usize) -> f64 {
        let m = self.mean.len();
        self.cov[j * m + j].max(0.0).sqrt()
    }
}

/// Scratch for allocation-free component predictions.
#[derive(Clone, Debug, Default)]
pub struct PredictScratch {
    unit: Vec<f64>,
    k: Vec<f64>,
}

impl Emulator {
    pub fn from_parts(parts: EmulatorParts) -> Result<Emulator> {
        let n = parts.design_ids.len();
        let d = parts.parameter_names.len();
        let m = parts.outputs.len();
        let r = parts.singular_values.len();
        if parts.basis.len() != m * r
            || parts.scores.len() != parts.n_components * n
            || parts.hypers.len() != parts.n_components
        {
            bail!(
                "emulator parts are inconsistent (basis {}, scores {}, hyperparameter sets {})",
                parts.basis.len(),
                parts.scores.len(),
                parts.hypers.len()
            );
        }
        let mut unit_inputs = vec![0.0; n * d];
        for i in 0..n {
            scale_to_unit(
                &parts.input_lo,
                &parts.input_hi,
                &parts.train_inputs[i * d..(i + 1) * d],
                &mut unit_inputs[i * d..(i + 1) * d],
            );
        }
        let mut gps = Vec::with_capacity(parts.n_components);
        for (k, hyper) in parts.hypers.iter().enumerate() {
            let y = &parts.scores[k * n..(k + 1) * n];
            let mut chol = CholeskyWorkspace::new(n);
            crate::engine::gp::ard_gram_lower(parts.kernel, hyper, &unit_inputs, n, &mut chol.factor);
            chol.factorize().map_err(|e| anyhow::anyhow!("component {k}: {e}"))?;
            let mut alpha = y.to_vec();
            chol.solve_in_place(&mut alpha);
            let linv = panels::InversePanels::new(&chol.lower_inverse(), n);
            let factor = chol.factor.clone();
            gps.push(FittedGp {
                alpha,
                linv,
                factor,
                signal_var: hyper.signal_var(),
                constant: hyper.constant(),
                noise_var: hyper.noise_var(),
                inv_l2: hyper.inv_sq_lengths(),
            });
        }
        let component_sd: Vec<f64> = parts.singular_values.iter().map(|s| s / (n as f64).sqrt()).collect();
        let kept_noise: Vec<f64> = gps.iter().map(|g| g.noise_var).collect();
        let removed = run_noise::removed_per_component(&parts, &component_sd, &kept_noise);
        let (mut truncation_cov, mut run_noise_cov) = (vec![0.0; m * m], vec![0.0; m * m]);
        let mut dropped_weights = Vec::with_capacity(r.saturating_sub(parts.n_components));
        for k in 0..r {
            let v2 = component_sd[k] * component_sd[k];
            let dropped = k >= parts.n_components;
            add_outer(&mut run_noise_cov, &parts.basis[k * m..(k + 1) * m], removed[k] * v2);
            if dropped {
                add_outer(&mut truncation_cov, &parts.basis[k * m..(k + 1) * m], (1.0 - removed[k]) * v2);
                dropped_weights.push((1.0 - removed[k]) * v2);
            }
        }
        // The PCA's mean and directions are themselves estimated from noisy runs.
        for (t, v) in truncation_cov.iter_mut().zip(run_noise::pca_noise_cov(&parts)) {
            *t += v;
        }
        let run_noise = removed[..parts.n_components].to_vec();
        let unit_columns =
            (0..d).flat_map(|p| (0..n).map(move |i| (p, i))).map(|(p, i)| unit_inputs[i * d + p]).collect();
        Ok(Emulator {
            parts,
            unit_inputs,
            unit_columns,
            gps,
            component_sd,
            truncation_cov,
            dropped_weights,
            run_noise,
            run_noise_cov,
        })
    }

    pub fn n_parameters(&self) -> usize {
        self.parts.parameter_names.len()
    }
    pub fn n_outputs(&self) -> usize {
        self.parts.outputs.len()
    }
    pub fn n_components(&self) -> usize {
        self.parts.n_components
    }
    pub fn outputs(&self) -> &[OutputKey] {
        &self.parts.outputs
    }

    pub fn scratch(&self) -> PredictScratch {
        PredictScratch { unit: vec![0.0; self.n_parameters()], k: vec![0.0; self.parts.design_ids.len()] }
    }

    /// Mean and variance of every kept component's (whitened) score at θ.
    pub fn predict_components(&self, theta: &[f64], means: &mut [f64], vars: &mut [f64], scratch: &mut PredictScratch) {
        let n = self.parts.design_ids.len();
        scale_to_unit(&self.parts.input_lo, &self.parts.input_hi, theta, &mut scratch.unit);
        for (c, gp) in self.gps.iter().enumerate() {
            self.cross_kernel_column(gp, &scratch.unit, &mut scratch.k[..n]);
            // The same sum, in the same order, as the batched path: αᵀk
            // cancels between large terms for a near-interpolating GP, so two
            // summation orders can differ by more than 1e-10 of the mean.
            means[c] = dot(&gp.alpha, &scratch.k[..n]);
            let quad = gp.linv.quadratic(&scratch.k[..n]);
            vars[c] = (gp.signal_var + gp.constant + gp.noise_var - quad).max(gp.noise_var) - self.run_noise[c];
        }
    }

    /// Component means and variances at many θ at once (row-major B × d in,
    /// B × K out). The variances' triangular solves become one matrix solve,
    /// which keeps bulk prediction fast for large designs.
    pub fn predict_components_batch(&self, thetas: &[f64], means: &mut [f64], vars: &mut [f64]) {
        let n = self.parts.design_ids.len();
        let kc = self.n_components();
        let unit = self.unit_rows(thetas);
        let b = unit.len() / self.n_parameters().max(1);
        let mut kstar = vec![0.0; n * b];
        for (c, gp) in self.gps.iter().enumerate() {
            self.cross_kernel(gp, &unit, &mut kstar, |q, mean| means[q * kc + c] = mean);
            let l = faer::MatRef::from_column_major_slice(&gp.factor, n, n);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                l,
                faer::MatMut::from_column_major_slice_mut(&mut kstar, n, b),
                faer::Par::Seq,
            );
            for q in 0..b {
                let w = &kstar[q * n..(q + 1) * n];
                vars[q * kc + c] =
                    (gp.signal_var + gp.constant + gp.noise_var - dot(w, w)).max(gp.noise_var) - self.run_noise[c];
            }
        }
    }

    /// θ rows (row-major B × d) scaled to the unit cube of the training inputs.
    fn unit_rows(&self, thetas: &[f64]) -> Vec<f64> {
        let d = self.n_parameters();
        let mut unit = vec![0.0; thetas.len()];
        for (u, t) in unit.chunks_mut(d).zip(thetas.chunks(d)) {
            scale_to_unit(&self.parts.input_lo, &self.parts.input_hi, t, u);
        }
        unit
    }

    /// `K(X, C)` of one component (signal and constant, no noise) for unit
    /// points C, column-major n × B into `kstar`, reporting each point's mean
    /// `αᵀ k` to `mean_at(q, mean)`.
    fn cross_kernel(&self, gp: &FittedGp, unit: &[f64], kstar: &mut [f64], mut mean_at: impl FnMut(usize, f64)) {
        let d = self.n_parameters();
        let n = self.parts.design_ids.len();
        for (q, u) in unit.chunks(d).enumerate() {
            let col = &mut kstar[q * n..(q + 1) * n];
            self.cross_kernel_column(gp, u, col);
            mean_at(q, dot(&gp.alpha, col));
        }
    }

    /// `k(X, u)` of one component (signal and constant, no noise) at one unit
    /// point into `col` (length n): the squared distances input by input
    /// over the inputs stored column by column (the order of
    /// `scaled_sq_dist`), then every correlation four at a time.
    fn cross_kernel_column(&self, gp: &FittedGp, u: &[f64], col: &mut [f64]) {
        let n = col.len();
        col.fill(0.0);
        for (p, (&up, &w)) in u.iter().zip(&gp.inv_l2).enumerate() {
            for (c, &x) in col.iter_mut().zip(&self.unit_columns[p * n..(p + 1) * n]) {
                let t = up - x;
                *c += t * t * w;
            }
        }
        self.parts.kernel.corr_in_place(col);
        for c in col.iter_mut() {
            *c = gp.signal_var * *c + gp.constant;
        }
    }

    /// Mean of the standardized, transformed outputs from component means.
    fn standardized_mean(&self, comp_mean: &[f64], j: usize) -> f64 {
        let m = self.n_outputs();
        comp_mean.iter().enumerate().map(|(k, mu)| mu * self.component_sd[k] * self.parts.basis[k * m + j]).sum()
    }

    /// Output j in observable units from its standardized, transformed value,
    /// and the derivative of that map (the delta-method Jacobian).
    fn to_observable(&self, j: usize, z: f64) -> (f64, f64) {
        let t = self.parts.output_mean[j] + self.parts.output_std[j] * z;
        if self.parts.log_transform[j] {
            let y = t.exp();
            (y, y * self.parts.output_std[j])
        } else {
            (t, self.parts.output_std[j])
        }
    }

    /// Mean of output `j` and its Jacobian factor, given component means.
    pub fn output_mean_from_components(&self, comp_mean: &[f64], j: usize) -> (f64, f64) {
        self.to_observable(j, self.standardized_mean(comp_mean, j))
    }

    /// Covariance of outputs `a` and `b` in observable units, given component
    /// variances and the two Jacobian factors.
    pub fn output_cov_from_components(&self, comp_var: &[f64], a: usize, b: usize, jac_a: f64, jac_b: f64) -> f64 {
        let m = self.n_outputs();
        let mut c = self.truncation_cov[a * m + b];
        for (k, v) in comp_var.iter().enumerate() {
            let s2 = self.component_sd[k] * self.component_sd[k];
            c += v * s2 * self.parts.basis[k * m + a] * self.parts.basis[k * m + b];
        }
        c * jac_a * jac_b
    }

    /// Adds `g_i g_j Cov(idx_i, idx_j)` (standardized, transformed units) to
    /// the lower triangle of `lower` (column-major n × n, n = idx.len()), for
    /// the outputs `idx` with per-point factors `g` (Jacobian × weight). The
    /// same sum as `output_cov_from_components` pair by pair, arranged as the
    /// gathered truncation covariance plus `Λ diag(w) Λᵀ`, Λ the kept
    /// components' loadings at the points. With an emulator across every
    /// observable this is a large part of a θ move.
    /// `loadings` is scratch of length at least 2 n K.
    pub fn add_points_covariance(
        &self,
        comp_var: &[f64],
        idx: &[usize],
        g: &[f64],
        lower: &mut [f64],
        loadings: &mut [f64],
    ) {
        let (n, m, kc) = (idx.len(), self.n_outputs(), comp_var.len());
        for j in 0..n {
            let row = &self.truncation_cov[idx[j] * m..(idx[j] + 1) * m];
            let col = &mut lower[j * n..(j + 1) * n];
            for i in j..n {
                col[i] += g[j] * g[i] * row[idx[i]];
            }
        }
        if n == 0 || kc == 0 {
            return;
        }
        let (plain, weighted) = loadings[..2 * n * kc].split_at_mut(n * kc);
        for (k, v) in comp_var.iter().enumerate() {
            let weight = v * self.component_sd[k] * self.component_sd[k];
            let basis = &self.parts.basis[k * m..(k + 1) * m];
            for i in 0..n {
                let l = basis[idx[i]] * g[i];
                plain[i + k * n] = l;
                weighted[i + k * n] = l * weight;
            }
        }
        add_lower_product(plain, weighted, n, kc, lower);
    }

    /// Full prediction of the simulator's mean at θ (allocates; for plots).
    pub fn predict(&self, theta: &[f64]) -> Prediction {
        self.predict_with(theta, false)
    }

    /// What one more run at θ would output: [`Emulator::predict`] plus the
    /// run noise the training runs reported (for validation on held-out runs).
    pub fn predict_run(&self, theta: &[f64]) -> Prediction {
        self.predict_with(theta, true)
    }

    fn predict_with(&self, theta: &[f64], with_run_noise: bool) -> Prediction {
        let (kc, m) = (self.n_components(), self.n_outputs());
        let mut scratch = self.scratch();
        let (mut cm, mut cv) = (vec![0.0; kc], vec![0.0; kc]);
        self.predict_components(theta, &mut cm, &mut cv, &mut scratch);
        let (mean, jac): (Vec<f64>, Vec<f64>) = (0..m).map(|j| self.output_mean_from_components(&cm, j)).unzip();
        let mut cov = vec![0.0; m * m];
        for a in 0..m {
            for b in 0..=a {
                let mut c = self.output_cov_from_components(&cv, a, b, jac[a], jac[b]);
                if with_run_noise {
                    c += self.run_noise_cov[a * m + b] * jac[a] * jac[b];
                }
                cov[a * m + b] = c;
                cov[b * m + a] = c;
            }
        }
        Prediction { mean, cov }
    }

    /// Mean in observable space and its Jacobian `∂mean_j/∂θ_p` (row-major m × d).
    pub fn mean_gradient(&self, theta: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let d = self.n_parameters();
        let n = self.parts.design_ids.len();
        let (kc, m) = (self.n_components(), self.n_outputs());
        let mut unit = vec![0.0; d];
        scale_to_unit(&self.parts.input_lo, &self.parts.input_hi, theta, &mut unit);
        let mut cm = vec![0.0; kc];
        let mut dcm = vec![0.0; kc * d];
        for (c, gp) in self.gps.iter().enumerate() {
            for i in 0..n {
                let xi = &self.unit_inputs[i * d..(i + 1) * d];
                let r2 = scaled_sq_dist(&unit, xi, &gp.inv_l2);
                let (corr, dcorr) = self.parts.kernel.corr_and_derivative(r2);
                cm[c] += gp.alpha[i] * (gp.signal_var * corr + gp.constant);
                for p in 0..d {
                    // ∂r²/∂u_p = 2 Δ_p / ℓ_p²; ∂u_p/∂θ_p = 1/(hi - lo).
                    let du = 2.0 * (unit[p] - xi[p]) * gp.inv_l2[p] / (self.parts.input_hi[p] - self.parts.input_lo[p]);
                    dcm[c * d + p] += gp.alpha[i] * gp.signal_var * dcorr * du;
                }
            }
        }
        let mut mean = vec![0.0; m];
        let mut jac = vec![0.0; m * d];
        for j in 0..m {
            let (y, dy_dz) = self.output_mean_from_components(&cm, j);
            mean[j] = y;
            for p in 0..d {
                let dz: f64 =
                    (0..kc).map(|c| dcm[c * d + p] * self.component_sd[c] * self.parts.basis[c * m + j]).sum();
                jac[j * d + p] = dy_dz * dz;
            }
        }
        (mean, jac)
    }

    /// Index of output (observable, x), matching x to 1e-9 relative.
    pub fn output_index(&self, observable: &str, x: f64) -> Option<usize> {
        self.parts.outputs.iter().position(|o| o.observable == observable && (o.x - x).abs() <= 1e-9 * x.abs().max(1.0))
    }

    /// The raw training data, as read.
    pub fn training_table(&self) -> TrainingTable {
        TrainingTable {
            path: std::path::PathBuf::from("<emulator training data>"),
            parameter_names: self.parts.parameter_names.clone(),
            design_ids: self.parts.design_ids.clone(),
            inputs: self.parts.train_inputs.clone(),
            outputs: self.parts.outputs.clone(),
            values: self.parts.train_values.clone(),
            errors: self.parts.train_errors.clone(),
            noise_correlation: (!self.parts.noise_correlation.is_empty()).then(|| self.parts.noise_correlation.clone()),
        }
    }

    /// Observables in output order, without repeats.
    pub fn observable_names(&self) -> Vec<String> {
        let mut names: Vec<String> = Vec::new();
        for o in &self.parts.outputs {
            if !names.contains(&o.observable) {
                names.push(o.observable.clone());
            }
        }
        names
    }
}

/// `mdpipe train-emulator`: reads the settings and the table, trains, stores.
/// With `design`, every design point must have runs in the table.
pub fn train_and_save(
    config: &std::path::Path,
    training: &std::path::Path,
    design: Option<&std::path::Path>,
    out: &std::path::Path,
    seed: u64,
) -> Result<(Emulator, TrainingReport)> {
    use anyhow::Context;
    let settings = EmulatorSettings::load(config)?;
    let config_hash = crate::base::artifacts::sha256_hex(
        &std::fs::read(config).with_context(|| format!("reading {}", config.display()))?,
    );
    let command = format!("train-emulator {} --training {}", config.display(), training.display());
    train_with_settings(&settings, &config_hash, &command, training, design, out, seed)
}

/// Trains on the table at `training` with explicit settings and stores the
/// emulator, with `config_hash` and `command` as its provenance.
pub fn train_with_settings(
    settings: &EmulatorSettings,
    config_hash: &str,
    command: &str,
    training: &std::path::Path,
    design: Option<&std::path::Path>,
    out: &std::path::Path,
    seed: u64,
) -> Result<(Emulator, TrainingReport)> {
    use anyhow::Context;
    let data_hash = crate::base::artifacts::sha256_hex(
        &std::fs::read(training).with_context(|| format!("reading {}", training.display()))?,
    );
    let table = table::read_training_table_selected(training, &settings.parameters, &settings.observables)?;
    if let Some(design) = design {
        check_against_design(&table, design)?;
    }
    let (emu, report) = train(&table, settings, seed)?;
    let prov = crate::base::artifacts::Provenance::new(config_hash.to_string(), data_hash, seed, command);
    store::save(out, &emu, settings, &report, &prov)?;
    Ok((emu, report))
}
