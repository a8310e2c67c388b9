//! What a sampler targets: a log-likelihood over the unbounded prior box,
//! and how it splits into terms that a sampler may move one at a time.

use super::MdLikelihood;

/// Anything a sampler can target, given a uniform prior.
pub trait LogLikelihood: Sync {
    fn log_likelihood(&self, x: &[f64]) -> f64;

    /// How the log-likelihood splits into independent terms, when it does; a
    /// sampler may then move one term's own parameters at the cost of that term.
    fn term_structure(&self) -> Option<TermStructure> {
        None
    }

    /// The log-likelihood, with each term written to `terms` (only called when
    /// `term_structure` is given).
    fn log_likelihood_terms(&self, x: &[f64], _terms: &mut [f64]) -> f64 {
        self.log_likelihood(x)
    }

    /// One term (only called when `term_structure` is given).
    fn log_likelihood_term(&self, _x: &[f64], _term: usize) -> f64 {
        unreachable!("log_likelihood_term needs a term structure")
    }

    /// For terms that are not separable: a cheap, fixed function of `x` whose
    /// change with term `term`'s own parameters tracks the likelihood's. A
    /// sampler may screen a move of those parameters with it before paying
    /// for a whole evaluation (delayed acceptance, Christen & Fox 2005),
    /// which leaves the target exact. `None`: no screen.
    fn screening_term(&self, _x: &[f64], _term: usize) -> Option<f64> {
        None
    }

    /// For terms linked only through a small term that does not move with
    /// their own parameters: how many values each term's statistics take
    /// (`block_stats`); 0 when they are not so. A sampler that keeps every
    /// term's statistics moves one term's own parameters at that term's
    /// cost, exactly.
    fn term_stats_width(&self) -> usize {
        0
    }

    /// The log-likelihood, with every term's statistics written to `stats`
    /// (only called when `term_stats_width` is not 0).
    fn log_likelihood_stats(&self, x: &[f64], _stats: &mut [f64]) -> f64 {
        self.log_likelihood(x)
    }

    /// Term `term`'s statistics recomputed at `x` in `stats` (every term's),
    /// and the log-likelihood from them.
    fn update_term_stats(&self, _x: &[f64], _term: usize, _stats: &mut [f64]) -> f64 {
        unreachable!("update_term_stats needs term statistics")
    }
}

/// `log L(x) = const + Σ_t L_t(x_shared, x_own(t))`: every term depends on the
/// shared parameters (θ) and on its own (one observable's φ), and on no other.
/// When the terms are not `separable` (a joint likelihood), the groups still
/// make good Gibbs moves, but each costs a whole evaluation.
#[derive(Clone, Debug)]
pub struct TermStructure {
    pub shared: Vec<usize>,
    pub own: Vec<Vec<usize>>,
    pub separable: bool,
}

impl LogLikelihood for MdLikelihood {
    fn log_likelihood(&self, x: &[f64]) -> f64 {
        MdLikelihood::log_likelihood(self, x)
    }
    fn term_structure(&self) -> Option<TermStructure> {
        let nh = self.n_hyper();
        if nh == 0 {
            return None;
        }
        let own =
            (0..self.blocks.len()).map(|b| (self.n_theta + b * nh..self.n_theta + (b + 1) * nh).collect()).collect();
        Some(TermStructure { shared: (0..self.n_theta).collect(), own, separable: self.joint.is_none() })
    }
    fn log_likelihood_terms(&self, x: &[f64], terms: &mut [f64]) -> f64 {
        MdLikelihood::log_likelihood_terms(self, x, terms)
    }
    fn log_likelihood_term(&self, x: &[f64], term: usize) -> f64 {
        MdLikelihood::log_likelihood_term(self, x, term)
    }
    fn screening_term(&self, x: &[f64], term: usize) -> Option<f64> {
        MdLikelihood::screening_term(self, x, term)
    }
    fn term_stats_width(&self) -> usize {
        MdLikelihood::term_stats_width(self)
    }
    fn log_likelihood_stats(&self, x: &[f64], stats: &mut [f64]) -> f64 {
        MdLikelihood::log_likelihood_stats(self, x, stats)
    }
    fn update_term_stats(&self, x: &[f64], term: usize, stats: &mut [f64]) -> f64 {
        MdLikelihood::update_term_stats(self, x, term, stats)
    }
}
