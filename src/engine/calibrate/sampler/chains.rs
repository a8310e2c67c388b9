//! Posterior draws as chains, the form every sampler returns.

use super::checkpoint;

/// Posterior draws grouped into chains (walkers for the ensemble sampler,
/// replicates for SMC). Each chain is row-major `draws × dim`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Chains {
    pub names: Vec<String>,
    pub dim: usize,
    #[serde(with = "checkpoint::f64_bits_rows")]
    pub chains: Vec<Vec<f64>>,
}

impl Chains {
    pub fn n_draws(&self) -> usize {
        self.chains.iter().map(|c| c.len() / self.dim).sum()
    }

    /// Per-chain series of parameter `p`.
    pub fn param_chains(&self, p: usize) -> Vec<Vec<f64>> {
        self.chains.iter().map(|c| c.chunks(self.dim).map(|row| row[p]).collect()).collect()
    }

    /// All draws of parameter `p`.
    pub fn param(&self, p: usize) -> Vec<f64> {
        self.chains.iter().flat_map(|c| c.chunks(self.dim).map(move |row| row[p])).collect()
    }

    /// All draws as rows.
    pub fn rows(&self) -> impl Iterator<Item = &[f64]> {
        self.chains.iter().flat_map(move |c| c.chunks(self.dim))
    }
}
