//! What a sampler targets: a log-likelihood over the unbounded prior box,
//! and how it splits into terms that a sampler may move one at a time.

/// Anything a sampler can target, given a uniform prior.
pub trait LogLikelihood: Sync {
    fn log_likelihood(&self, x: &[f64]) -> f64;

    /// `log_likelihood(x)`, or −∞ when it is below `floor`: a likelihood
    /// that can tell sooner than by computing it may stop there. Values
    /// below the floor may come back either way; a sampler that passes a
    /// floor treats them all as −∞.
    fn log_likelihood_above(&self, x: &[f64], _floor: f64) -> f64 {
        self.log_likelihood(x)
    }

    /// How the log-likelihood splits into independent terms, when it does; a
    /// sampler may then move one term's own parameters at the cost of that term.
    fn term_structure(&self) -> Option<TermStructure> {
        None
    }

    /// For terms that are not separable: a cheap, fixed function of `x` whose
    /// change with term `term`'s own parameters tracks the likelihood's. A
    /// sampler may screen a move of those parameters with it before paying
    /// for a whole evaluation (delayed acceptance, Christen & Fox 2005),
    /// which leaves the target exact. `None`: no screen.
    fn screening_term(&self, _x: &[f64], _term: usize) -> Option<f64> {
        None
    }

    /// The terms evaluated one at a time, when they are independent (a
    /// separable `term_structure`); `None` otherwise.
    fn separable_terms(&self) -> Option<&dyn SeparableTerms> {
        None
    }

    /// For terms linked only through a small term that does not move with
    /// their own parameters: each term's statistics (`block_stats`); `None`
    /// when they are not so. A sampler that keeps every term's statistics
    /// moves one term's own parameters at that term's cost, exactly.
    fn term_statistics(&self) -> Option<&dyn TermStatistics> {
        None
    }
}

/// Independent terms: `log L = Σ_t L_t`, each computable alone.
pub trait SeparableTerms: Sync {
    /// The log-likelihood, with each term written to `terms`.
    fn log_likelihood_terms(&self, x: &[f64], terms: &mut [f64]) -> f64;
    /// One term.
    fn log_likelihood_term(&self, x: &[f64], term: usize) -> f64;
}

/// Linked terms whose link is a small term: every term's statistics kept,
/// one term's recomputed when its own parameters move.
pub trait TermStatistics: Sync {
    /// How many values each term's statistics take (at least 1).
    fn width(&self) -> usize;
    /// The log-likelihood, with every term's statistics written to `stats`.
    fn log_likelihood_stats(&self, x: &[f64], stats: &mut [f64]) -> f64;
    /// Term `term`'s statistics recomputed at `x` in `stats` (every term's),
    /// and the log-likelihood from them.
    fn update_term_stats(&self, x: &[f64], term: usize, stats: &mut [f64]) -> f64;
}

/// `log L(x) = const + Σ_t L_t(x_shared, x_own(t))`: every term depends on the
/// shared parameters (θ) and on its own (one observable's φ), and on no other.
/// When the terms are not separable (a joint likelihood, no
/// `LogLikelihood::separable_terms`), the groups still make good Gibbs
/// moves, but each costs a whole evaluation.
#[derive(Clone, Debug)]
pub struct TermStructure {
    pub shared: Vec<usize>,
    pub own: Vec<Vec<usize>>,
}
