//! The Kennedy–O'Hagan likelihood with one independent block per observable:
//!
//! `y_b - η_b(x, θ) ~ N(0, K_φb(x, x) + diag(σ_b²) [+ C_emu,b(θ)])`, "no MD"
//! being `K = 0`. `C_emu,b` is an emulator's predictive covariance restricted
//! to block b (covariance between observables is not used, as the blocks are
//! independent).
//!
//! Scaling follows the paper: each observable is standardized by the mean and
//! population standard deviation of its measured values (so the discrepancy
//! hyperparameters are comparable across observables), while x is used as is
//! (x = t/1 s, or pT/1 GeV). The returned log-likelihood includes the Jacobian
//! of that standardization, so it is the density of the data in their own
//! units and evidences are comparable with any other analysis of the same data.

use crate::base::artifacts::Measurement;
use crate::base::config::KernelInput;
use crate::engine::gp::{gaussian_logpdf_factored, CholeskyWorkspace, DiscrepancyGram, DiscrepancyKernel};
use crate::engine::model::Simulator;
use anyhow::{bail, Result};
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Measurements of one observable, standardized.
#[derive(Clone, Debug)]
pub struct ObservableBlock {
    pub name: String,
    /// Index of this observable in the simulator's `observable_names`.
    pub model_index: usize,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub error: Vec<f64>,
    /// Standardization: `y_std = (y - mean) / scale`.
    pub mean: f64,
    pub scale: f64,
    /// How x becomes the discrepancy kernel's input, and those inputs.
    pub input: KernelInput,
    pub kernel_x: Vec<f64>,
    pub gram: DiscrepancyGram,
    /// Covariance of the measurements beyond their errors (column-major
    /// n × n, data units, in the block's x order), from `[data] covariance`.
    pub covariance: Option<Vec<f64>>,
}

impl ObservableBlock {
    pub fn new(name: &str, model_index: usize, rows: &[&Measurement]) -> Result<Self> {
        if rows.len() < 2 {
            bail!("observable '{name}' has {} measurement(s); at least 2 are needed to standardize it", rows.len());
        }
        let mut rows: Vec<&Measurement> = rows.to_vec();
        rows.sort_by(|a, b| a.x.total_cmp(&b.x));
        let y: Vec<f64> = rows.iter().map(|m| m.value).collect();
        let mean = y.iter().sum::<f64>() / y.len() as f64;
        let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / y.len() as f64;
        // A constant observable (e.g. acceleration in a drag-free world) has no
        // spread; fall back to the typical error so the scale stays meaningful.
        let mean_err = rows.iter().map(|m| m.error).sum::<f64>() / rows.len() as f64;
        let scale = if var.sqrt() > 1e-12 * mean.abs().max(1.0) { var.sqrt() } else { mean_err };
        let x: Vec<f64> = rows.iter().map(|m| m.x).collect();
        Ok(ObservableBlock {
            name: name.to_string(),
            model_index,
            input: KernelInput::default(),
            kernel_x: x.clone(),
            gram: DiscrepancyGram::new(&x),
            x,
            y,
            error: rows.iter().map(|m| m.error).collect(),
            mean,
            scale,
            covariance: None,
        })
    }

    /// Adds `scale2 ×` the data's covariance (errors² and any covariance
    /// beyond them) to the lower triangle of `lower` (column-major n × n).
    pub fn add_data_covariance(&self, scale2: f64, lower: &mut [f64]) {
        let n = self.len();
        for i in 0..n {
            lower[i * n + i] += scale2 * self.error[i] * self.error[i];
        }
        if let Some(c) = &self.covariance {
            for j in 0..n {
                for i in j..n {
                    lower[j * n + i] += scale2 * c[j * n + i];
                }
            }
        }
    }

    /// Whether the data's covariance is diagonal (errors only).
    pub fn diagonal_data(&self) -> bool {
        self.covariance.is_none()
    }

    /// The block with the kernel's inputs `input.apply(x)` (the paper's x
    /// itself by default).
    pub fn with_kernel_input(mut self, input: KernelInput) -> Self {
        self.kernel_x = self.x.iter().map(|&x| input.apply(x)).collect();
        self.gram = DiscrepancyGram::new(&self.kernel_x);
        self.input = input;
        self
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Per-thread scratch so that evaluations allocate nothing.
struct Workspace {
    chol: Vec<CholeskyWorkspace>,
    eta: Vec<f64>,
    resid: Vec<f64>,
    xr: Vec<f64>,
    corr: Vec<f64>,
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

thread_local! {
    static WORKSPACES: RefCell<Vec<(u64, Workspace)>> = const { RefCell::new(Vec::new()) };
}

/// Log-likelihood of the calibration parameters `[θ, φ_1, φ_2, …]`.
pub struct MdLikelihood {
    id: u64,
    pub simulator: Arc<dyn Simulator>,
    pub blocks: Vec<ObservableBlock>,
    pub kernel: Option<DiscrepancyKernel>,
    pub n_theta: usize,
    log_jacobian: f64,
    /// The model adds its own predictive covariance (an emulator).
    model_covariance: bool,
}

impl MdLikelihood {
    pub fn new(simulator: Arc<dyn Simulator>, blocks: Vec<ObservableBlock>, kernel: Option<DiscrepancyKernel>) -> Self {
        let n_theta = simulator.parameter_names().len();
        let log_jacobian = -blocks.iter().map(|b| b.len() as f64 * b.scale.ln()).sum::<f64>();
        let model_covariance = simulator.has_model_covariance();
        MdLikelihood { id: NEXT_ID.fetch_add(1, Ordering::Relaxed), simulator, blocks, kernel, n_theta, log_jacobian, model_covariance }
    }

    pub fn n_hyper(&self) -> usize {
        self.kernel.map(|k| k.n_hyper()).unwrap_or(0)
    }

    pub fn dim(&self) -> usize {
        self.n_theta + self.blocks.len() * self.n_hyper()
    }

    /// Parameter names: θ names, then `<observable>.<hyper>` per block.
    pub fn parameter_names(&self) -> Vec<String> {
        let mut names = self.simulator.parameter_names();
        if let Some(k) = self.kernel {
            for b in &self.blocks {
                for h in k.hyper_names() {
                    names.push(format!("{}.{}", b.name, h));
                }
            }
        }
        names
    }

    /// The discrepancy hyperparameters of block `b` within a parameter vector.
    pub fn hyper_of<'a>(&self, params: &'a [f64], b: usize) -> &'a [f64] {
        let nh = self.n_hyper();
        &params[self.n_theta + b * nh..self.n_theta + (b + 1) * nh]
    }

    fn new_workspace(&self) -> Workspace {
        let nmax = self.blocks.iter().map(|b| b.len()).max().unwrap_or(0);
        Workspace {
            chol: self.blocks.iter().map(|b| CholeskyWorkspace::new(b.len())).collect(),
            eta: vec![0.0; nmax],
            resid: vec![0.0; nmax],
            xr: vec![0.0; nmax],
            corr: vec![0.0; self.blocks.iter().map(|b| b.gram.n_unique()).max().unwrap_or(0)],
        }
    }

    /// Runs `f` with this thread's workspace for this likelihood.
    fn with_workspace<R>(&self, f: impl FnOnce(&mut Workspace) -> R) -> R {
        WORKSPACES.with(|cell| {
            let mut list = cell.borrow_mut();
            let pos = match list.iter().position(|(id, _)| *id == self.id) {
                Some(p) => p,
                None => {
                    if list.len() >= 16 {
                        list.remove(0);
                    }
                    list.push((self.id, self.new_workspace()));
                    list.len() - 1
                }
            };
            f(&mut list[pos].1)
        })
    }

    pub fn log_likelihood(&self, params: &[f64]) -> f64 {
        self.with_workspace(|ws| {
            let mut total = self.log_jacobian;
            for b in 0..self.blocks.len() {
                total += self.block_log_likelihood(params, b, ws);
            }
            total
        })
    }

    /// The log-likelihood, with each observable block's term written to `terms`
    /// (the total is their sum plus the standardization's Jacobian).
    pub fn log_likelihood_terms(&self, params: &[f64], terms: &mut [f64]) -> f64 {
        self.with_workspace(|ws| {
            let mut total = self.log_jacobian;
            for (b, t) in terms.iter_mut().enumerate() {
                *t = self.block_log_likelihood(params, b, ws);
                total += *t;
            }
            total
        })
    }

    /// One observable block's term of the log-likelihood.
    pub fn log_likelihood_term(&self, params: &[f64], b: usize) -> f64 {
        self.with_workspace(|ws| self.block_log_likelihood(params, b, ws))
    }

    /// Fisher information of θ for the model without MD at `theta`,
    /// `F = Σ_b J_bᵀ diag(σ_b⁻²) J_b` (column-major d × d), with the Jacobian
    /// by central differences of step `steps[k]` in θ_k. `None` when the model
    /// carries its own θ-dependent covariance (an emulator): that dependence
    /// carries information this form leaves out, so it would be no bound.
    pub fn fisher_information(&self, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
        if self.model_covariance {
            return None;
        }
        let d = self.n_theta;
        let mut fisher = vec![0.0; d * d];
        let mut shifted = theta.to_vec();
        for block in &self.blocks {
            let n = block.len();
            let (mut up, mut down) = (vec![0.0; n], vec![0.0; n]);
            let mut jac = vec![0.0; n * d];
            for k in 0..d {
                shifted[k] = theta[k] + steps[k];
                self.simulator.predict(block.model_index, &block.x, &shifted, &mut up);
                shifted[k] = theta[k] - steps[k];
                self.simulator.predict(block.model_index, &block.x, &shifted, &mut down);
                shifted[k] = theta[k];
                for i in 0..n {
                    jac[i + k * n] = (up[i] - down[i]) / (2.0 * steps[k] * block.error[i]);
                }
            }
            if !block.diagonal_data() {
                whiten_by_data_covariance(block, &mut jac, d)?;
            }
            for a in 0..d {
                for b in 0..d {
                    fisher[a + b * d] += (0..n).map(|i| jac[i + a * n] * jac[i + b * n]).sum::<f64>();
                }
            }
        }
        Some(fisher)
    }

    /// Cramér–Rao standard deviations of θ at `theta`: the smallest spread any
    /// unbiased analysis of these data can reach with this model, `sqrt(diag F⁻¹)`.
    /// `None` as for `fisher_information`, or when F is singular (parameters
    /// the data cannot tell apart, such as g and a constant extra force).
    pub fn cramer_rao_sd(&self, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
        let d = self.n_theta;
        let fisher = self.fisher_information(theta, steps)?;
        let mut chol = CholeskyWorkspace::new(d);
        chol.factor.copy_from_slice(&fisher);
        if !chol.factorize_exact() {
            return None;
        }
        let inv = chol.inverse();
        let sd: Vec<f64> = (0..d).map(|k| inv[k + k * d].sqrt()).collect();
        sd.iter().all(|v| v.is_finite()).then_some(sd)
    }

    fn block_log_likelihood(&self, params: &[f64], b: usize, ws: &mut Workspace) -> f64 {
        let theta = &params[..self.n_theta];
        let block = &self.blocks[b];
        let n = block.len();
        let eta = &mut ws.eta[..n];
        self.simulator.predict(block.model_index, &block.x, theta, eta);
        let resid = &mut ws.resid[..n];
        let inv_scale = 1.0 / block.scale;
        for i in 0..n {
            resid[i] = (block.y[i] - eta[i]) * inv_scale;
        }
        let mut total = 0.0;
        if self.kernel.is_none() && !self.model_covariance && block.diagonal_data() {
            // Diagonal covariance: no factorization needed.
            for i in 0..n {
                let s = block.error[i] * inv_scale;
                let z = resid[i] / s;
                total += -0.5 * (z * z + 2.0 * s.ln() + LN_2PI);
            }
        } else {
            let chol = &mut ws.chol[b];
            match self.kernel {
                Some(kernel) => block.gram.fill_lower(kernel, self.hyper_of(params, b), &mut chol.factor, &mut ws.xr[..n], &mut ws.corr),
                None => chol.factor.iter_mut().for_each(|v| *v = 0.0),
            }
            if self.model_covariance {
                self.simulator.add_model_covariance(block.model_index, &block.x, theta, inv_scale * inv_scale, &mut chol.factor);
            }
            block.add_data_covariance(inv_scale * inv_scale, &mut chol.factor);
            if chol.factorize().is_err() {
                return f64::NEG_INFINITY;
            }
            total = gaussian_logpdf_factored(chol, resid);
        }
        if total.is_nan() {
            f64::NEG_INFINITY
        } else {
            total
        }
    }
}

/// Turns the error-scaled Jacobian columns `J/σ` into `L⁻¹J`, with `L L'`
/// the data's whole covariance, so that `Σ_i` of their products is `J'C⁻¹J`.
fn whiten_by_data_covariance(block: &ObservableBlock, jac: &mut [f64], d: usize) -> Option<()> {
    let n = block.len();
    let mut chol = CholeskyWorkspace::new(n);
    chol.factor.fill(0.0);
    block.add_data_covariance(1.0, &mut chol.factor);
    if !chol.factorize_exact() {
        return None;
    }
    for k in 0..d {
        let col = &mut jac[k * n..(k + 1) * n];
        for i in 0..n {
            col[i] *= block.error[i];
        }
        chol.solve_lower_in_place(col);
    }
    Some(())
}

const LN_2PI: f64 = 1.837_877_066_409_345_5;
