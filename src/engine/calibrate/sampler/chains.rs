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
    /// Draws per chain when `dim` is 0 (a model with nothing to calibrate:
    /// every draw is the one point), which the rows cannot tell.
    #[serde(default)]
    pub points: usize,
}

impl Chains {
    /// Chains of `dim` coordinates (at least one) from their rows.
    pub fn new(names: Vec<String>, dim: usize, chains: Vec<Vec<f64>>) -> Chains {
        Chains { names, dim, chains, points: 0 }
    }

    /// `chains` chains of `points` draws of no coordinates.
    pub fn of_a_point(chains: usize, points: usize) -> Chains {
        Chains { names: Vec::new(), dim: 0, chains: vec![Vec::new(); chains], points }
    }

    pub fn draws_in(&self, chain: &[f64]) -> usize {
        chain.len().checked_div(self.dim).unwrap_or(self.points)
    }

    pub fn n_draws(&self) -> usize {
        self.chains.iter().map(|c| self.draws_in(c)).sum()
    }

    /// Per-chain series of parameter `p`.
    pub fn param_chains(&self, p: usize) -> Vec<Vec<f64>> {
        self.chains.iter().map(|c| c.chunks(self.dim).map(|row| row[p]).collect()).collect()
    }

    /// All draws of parameter `p`.
    pub fn param(&self, p: usize) -> Vec<f64> {
        self.chains.iter().flat_map(|c| c.chunks(self.dim).map(move |row| row[p])).collect()
    }

    /// All draws as rows (empty rows, one per draw, when `dim` is 0).
    pub fn rows(&self) -> impl Iterator<Item = &[f64]> {
        let empty: &[f64] = &[];
        let width = self.dim.max(1);
        self.chains.iter().flat_map(move |c| {
            let n = self.draws_in(c);
            (0..n).map(move |i| if self.dim == 0 { empty } else { &c[i * width..(i + 1) * width] })
        })
    }
}
