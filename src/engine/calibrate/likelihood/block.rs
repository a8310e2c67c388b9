//! One observable's measurements as the likelihood sees them: sorted by x,
//! standardized by their mean and spread (the paper's convention, so that
//! discrepancy hyperparameters are comparable across observables), with the
//! discrepancy kernel's inputs and any covariance beyond the errors.

use crate::base::artifacts::Measurement;
use crate::base::config::KernelInput;
use crate::engine::gp::{CholeskyWorkspace, DiscrepancyGram};
use anyhow::{bail, Result};

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

impl ObservableBlock {
    /// The factor of a block's data covariance (errors² and any covariance
    /// beyond them, standardized), made once for a likelihood in which nothing
    /// depends on the parameters: the block form's counterpart of
    /// `FixedFactors`. `None` for errors alone (no factorization needed) or a
    /// covariance that needs jitter (then it is factorized, with the jitter
    /// counted, at each evaluation as before).
    pub fn fixed_factor(&self) -> Option<CholeskyWorkspace> {
        if self.diagonal_data() {
            return None;
        }
        let n = self.len();
        let mut chol = CholeskyWorkspace::new(n);
        chol.factor.iter_mut().for_each(|v| *v = 0.0);
        self.add_data_covariance(1.0 / (self.scale * self.scale), &mut chol.factor);
        chol.factorize_exact().then_some(chol)
    }
}
