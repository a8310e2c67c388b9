//! Uniform (box) priors, as in the paper, for θ and the discrepancy
//! hyperparameters alike.

use anyhow::{bail, Result};
use rand::Rng;

#[derive(Clone, Debug)]
pub struct UniformPrior {
    pub names: Vec<String>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    log_density: f64,
}

impl UniformPrior {
    pub fn new(names: Vec<String>, lower: Vec<f64>, upper: Vec<f64>) -> Result<Self> {
        assert_eq!(names.len(), lower.len());
        assert_eq!(names.len(), upper.len());
        for i in 0..names.len() {
            if !(lower[i].is_finite() && upper[i].is_finite() && lower[i] < upper[i]) {
                bail!("prior bounds for '{}' must be finite with min < max, got ({}, {})", names[i], lower[i], upper[i]);
            }
        }
        let log_density = -(0..names.len()).map(|i| (upper[i] - lower[i]).ln()).sum::<f64>();
        Ok(UniformPrior { names, lower, upper, log_density })
    }

    pub fn dim(&self) -> usize {
        self.names.len()
    }

    /// Bounds are open intervals: hyperparameters such as ℓ must stay > 0.
    #[inline]
    pub fn contains(&self, x: &[f64]) -> bool {
        x.iter().zip(self.lower.iter().zip(&self.upper)).all(|(v, (lo, hi))| *v > *lo && *v < *hi)
    }

    #[inline]
    pub fn log_density(&self, x: &[f64]) -> f64 {
        if self.contains(x) {
            self.log_density
        } else {
            f64::NEG_INFINITY
        }
    }

    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
        for i in 0..self.dim() {
            loop {
                let u: f64 = rng.random();
                let v = self.lower[i] + u * (self.upper[i] - self.lower[i]);
                if v > self.lower[i] && v < self.upper[i] {
                    out[i] = v;
                    break;
                }
            }
        }
    }
}
