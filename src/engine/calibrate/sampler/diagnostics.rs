//! Convergence diagnostics after Vehtari, Gelman, Simpson, Carpenter & Bürkner
//! (2021): rank-normalized split-R̂, bulk and tail effective sample size, and
//! the integrated autocorrelation time (Sokal's adaptive window, as in emcee).
//!
//! `chains` is a slice of chains, each the draws of one scalar quantity.

use statrs::distribution::{ContinuousCDF, Normal};

/// Thresholds below which a run is reported as not converged.
pub const RHAT_MAX: f64 = 1.01;
pub const ESS_MIN: f64 = 400.0;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct ParamDiagnostics {
    pub name: String,
    pub rhat: f64,
    pub ess_bulk: f64,
    pub ess_tail: f64,
    /// Integrated autocorrelation time in draws (per chain).
    pub tau: f64,
}

impl ParamDiagnostics {
    pub fn converged(&self) -> bool {
        self.rhat <= RHAT_MAX && self.ess_bulk >= ESS_MIN && self.ess_tail >= ESS_MIN
    }
}

pub fn diagnose_param(name: &str, chains: &[Vec<f64>]) -> ParamDiagnostics {
    ParamDiagnostics {
        name: name.to_string(),
        rhat: rhat(chains),
        ess_bulk: ess_bulk(chains),
        ess_tail: ess_tail(chains),
        tau: integrated_autocorr_time(chains),
    }
}

fn split_chains(chains: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut out = Vec::with_capacity(2 * chains.len());
    for c in chains {
        let half = c.len() / 2;
        // With an odd length the middle draw is dropped, as in ArviZ.
        out.push(c[..half].to_vec());
        out.push(c[c.len() - half..].to_vec());
    }
    out
}

/// Pooled ranks mapped through the normal quantile function.
fn z_scale(chains: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let total: usize = chains.iter().map(|c| c.len()).sum();
    let mut all: Vec<(f64, usize)> = chains.iter().flatten().copied().enumerate().map(|(i, v)| (v, i)).collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut ranks = vec![0.0; total];
    let mut i = 0;
    while i < total {
        let mut j = i;
        while j + 1 < total && all[j + 1].0 == all[i].0 {
            j += 1;
        }
        let avg_rank = (i + j) as f64 / 2.0 + 1.0;
        for k in i..=j {
            ranks[all[k].1] = avg_rank;
        }
        i = j + 1;
    }
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut out = Vec::with_capacity(chains.len());
    let mut offset = 0;
    for c in chains {
        out.push(
            (0..c.len()).map(|k| normal.inverse_cdf((ranks[offset + k] - 0.375) / (total as f64 + 0.25))).collect(),
        );
        offset += c.len();
    }
    out
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn var_ddof1(v: &[f64]) -> f64 {
    let m = mean(v);
    v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() as f64 - 1.0)
}

fn rhat_basic(chains: &[Vec<f64>]) -> f64 {
    let n = chains.iter().map(|c| c.len()).min().unwrap_or(0) as f64;
    if chains.len() < 2 || n < 2.0 {
        return f64::NAN;
    }
    let means: Vec<f64> = chains.iter().map(|c| mean(c)).collect();
    let w = mean(&chains.iter().map(|c| var_ddof1(c)).collect::<Vec<_>>());
    let b = n * var_ddof1(&means);
    let var_hat = (n - 1.0) / n * w + b / n;
    if w <= 0.0 {
        return if b <= 0.0 { 1.0 } else { f64::INFINITY };
    }
    (var_hat / w).sqrt()
}

/// Rank-normalized split-R̂: the larger of the bulk and tail (folded) versions.
pub fn rhat(chains: &[Vec<f64>]) -> f64 {
    let split = split_chains(chains);
    let bulk = rhat_basic(&z_scale(&split));
    let all: Vec<f64> = chains.iter().flatten().copied().collect();
    let med = quantile(&all, 0.5);
    let folded: Vec<Vec<f64>> = split.iter().map(|c| c.iter().map(|x| (x - med).abs()).collect()).collect();
    let tail = rhat_basic(&z_scale(&folded));
    bulk.max(tail)
}

/// Effective sample size with Geyer's initial monotone sequence estimator,
/// computing autocovariances lag by lag and stopping as soon as Geyer's rule does.
pub fn ess_basic(chains: &[Vec<f64>]) -> f64 {
    let m = chains.len();
    let n = chains.iter().map(|c| c.len()).min().unwrap_or(0);
    if m == 0 || n < 4 {
        return f64::NAN;
    }
    let means: Vec<f64> = chains.iter().map(|c| mean(&c[..n])).collect();
    let acov = |t: usize| -> f64 {
        let mut s = 0.0;
        for (c, mu) in chains.iter().zip(&means) {
            let c = &c[..n];
            let mut a = 0.0;
            for i in 0..n - t {
                a += (c[i] - mu) * (c[i + t] - mu);
            }
            s += a / n as f64;
        }
        s / m as f64
    };
    let acov0 = acov(0);
    let nf = n as f64;
    let mean_var = acov0 * nf / (nf - 1.0);
    let mut var_plus = mean_var * (nf - 1.0) / nf;
    if m > 1 {
        var_plus += var_ddof1(&means);
    }
    if var_plus <= 0.0 {
        return f64::NAN;
    }
    let rho = |t: usize| 1.0 - (mean_var - acov(t)) / var_plus;
    let mut rho_t = vec![0.0; n];
    rho_t[0] = 1.0;
    let mut rho_even = 1.0;
    let mut rho_odd = rho(1);
    rho_t[1] = rho_odd;
    let mut t = 1;
    while t < n - 3 && rho_even + rho_odd > 0.0 {
        rho_even = rho(t + 1);
        rho_odd = rho(t + 2);
        if rho_even + rho_odd >= 0.0 {
            rho_t[t + 1] = rho_even;
            rho_t[t + 2] = rho_odd;
        }
        t += 2;
    }
    let max_t = t.saturating_sub(2);
    if rho_even > 0.0 && max_t + 1 < n {
        rho_t[max_t + 1] = rho_even;
    }
    let mut t = 1;
    while t + 2 <= max_t {
        if rho_t[t + 1] + rho_t[t + 2] > rho_t[t - 1] + rho_t[t] {
            rho_t[t + 1] = (rho_t[t - 1] + rho_t[t]) / 2.0;
            rho_t[t + 2] = rho_t[t + 1];
        }
        t += 2;
    }
    let total = (m * n) as f64;
    let extra = if max_t + 1 < n { rho_t[max_t + 1] } else { 0.0 };
    let tau = (-1.0 + 2.0 * rho_t[..=max_t].iter().sum::<f64>() + extra).max(1.0 / total.log10());
    total / tau
}

pub fn ess_bulk(chains: &[Vec<f64>]) -> f64 {
    ess_basic(&z_scale(&split_chains(chains)))
}

/// Minimum of the ESS of the 5% and 95% quantile indicators.
pub fn ess_tail(chains: &[Vec<f64>]) -> f64 {
    let all: Vec<f64> = chains.iter().flatten().copied().collect();
    let split = split_chains(chains);
    let mut worst = f64::INFINITY;
    for q in [0.05, 0.95] {
        let cut = quantile(&all, q);
        let ind: Vec<Vec<f64>> =
            split.iter().map(|c| c.iter().map(|&x| if x <= cut { 1.0 } else { 0.0 }).collect()).collect();
        worst = worst.min(ess_basic(&ind));
    }
    worst
}

/// Integrated autocorrelation time of the chain-averaged autocorrelation
/// function, with Sokal's window `M >= c τ(M)`, c = 5 (Goodman & Weare 2010; emcee).
pub fn integrated_autocorr_time(chains: &[Vec<f64>]) -> f64 {
    let n = chains.iter().map(|c| c.len()).min().unwrap_or(0);
    if n < 4 {
        return f64::NAN;
    }
    let m = chains.len() as f64;
    let centered: Vec<Vec<f64>> = chains
        .iter()
        .map(|c| {
            let mu = mean(&c[..n]);
            c[..n].iter().map(|x| x - mu).collect()
        })
        .collect();
    let acf = |t: usize| -> f64 {
        let mut s = 0.0;
        for c in &centered {
            let mut a = 0.0;
            for i in 0..n - t {
                a += c[i] * c[i + t];
            }
            s += a;
        }
        s / m
    };
    let a0 = acf(0);
    if a0 <= 0.0 {
        return f64::NAN;
    }
    let mut tau = 1.0;
    for t in 1..n {
        tau += 2.0 * acf(t) / a0;
        if t as f64 >= 5.0 * tau {
            break;
        }
    }
    tau
}

/// Linear-interpolation quantile (type 7, as numpy's default).
pub fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    quantile_sorted(&v, q)
}

pub fn quantile_sorted(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let pos = q * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    v[lo] + (pos - lo as f64) * (v[hi] - v[lo])
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn ar1_chains(m: usize, n: usize, phi: f64, offsets: &[f64], seed: u64) -> Vec<Vec<f64>> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..m)
            .map(|k| {
                let mut x = 0.0;
                let s = (1.0 - phi * phi).sqrt();
                (0..n)
                    .map(|_| {
                        let e: f64 = StandardNormal.sample(&mut rng);
                        x = phi * x + s * e;
                        x + offsets[k % offsets.len()]
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn iid_draws_have_full_ess_and_unit_rhat() {
        let c = ar1_chains(4, 2000, 0.0, &[0.0], 1);
        let ess = ess_bulk(&c);
        // For iid draws ESS ≈ 8000; its sampling spread is a few percent.
        assert!((ess - 8000.0).abs() < 800.0, "ess {ess}");
        assert!(rhat(&c) < 1.01);
    }

    #[test]
    fn ar1_ess_and_tau_match_theory() {
        // AR(1) with φ = 0.9: τ = (1+φ)/(1-φ) = 19.
        let c = ar1_chains(4, 20000, 0.9, &[0.0], 2);
        let tau = integrated_autocorr_time(&c);
        assert!((tau - 19.0).abs() < 3.0, "tau {tau}");
        let ess = ess_basic(&c);
        let expected = 80000.0 / 19.0;
        assert!((ess / expected - 1.0).abs() < 0.2, "ess {ess} vs {expected}");
    }

    #[test]
    fn shifted_chain_is_flagged() {
        let c = ar1_chains(4, 1000, 0.5, &[0.0, 0.0, 0.0, 1.0], 3);
        assert!(rhat(&c) > 1.05);
    }

    #[test]
    fn quantile_matches_numpy_type7() {
        let v = [3.0, 1.0, 2.0, 4.0];
        assert_eq!(quantile(&v, 0.5), 2.5);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert!((quantile(&v, 0.25) - 1.75).abs() < 1e-12);
    }
}
