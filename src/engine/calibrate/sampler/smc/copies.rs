//! Whether the copies that the final resampling made still resemble each
//! other: the correlation within groups of common ancestry.
//!
//! Why: the final sweeps exist to separate those copies. The draws are
//! reported in ancestor order and their effective sample size is read from
//! the correlation of neighbours (`diagnostics`), so once the copies are as
//! good as independent, further sweeps buy nothing that is reported. A
//! cloud whose copies separate in a few sweeps stops there; one whose
//! copies stay alike sweeps up to the configured count.

/// Whether the copies are as good as independent: every coordinate's
/// correlation among copies, ρ (the share of its variance that lies between
/// groups of common ancestry, from one-way analysis of variance), is at most
/// `target` beyond one standard error of its estimate. Groups are the runs
/// of equal `ancestors` (sorted). The allowance matters: from one replicate
/// of 2 000 particles the estimate's error is about 0.06, as large as the
/// correlation that is left after a few sweeps, and the largest of a dozen
/// such estimates stays near 0.1 however long the sweeps go on.
pub(super) fn separated(x: &[f64], dim: usize, ancestors: &[usize], target: f64) -> bool {
    let n = ancestors.len();
    let groups = runs(ancestors);
    if n < 2 || groups.len() == n {
        return true;
    }
    // Standard error of 1 − W/V at ρ = 0 from the within-group and total
    // variances' degrees of freedom (their positive covariance ignored, so
    // this is at least the error).
    let se = (2.0 / (n - groups.len()) as f64 + 2.0 / (n - 1) as f64).sqrt();
    (0..dim).all(|j| correlation_among_copies(x, dim, j, &groups) <= target + se)
}

/// ρ of coordinate `j`: one minus the within-group variance per degree of
/// freedom over the total's, clipped to [0, 1].
fn correlation_among_copies(x: &[f64], dim: usize, j: usize, groups: &[std::ops::Range<usize>]) -> f64 {
    let value = |i: usize| x[i * dim + j];
    let n = groups.last().map_or(0, |r| r.end);
    let mean = (0..n).map(value).sum::<f64>() / n as f64;
    let total: f64 = (0..n).map(|i| (value(i) - mean).powi(2)).sum();
    let within: f64 = groups
        .iter()
        .map(|r| {
            let m = r.clone().map(value).sum::<f64>() / r.len() as f64;
            r.clone().map(|i| (value(i) - m).powi(2)).sum::<f64>()
        })
        .sum();
    let within_var = within / (n - groups.len()) as f64;
    let total_var = total / (n - 1) as f64;
    if total_var > 0.0 {
        (1.0 - within_var / total_var).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The index ranges of equal neighbours in `ancestors`.
fn runs(ancestors: &[usize]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=ancestors.len() {
        if i == ancestors.len() || ancestors[i] != ancestors[start] {
            out.push(start..i);
            start = i;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_distr::StandardNormal;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// 2 000 draws in groups of 1, 2 and 3 (about the share of copies that
    /// multinomial resampling of even weights makes): exact copies have ρ = 1,
    /// independent draws about 0 (its error ~0.06), a copy that kept a share
    /// s of its variance in common ρ ≈ s. Seeded. The estimate's error here
    /// is about 0.055; the bounds on ρ sit three or more errors from where
    /// the estimate is expected, but the independent draws' `separated`
    /// (ρ ≤ 0.05 + its error) only about two: one seed in some 40 would
    /// fail it, which is the rule's own false-alarm rate, not the test's.
    #[test]
    fn copies_are_told_from_independent_draws() {
        let ancestors: Vec<usize> = (0..1000).flat_map(|g| std::iter::repeat_n(g, 1 + g % 3)).take(2000).collect();
        let groups = runs(&ancestors);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut draw = || -> f64 { rng.sample(StandardNormal) };
        let shared: Vec<f64> = (0..1000).map(|_| draw()).collect();
        let copies: Vec<f64> = ancestors.iter().map(|&a| shared[a]).collect();
        assert_eq!(correlation_among_copies(&copies, 1, 0, &groups), 1.0);
        assert!(!separated(&copies, 1, &ancestors, 0.05));
        let independent: Vec<f64> = (0..2000).map(|_| draw()).collect();
        assert!(correlation_among_copies(&independent, 1, 0, &groups) < 0.2);
        assert!(separated(&independent, 1, &ancestors, 0.05));
        for share in [0.3f64, 0.6] {
            let mixed: Vec<f64> =
                ancestors.iter().map(|&a| share.sqrt() * shared[a] + (1.0 - share).sqrt() * draw()).collect();
            let rho = correlation_among_copies(&mixed, 1, 0, &groups);
            assert!((rho - share).abs() < 0.2, "share {share}: rho {rho}");
            assert!(!separated(&mixed, 1, &ancestors, 0.05), "share {share}");
        }
        // The worst coordinate decides.
        let two: Vec<f64> = independent.iter().zip(&copies).flat_map(|(a, b)| [*a, *b]).collect();
        assert!(!separated(&two, 2, &ancestors, 0.05));
        // Every particle its own ancestor: nothing to separate.
        let own: Vec<usize> = (0..2000).collect();
        assert!(separated(&copies, 1, &own, 0.05));
    }
}
