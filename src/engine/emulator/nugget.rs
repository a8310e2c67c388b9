//! Does a component scatter more than its runs report?
//!
//! Each component's GP fits a white-noise term σ_n² to the runs. When the
//! runs report their statistical errors, that noise projected on the
//! component, ν (see `run_noise`), is known, and only the part of σ_n²
//! beyond ν is model uncertainty (roughness the GP cannot follow). That
//! part stays in every prediction and no number of design points lowers it.
//!
//! A fitted σ_n² is itself noisy: its relative sd is about √(2/n) with n
//! runs, so it lands above ν about half the time when there is no excess at
//! all. In the bundled heavy-ion study the leading spectrum component's
//! nugget came out 8% above ν with 100 runs (a 14% sampling sd), and
//! because that component carries most of the spectra's variance, the
//! chance excess alone put the spectra's predictive sd at 1.6 times the
//! data error after every round of adaptive design.
//!
//! So the excess is a variance component that is kept only when the runs
//! show it: the likelihood-ratio statistic `2 (log L_free − log L_{σ_n²=ν})`,
//! the null fit re-optimized over the other hyperparameters. The null value
//! sits on the boundary of the allowed σ_n² ≥ ν, where the statistic follows
//! ½χ²₀ + ½χ²₁ (Self & Liang 1987). One training tests every kept component
//! whose nugget came out above ν, and one emulator's question is whether its
//! runs scatter as reported, so the components are tested as a family at 5%
//! by Holm's step-down: a chance excess in some component of ten would
//! otherwise be kept 40% of the time, and one kept in a leading component
//! costs as much as the example above. A component whose excess is not
//! kept uses its null fit.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// The family-wise level of the test.
pub const LEVEL: f64 = 0.05;

/// One kept component's test, as recorded in the training report.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ExcessScatterTest {
    pub component: usize,
    /// The freely fitted white-noise variance (whitened units).
    pub fitted_noise_var: f64,
    /// The runs' reported noise projected on the component (whitened units).
    pub reported_noise_var: f64,
    /// `2 (log L_free − log L_null)`, floored at 0.
    pub statistic: f64,
    /// Its tail probability under ½χ²₀ + ½χ²₁.
    pub p_value: f64,
    /// Whether the excess over the reported noise was kept (Holm, at [`LEVEL`]).
    pub excess_kept: bool,
}

impl ExcessScatterTest {
    /// One component's test from the two fits' log marginal likelihoods,
    /// undecided until [`decide_by_holm`].
    pub fn new(
        component: usize,
        fitted_noise_var: f64,
        reported_noise_var: f64,
        free_lml: f64,
        null_lml: f64,
    ) -> ExcessScatterTest {
        // A null fit that found a higher likelihood (a local optimum of the free one) is no evidence.
        let statistic = (2.0 * (free_lml - null_lml)).max(0.0);
        ExcessScatterTest {
            component,
            fitted_noise_var,
            reported_noise_var,
            statistic,
            p_value: boundary_p_value(statistic),
            excess_kept: false,
        }
    }
}

/// `P(T ≥ t)` for T ~ ½χ²₀ + ½χ²₁.
pub fn boundary_p_value(statistic: f64) -> f64 {
    if statistic > 0.0 {
        0.5 * ChiSquared::new(1.0).expect("one degree of freedom").sf(statistic)
    } else {
        1.0
    }
}

/// Holm's step-down at [`LEVEL`]: the i-th smallest of K p-values is
/// rejected at `LEVEL/(K − i)`, up to the first that is not.
pub fn decide_by_holm(tests: &mut [ExcessScatterTest]) {
    let mut order: Vec<usize> = (0..tests.len()).collect();
    order.sort_by(|&a, &b| tests[a].p_value.total_cmp(&tests[b].p_value));
    let k = tests.len();
    for (rank, &i) in order.iter().enumerate() {
        if tests[i].p_value > LEVEL / (k - rank) as f64 {
            break;
        }
        tests[i].excess_kept = true;
    }
}

/// Whether a component needs the test: its runs report noise and its fitted
/// white noise exceeds it.
pub fn has_excess(fitted_noise_var: f64, reported_noise_var: f64) -> bool {
    reported_noise_var > 0.0 && fitted_noise_var > reported_noise_var
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At the boundary mixture's 95% point (χ²₁'s 90% point, 2.7055) the
    /// p-value is 5%; at 0 it is 1.
    #[test]
    fn the_p_value_is_the_boundary_mixtures_tail() {
        assert!((boundary_p_value(2.705_543_454_095_404) - 0.05).abs() < 1e-9);
        assert_eq!(boundary_p_value(0.0), 1.0);
    }

    fn with_p(p_values: &[f64]) -> Vec<ExcessScatterTest> {
        p_values
            .iter()
            .enumerate()
            .map(|(k, &p)| ExcessScatterTest {
                component: k,
                fitted_noise_var: 2.0,
                reported_noise_var: 1.0,
                statistic: 1.0,
                p_value: p,
                excess_kept: false,
            })
            .collect()
    }

    /// Holm steps down from the smallest p-value and stops at the first
    /// that misses its threshold (0.05/K, 0.05/(K−1), …).
    #[test]
    fn holm_keeps_the_excesses_that_survive_the_step_down() {
        let kept = |p: &[f64]| {
            let mut t = with_p(p);
            decide_by_holm(&mut t);
            t.iter().map(|t| t.excess_kept).collect::<Vec<_>>()
        };
        // One test: the plain 5% level.
        assert_eq!(kept(&[0.049]), [true]);
        assert_eq!(kept(&[0.051]), [false]);
        // Four: 0.012 ≤ 0.0125 and 0.016 ≤ 0.0167 are kept; 0.03 > 0.025 stops the rest.
        assert_eq!(kept(&[0.03, 0.012, 0.5, 0.016]), [false, true, false, true]);
        // The study's case: 0.043 alone among four is not enough.
        assert_eq!(kept(&[0.3, 0.043, 0.3, 0.6]), [false, false, false, false]);
    }
}
