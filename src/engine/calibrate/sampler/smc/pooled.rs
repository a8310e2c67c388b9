//! The evidence of independent replicates pooled: Ẑ = mean_k Ẑ_k, and its
//! error.
//!
//! Each replicate's Lee–Whiteley variance sees only the modes that
//! replicate visited: four replicates stuck in four modes of a periodic
//! term's frequency each report a tight error while their log Ẑ_k differ
//! by several nats (seen on a discovered sinusoid: 207.0 to 213.3, each
//! ± 0.3). The replicates themselves are the independent check. Where
//! their scatter is consistent with their own errors (a χ² test at 1%,
//! `K − 1` degrees of freedom), the Lee–Whiteley error stands, so a
//! calibrated error stays calibrated; where it is not, the error of the
//! mean is taken from the scatter of the Ẑ_k themselves.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// A scatter beyond this quantile of χ²_{K−1} means the replicates' own
/// errors are blind to something (a mode they never visited).
const SCATTER_QUANTILE: f64 = 0.99;

/// Pooled log Ẑ and its standard error, from each replicate's log Ẑ_k and
/// Lee–Whiteley estimate of Var(Ẑ_k)/Z².
pub fn pool(log_z: &[f64], relative_variance: &[f64]) -> (f64, f64) {
    let k = log_z.len().max(1) as f64;
    let log_evidence = super::log_sum_exp(log_z) - k.ln();
    let lee_whiteley: f64 = relative_variance.iter().map(|v| v.max(0.0)).sum::<f64>() / (k * k);
    let rel_var = if scatter_beyond_errors(log_z, relative_variance) {
        // Var(mean Ẑ_k)/Z² from the sample variance of Ẑ_k/Ẑ, divided by K.
        let ratios: Vec<f64> = log_z.iter().map(|l| (l - log_evidence).exp()).collect();
        let sample_var = ratios.iter().map(|r| (r - 1.0).powi(2)).sum::<f64>() / (k - 1.0);
        lee_whiteley.max(sample_var / k)
    } else {
        lee_whiteley
    };
    (log_evidence, rel_var.ln_1p().sqrt())
}

/// Whether the replicates' log Ẑ_k scatter more than their own errors
/// allow: Σ (log Ẑ_k − weighted mean)² / e_k² beyond χ²_{K−1}'s quantile.
fn scatter_beyond_errors(log_z: &[f64], relative_variance: &[f64]) -> bool {
    if log_z.len() < 2 || log_z.iter().any(|l| !l.is_finite()) {
        return false;
    }
    let var: Vec<f64> = relative_variance.iter().map(|v| v.max(1e-12).ln_1p()).collect();
    let weight_sum: f64 = var.iter().map(|v| 1.0 / v).sum();
    let mean = log_z.iter().zip(&var).map(|(l, v)| l / v).sum::<f64>() / weight_sum;
    let q: f64 = log_z.iter().zip(&var).map(|(l, v)| (l - mean).powi(2) / v).sum();
    let limit =
        ChiSquared::new((log_z.len() - 1) as f64).map(|d| d.inverse_cdf(SCATTER_QUANTILE)).unwrap_or(f64::INFINITY);
    q > limit
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replicates_that_agree_keep_the_lee_whiteley_error() {
        // Spread 0.1 against errors of 0.1 each: consistent.
        let log_z = [10.0, 10.1, 9.95, 10.05];
        let rv = [0.01f64.exp_m1(); 4];
        let (z, e) = pool(&log_z, &rv);
        let lw = (rv.iter().sum::<f64>() / 16.0).ln_1p().sqrt();
        assert!((e - lw).abs() < 1e-15, "{e} vs {lw}");
        assert!(z > 9.95 && z < 10.1);
    }

    #[test]
    fn replicates_stuck_in_different_modes_get_the_error_of_their_scatter() {
        // The four replicates of a discovered sinusoid's fit, each ± 0.3.
        let log_z = [212.05, 213.25, 206.97, 210.59];
        let rv = [0.09f64.exp_m1(); 4];
        let (z, e) = pool(&log_z, &rv);
        // Ẑ is dominated by the largest replicate; the error is that of the
        // mean of the four ratios Ẑ_k/Ẑ.
        let mean_of_ratios: f64 = log_z.iter().map(|l| (l - 213.25).exp()).sum::<f64>() / 4.0;
        assert!((z - (213.25 + mean_of_ratios.ln())).abs() < 1e-12);
        let ratios: Vec<f64> = log_z.iter().map(|l| (l - z).exp()).collect();
        let sd = (ratios.iter().map(|r| (r - 1.0).powi(2)).sum::<f64>() / 3.0).sqrt();
        assert!((e - ((sd * sd / 4.0).ln_1p()).sqrt()).abs() < 1e-12);
        // The ratios' sd is about 1.3, so the error is sqrt(ln(1 + 1.3²/4)) ≈ 0.6.
        assert!(e > 4.0 * 0.15, "the scatter's error {e} must exceed four times the replicates' own 0.15");
    }

    #[test]
    fn one_replicate_has_only_its_own_error() {
        let (z, e) = pool(&[3.0], &[0.04]);
        assert_eq!(z, 3.0);
        assert!((e - 0.04f64.ln_1p().sqrt()).abs() < 1e-15);
    }
}
