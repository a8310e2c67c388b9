//! Tempering: the next inverse temperature β from the weights' effective
//! sample size, the floor below which a particle has no weight, and
//! multinomial resampling.

use super::*;

/// A particle whose log-likelihood is this many nats over β below the best
/// seen has relative weight below e^-200 at β: none to notice. The target
/// at β is `π L^β` times the indicator of log L ≥ that floor; as β and the
/// best seen grow, the floor rises, so each target's support lies in the
/// last one's (as SMC's reweighting needs), and at β = 1 the region left
/// out holds at most e^-200 of the best point's likelihood per unit of
/// prior mass: the evidence and the posterior change by less than any
/// Monte Carlo error. What it buys: a likelihood told the floor may stop
/// computing a point below it (`LogLikelihood::log_likelihood_above`),
/// such as an ODE that a proposal drives far from the data.
pub(super) const FLOOR_NATS: f64 = 200.0;

/// The floor at β given the best log-likelihood seen (−∞ at β = 0).
pub(super) fn floor_at(best: f64, beta: f64) -> f64 {
    if beta > 0.0 && best.is_finite() {
        best - FLOOR_NATS / beta
    } else {
        f64::NEG_INFINITY
    }
}

/// Log-likelihoods below `floor` set to −∞: the target there is zero.
pub(super) fn drop_below(loglik: &mut [f64], floor: f64) {
    loglik.iter_mut().filter(|l| **l < floor).for_each(|l| *l = f64::NEG_INFINITY);
}

pub fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// ESS of weights `exp(delta * loglik)`, relative to nothing (absolute count).
pub(super) fn weight_ess(loglik: &[f64], max_ll: f64, delta: f64) -> f64 {
    let (mut s, mut s2) = (0.0, 0.0);
    for &l in loglik {
        let w = (delta * (l - max_ll)).exp();
        s += w;
        s2 += w * w;
    }
    if s2 == 0.0 {
        0.0
    } else {
        s * s / s2
    }
}

/// Largest increment Δ ≤ 1 - β whose weights keep ESS ≥ target.
pub(super) fn next_increment(loglik: &[f64], beta: f64, target_ess: f64) -> f64 {
    let max_ll = loglik.iter().cloned().filter(|l| l.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    let remaining = 1.0 - beta;
    if weight_ess(loglik, max_ll, remaining) >= target_ess {
        return remaining;
    }
    let (mut lo, mut hi) = (0.0, remaining);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if weight_ess(loglik, max_ll, mid) >= target_ess {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    // Guarantee progress even when a single particle dominates.
    lo.max(1e-12 * remaining).min(remaining)
}

/// Multinomial resampling via sorted uniforms: ancestors come out sorted, so
/// copies of one particle are adjacent.
pub(super) fn multinomial_ancestors<R: Rng>(weights: &[f64], rng: &mut R) -> Vec<usize> {
    let n = weights.len();
    // Sorted uniforms from normalized cumulative exponential spacings.
    let mut cum = Vec::with_capacity(n + 1);
    let mut acc = 0.0;
    for _ in 0..=n {
        let u: f64 = rng.random();
        acc += -(1.0 - u).ln();
        cum.push(acc);
    }
    let total = cum[n];
    let mut out = Vec::with_capacity(n);
    let mut j = 0;
    let mut cw = weights[0];
    for &c in cum.iter().take(n) {
        let u = c / total;
        while u > cw && j + 1 < n {
            j += 1;
            cw += weights[j];
        }
        out.push(j);
    }
    out
}

pub(super) fn reindex(x: &[f64], dim: usize, ancestors: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    for &a in ancestors {
        out.extend_from_slice(&x[a * dim..(a + 1) * dim]);
    }
    out
}

/// Lee & Whiteley (2018): Var(Ẑ)/Z² ≈ 1 - (n/(n-1))^T Σ_{i,j: E_i≠E_j} W_i W_j,
/// with E_i particle i's ancestor at β = 0 (`eve`) after T tempering steps.
pub(super) fn relative_variance(eve: &[usize], stages: usize, weights: &[f64]) -> f64 {
    let nf = eve.len() as f64;
    let mut eve_mass = vec![0.0; eve.len()];
    for (e, w) in eve.iter().zip(weights) {
        eve_mass[*e] += w;
    }
    let same_eve: f64 = eve_mass.iter().map(|s| s * s).sum();
    1.0 - (nf / (nf - 1.0)).powi(stages as i32) * (1.0 - same_eve)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn multinomial_ancestors_are_sorted_and_follow_weights() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let w = [0.1, 0.0, 0.6, 0.3];
        let mut counts = [0usize; 4];
        let reps = 2000;
        for _ in 0..reps {
            let a = multinomial_ancestors(&w, &mut rng);
            assert!(a.windows(2).all(|p| p[0] <= p[1]));
            for i in a {
                counts[i] += 1;
            }
        }
        let total = (reps * 4) as f64;
        for k in 0..4 {
            let p = counts[k] as f64 / total;
            // Binomial standard error of p over 8000 draws is below 0.006; allow 4σ.
            assert!((p - w[k]).abs() < 0.024, "k={k}: {p} vs {}", w[k]);
        }
        assert_eq!(counts[1], 0);
    }
}
