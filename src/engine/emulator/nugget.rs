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
//! the null fit re-optimized over the other hyperparameters, is compared
//! with the 95% point of its null distribution. The null value sits on the
//! boundary of the allowed σ_n² ≥ ν, where the statistic follows
//! ½χ²₀ + ½χ²₁ (Self & Liang 1987), whose 95% point is χ²₁'s 90% point.
//! When the test does not reject, the component uses the null fit.

/// The 95% point of ½χ²₀ + ½χ²₁, i.e. the 90% point of χ²₁.
pub const CRITICAL_STATISTIC: f64 = 2.705_543_454_095_404;

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
    /// Whether the excess over the reported noise was kept.
    pub excess_kept: bool,
}

impl ExcessScatterTest {
    /// The decision from the two fits' log marginal likelihoods.
    pub fn decide(component: usize, fitted_noise_var: f64, reported_noise_var: f64, free_lml: f64, null_lml: f64) -> ExcessScatterTest {
        let statistic = (2.0 * (free_lml - null_lml)).max(0.0);
        ExcessScatterTest { component, fitted_noise_var, reported_noise_var, statistic, excess_kept: statistic > CRITICAL_STATISTIC }
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

    /// The critical value is the boundary mixture's 95% point: half the mass
    /// is the point at 0, so χ²₁ must leave 0.10 above it.
    #[test]
    fn the_critical_value_leaves_five_percent_under_the_boundary_null() {
        use statrs::distribution::{ChiSquared, ContinuousCDF};
        let tail = ChiSquared::new(1.0).unwrap().sf(CRITICAL_STATISTIC);
        assert!((0.5 * tail - 0.05).abs() < 1e-9, "tail {tail}");
    }

    #[test]
    fn a_statistic_below_the_critical_value_drops_the_excess() {
        assert!(!ExcessScatterTest::decide(0, 1.1, 1.0, 10.0, 9.0).excess_kept);
        assert!(ExcessScatterTest::decide(0, 2.0, 1.0, 10.0, 8.0).excess_kept);
        // A null fit that found a higher likelihood than the free one (a local optimum) is no evidence.
        assert_eq!(ExcessScatterTest::decide(0, 1.1, 1.0, 9.0, 9.5).statistic, 0.0);
        assert!(!has_excess(1.0, 0.0) && !has_excess(0.9, 1.0) && has_excess(1.1, 1.0));
    }
}
