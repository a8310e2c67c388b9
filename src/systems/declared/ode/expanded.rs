//! The rates that are polynomials in the state, expanded once into
//! monomials whose coefficients are computed once per integration
//! (`engine::formula::polynomial`, which says why), and where each rate's
//! coefficients sit in the integration's buffer.

use crate::engine::formula::polynomial::{Polynomial, MAX_DEGREE, MAX_VARIABLES};
use crate::engine::formula::{Formula, Scope};

/// Coefficients of all expanded rates together, at most: a rate that would
/// pass it is evaluated as written.
pub(super) const MAX_COEFFICIENTS: usize = 64;

pub(super) struct ExpandedRates {
    /// Per rate, its expansion and the offset of its coefficients.
    pub rates: Vec<Option<(Polynomial, usize)>>,
    /// The highest power of a state in any expansion.
    pub degree: usize,
    /// Every rate is expanded: the value vector need not be written.
    pub all: bool,
}

impl ExpandedRates {
    /// The rates (each a formula of the input, θ, constants and `states`,
    /// in `scope`, whose first name is the input: t, or what `[model] input`
    /// calls it) that expand; None when none does or there are too many
    /// states for it. A rate that reads the input is never expanded: its
    /// coefficients would be frozen at t0.
    pub fn of(rates: &[Formula], states: &[String], scope: &Scope) -> Option<ExpandedRates> {
        let input = scope.names().first()?.as_str();
        if states.len() > MAX_VARIABLES {
            return None;
        }
        let mut used = 0;
        let expanded: Vec<Option<(Polynomial, usize)>> = rates
            .iter()
            .map(|r| {
                let p = Polynomial::expand(r.expr(), states, &[input], scope, r.text())?;
                let at = used;
                (at + p.len() <= MAX_COEFFICIENTS).then(|| {
                    used += p.len();
                    (p, at)
                })
            })
            .collect();
        if expanded.iter().all(Option::is_none) {
            return None;
        }
        let degree = expanded.iter().flatten().map(|(p, _)| p.degree()).max().unwrap_or(1).clamp(1, MAX_DEGREE);
        let all = expanded.iter().all(Option::is_some);
        Some(ExpandedRates { rates: expanded, degree, all })
    }

    /// Every expanded rate's coefficients at `values` (θ and constants in place).
    pub fn coefficients(&self, values: &[f64]) -> [f64; MAX_COEFFICIENTS] {
        let mut c = [0.0; MAX_COEFFICIENTS];
        for (p, at) in self.rates.iter().flatten() {
            p.coefficients_at(values, &mut c[*at..*at + p.len()]);
        }
        c
    }
}
