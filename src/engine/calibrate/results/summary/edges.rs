//! A posterior piled against its prior box: the likelihood still rises at
//! a bound, so the box, not the data, ends the posterior there, and the
//! intervals are as narrow as the box makes them. For an emulator the box
//! is its training design, beyond which it cannot be asked; for any model
//! the advice is the same: widen the box (and, for an emulator, its design)
//! and fit again.

use super::Chains;
use crate::engine::calibrate::sampler::uniform_prior::UniformPrior;

/// The strip along a bound, as a share of the parameter's range.
const STRIP: f64 = 0.02;
/// More than this share of the draws in the strip is "piled": five times
/// what a posterior flat near the bound (the prior's own shape) puts there.
const PILED: f64 = 5.0 * STRIP;

/// A parameter whose draws pile against one bound of its prior box.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PiledAtBound {
    pub parameter: String,
    /// `lower` or `upper`.
    pub bound: String,
    /// The bound's value.
    pub value: f64,
    /// The share of the draws within 2% of the range from the bound.
    pub share: f64,
}

impl std::fmt::Display for PiledAtBound {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {:.0}% of the draws lie within {:.0}% of the range from its {} bound {}; the box, not the data, ends the posterior there: widen the prior (an emulator's design) and fit again",
            self.parameter,
            100.0 * self.share,
            100.0 * STRIP,
            self.bound,
            super::readable(self.value)
        )
    }
}

/// Every parameter piled against a bound of `prior`, in parameter order.
/// The first `n_theta` are the model's; those after are δ's hyperparameters,
/// whose lower bound of zero is no box but the data's own answer (δ's
/// amplitude at zero: no discrepancy there), and is not reported.
pub fn piled_at_bounds(chains: &Chains, prior: &UniformPrior, n_theta: usize) -> Vec<PiledAtBound> {
    let mut found = Vec::new();
    for p in 0..chains.dim.min(prior.dim()) {
        let draws = chains.param(p);
        if draws.is_empty() {
            continue;
        }
        let (lo, hi) = (prior.lower[p], prior.upper[p]);
        let width = STRIP * (hi - lo);
        let n = draws.len() as f64;
        let near_lower = draws.iter().filter(|v| **v <= lo + width).count() as f64 / n;
        let near_upper = draws.iter().filter(|v| **v >= hi - width).count() as f64 / n;
        for (bound, value, share) in [("lower", lo, near_lower), ("upper", hi, near_upper)] {
            let natural = p >= n_theta && bound == "lower" && value == 0.0;
            if share > PILED && !natural {
                found.push(PiledAtBound { parameter: chains.names[p].clone(), bound: bound.into(), value, share });
            }
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chains_of(columns: &[Vec<f64>]) -> Chains {
        let dim = columns.len();
        let n = columns[0].len();
        let rows: Vec<f64> = (0..n).flat_map(|i| columns.iter().map(move |c| c[i])).collect();
        Chains::new((0..dim).map(|k| format!("p{k}")).collect(), dim, vec![rows])
    }

    #[test]
    fn a_posterior_against_its_upper_bound_is_reported_and_an_interior_or_flat_one_is_not() {
        let prior = UniformPrior::new(vec!["p0".into(), "p1".into(), "p2".into()], vec![0.0; 3], vec![1.0; 3]).unwrap();
        // p0 rises to the upper bound (density ∝ x^20: 1 − 0.98^21 ≈ 35% in the strip),
        // p1 is flat (2% in each strip), p2 is narrow and inside (none).
        let n = 4000;
        let u: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect();
        let rising: Vec<f64> = u.iter().map(|v| v.powf(1.0 / 21.0)).collect();
        let narrow: Vec<f64> = u.iter().map(|v| 0.5 + 0.05 * (v - 0.5)).collect();
        let found = piled_at_bounds(&chains_of(&[rising, u.clone(), narrow]), &prior, 3);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!((found[0].parameter.as_str(), found[0].bound.as_str()), ("p0", "upper"));
        assert!((found[0].share - (1.0 - 0.98f64.powi(21))).abs() < 0.01, "{}", found[0].share);
        assert!(found[0].to_string().contains("widen the prior"));
    }

    #[test]
    fn a_discrepancy_amplitude_at_zero_is_not_the_box_but_a_model_parameter_there_is() {
        // p0 a model parameter, p1 δ's amplitude.
        let prior = UniformPrior::new(vec!["p0".into(), "p1".into()], vec![0.0; 2], vec![1.0; 2]).unwrap();
        let n = 4000;
        // Both fall from zero (density ∝ (1 − x)^20: 35% in the lower strip).
        let falling: Vec<f64> = (0..n).map(|i| 1.0 - ((i as f64 + 0.5) / n as f64).powf(1.0 / 21.0)).collect();
        let found = piled_at_bounds(&chains_of(&[falling.clone(), falling]), &prior, 1);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!((found[0].parameter.as_str(), found[0].bound.as_str()), ("p0", "lower"));
    }
}
