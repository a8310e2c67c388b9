//! The measurement that would separate two candidates still standing.
//!
//! Where two fits explain the data alike, the next experiment should go where
//! their posterior predictive distributions of a new measurement differ most.
//! If candidate A is right, n new values at one x change the log Bayes factor
//! of A over B by log p_A(ȳ | data) − log p_B(ȳ | data) (for Gaussian errors
//! the rest of the likelihood is the same under both), whose expectation
//! under A is the Kullback–Leibler divergence KL(p_A ‖ p_B). Each predictive
//! is approximated by a normal: the fit's η band, N(m, s²), plus the mean's
//! error σ²/n. As n grows the gain saturates at KL(N(m_A, s_A²) ‖ N(m_B,
//! s_B²)): repeats cannot beat the fits' own uncertainty at that x.
//!
//! The suggestion is the observable and x needing the fewest repeats for the
//! expected log BF to become decisive whichever of the two is right (the
//! current lead counted), ties going to the larger gain; when no x can settle
//! it within `MAX_REPEATS`, the x with the largest gain from `MAX_REPEATS`
//! repeats, and the statement says so.

use crate::engine::calibrate::{Calibration, Problem};

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Suggestion {
    pub observable: String,
    pub x: f64,
    /// The assumed error of the new measurement: the data's errors
    /// interpolated linearly in x (the nearest one's beyond the data).
    pub error: f64,
    /// The two candidates it separates, and each one's predictive mean and
    /// sd of the model at x (without the measurement error).
    pub candidates: [String; 2],
    pub predicted_mean: [f64; 2],
    pub predicted_sd: [f64; 2],
    /// How many measurements there are expected to make the verdict
    /// decisive whichever is right; None: not within `MAX_REPEATS`.
    pub repeats: Option<usize>,
    /// Expected change of the log Bayes factor, in favour of the right one,
    /// from that many measurements (or `MAX_REPEATS`): if the first is
    /// right, if the second is.
    pub expected_gain: [f64; 2],
}

/// The most repeats of one measurement worth suggesting.
pub const MAX_REPEATS: usize = 100;

/// What the new measurements must achieve: the first candidate leads by
/// `lead` now, and a verdict needs a lead above `decisive`.
#[derive(Clone, Copy, Debug)]
pub struct Goal {
    pub lead: f64,
    pub decisive: f64,
}

/// One fit's predictive for a new measurement, by observable and x.
pub struct Fit<'a> {
    pub name: &'a str,
    pub problem: &'a Problem,
    pub calibration: &'a Calibration,
}

/// KL(N(m1, v1) ‖ N(m2, v2)).
pub fn kl_normal(m1: f64, v1: f64, m2: f64, v2: f64) -> f64 {
    0.5 * ((v2 / v1).ln() + (v1 + (m1 - m2) * (m1 - m2)) / v2 - 1.0)
}

/// Linear interpolation of the errors over sorted `xs`, constant beyond.
fn error_at(xs: &[f64], errors: &[f64], x: f64) -> f64 {
    let k = xs.partition_point(|&v| v < x);
    if k == 0 {
        return errors[0];
    }
    if k == xs.len() {
        return errors[xs.len() - 1];
    }
    let t = (x - xs[k - 1]) / (xs[k] - xs[k - 1]);
    errors[k - 1] + t * (errors[k] - errors[k - 1])
}

/// Expected gains (A right, B right) from `n` measurements of error `error`.
fn gains(n: usize, error: f64, (ma, sa): (f64, f64), (mb, sb): (f64, f64)) -> [f64; 2] {
    let e2 = error * error / n as f64;
    let (va, vb) = (sa * sa + e2, sb * sb + e2);
    [kl_normal(ma, va, mb, vb), kl_normal(mb, vb, ma, va)]
}

/// The fewest repeats (≤ `MAX_REPEATS`) after which the expected log BF is
/// decisive whichever of the two is right.
fn repeats_needed(goal: Goal, error: f64, a: (f64, f64), b: (f64, f64)) -> Option<usize> {
    (1..=MAX_REPEATS).find(|&n| {
        let g = gains(n, error, a, b);
        goal.lead + g[0] > goal.decisive && g[1] - goal.lead > goal.decisive
    })
}

/// The best measurement to separate `a` from `b`, among the x where both
/// fits predict (the prediction grid and the data points).
pub fn suggest(a: &Fit, b: &Fit, goal: Goal) -> Option<Suggestion> {
    let mut best: Option<((usize, f64), Suggestion)> = None;
    for block in &a.problem.likelihood.blocks {
        for ra in a.calibration.predictions.iter().filter(|r| r.observable == block.name) {
            let Some(rb) = b
                .calibration
                .predictions
                .iter()
                .find(|r| r.observable == ra.observable && r.kind == ra.kind && r.x == ra.x)
            else {
                continue;
            };
            let error = error_at(&block.x, &block.error, ra.x);
            // The 16–84% half-width is the sd for a normal band.
            let pa = (ra.model[2], 0.5 * (ra.model[3] - ra.model[1]));
            let pb = (rb.model[2], 0.5 * (rb.model[3] - rb.model[1]));
            let repeats = repeats_needed(goal, error, pa, pb);
            let gain = gains(repeats.unwrap_or(MAX_REPEATS), error, pa, pb);
            // Fewer repeats first, then the larger of the smaller gains.
            let score = (repeats.unwrap_or(usize::MAX), -gain[0].min(gain[1]));
            if !score.1.is_finite() || best.as_ref().is_some_and(|(s, _)| *s <= score) {
                continue;
            }
            let suggestion = Suggestion {
                observable: block.name.clone(),
                x: ra.x,
                error,
                candidates: [a.name.to_string(), b.name.to_string()],
                predicted_mean: [pa.0, pb.0],
                predicted_sd: [pa.1, pb.1],
                repeats,
                expected_gain: gain,
            };
            best = Some((score, suggestion));
        }
    }
    best.map(|(_, s)| s)
}

/// `v` to `digits` significant figures, in fixed notation.
fn sig(v: f64, digits: i32) -> String {
    let magnitude = if v == 0.0 || !v.is_finite() { 0 } else { v.abs().log10().floor() as i32 };
    format!("{:.*}", (digits - 1 - magnitude).clamp(0, 12) as usize, v)
}

/// "to separate them, measure work at x = 6.000 (…) 3 times: …".
pub fn phrase(s: &Suggestion) -> String {
    let [a, b] = &s.candidates;
    // Laws that agree wherever they can be measured are not told apart by any repeat.
    if s.repeats.is_none() && s.expected_gain[0].max(s.expected_gain[1]) < 0.1 {
        return format!(
            "no measurement of these observables in the prediction range separates {a} from {b}: they predict alike everywhere (expected log BF gain below 0.1 even from {MAX_REPEATS} repeats at the best x, {} = {:.3})",
            s.observable, s.x
        );
    }
    let predicts = |k: usize| {
        format!("{} predicts {} ± {}", s.candidates[k], sig(s.predicted_mean[k], 4), sig(s.predicted_sd[k], 2))
    };
    let how_often = match s.repeats {
        Some(1) => "once".to_string(),
        Some(n) => format!("{n} times"),
        None => format!("{MAX_REPEATS} times (no measurement in the prediction range is expected to settle it with fewer or more; widen [predictions] or measure another observable)"),
    };
    format!(
        "to separate them, measure {} at x = {:.3} {how_often}, each with an error of {} (interpolated from the data's): {}, {}; this is expected to move log BF by {:.1} towards {a} if it is right, or by {:.1} towards {b}",
        s.observable,
        s.x,
        sig(s.error, 3),
        predicts(0),
        predicts(1),
        s.expected_gain[0],
        s.expected_gain[1],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn kl_of_normals_matches_monte_carlo_and_closed_forms() {
        // Equal variances: KL = Δ²/(2v); identical normals: 0.
        assert!((kl_normal(1.0, 4.0, 3.0, 4.0) - 0.5).abs() < 1e-12);
        assert_eq!(kl_normal(0.3, 2.0, 0.3, 2.0), 0.0);
        // Unequal: E_p[log p − log q] by 200 000 draws, within 4 standard errors.
        let (m1, v1, m2, v2): (f64, f64, f64, f64) = (0.0, 1.0, 0.5, 2.25);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let p = Normal::new(m1, v1.sqrt()).unwrap();
        let logn = |y: f64, m: f64, v: f64| -0.5 * ((y - m) * (y - m) / v + v.ln());
        let n = 200_000;
        let terms: Vec<f64> = (0..n).map(|_| p.sample(&mut rng)).map(|y| logn(y, m1, v1) - logn(y, m2, v2)).collect();
        let mc = terms.iter().sum::<f64>() / n as f64;
        let se = (terms.iter().map(|t| (t - mc) * (t - mc)).sum::<f64>() / (n - 1) as f64 / n as f64).sqrt();
        let exact = kl_normal(m1, v1, m2, v2);
        assert!((mc - exact).abs() < 4.0 * se, "MC {mc} ± {se} vs closed form {exact}");
    }

    #[test]
    fn repeats_help_until_the_fits_own_spread_dominates() {
        // Equal sds s and error σ: gain(n) = Δ²/(2(s² + σ²/n)), both ways.
        let (a, b) = ((0.0, 0.1), (1.0, 0.1));
        let g = gains(4, 0.4, a, b);
        assert!((g[0] - 1.0 / (2.0 * (0.01 + 0.04))).abs() < 1e-12 && (g[0] - g[1]).abs() < 1e-12);
        // A lead above 3 from 0: 1/(2(0.01 + 0.16/n)) is 2.94 at n = 1, 5.56 at n = 2.
        assert_eq!(repeats_needed(Goal { lead: 0.0, decisive: 3.0 }, 0.4, a, b), Some(2));
        // A close pair: Δ = 0.3 saturates at 0.3²/(2 × 0.01) = 4.5 < 3 + 2 = 5: never.
        assert_eq!(repeats_needed(Goal { lead: 0.0, decisive: 5.0 }, 0.4, (0.0, 0.1), (0.3, 0.1)), None);
        // Reachable: 0.09/(2(0.01 + 0.16/n)) > 2.8 ⇔ 0.16/n < 0.006071 ⇔ n > 26.35.
        assert_eq!(repeats_needed(Goal { lead: 0.0, decisive: 2.8 }, 0.4, (0.0, 0.1), (0.3, 0.1)), Some(27));
        // A current lead of 1 for A: B must gain 1 more, A 1 less. n: 0.045/(0.01 + 0.16/n) > 4 ⇔ 0.16/n < 0.00125 ⇔ n > 128.
        assert_eq!(repeats_needed(Goal { lead: 1.0, decisive: 3.0 }, 0.4, (0.0, 0.1), (0.3, 0.1)), None);
    }

    #[test]
    fn figures_are_rounded_to_significant_digits() {
        assert_eq!(sig(3.04567, 4), "3.046");
        assert_eq!(sig(0.0123456, 2), "0.012");
        assert_eq!(sig(1234.4, 2), "1234");
        assert_eq!(sig(0.0, 3), "0.00");
    }

    #[test]
    fn errors_are_interpolated_inside_and_held_beyond_the_data() {
        let (xs, es) = ([1.0, 2.0, 4.0], [0.1, 0.3, 0.5]);
        assert_eq!(error_at(&xs, &es, 0.0), 0.1);
        assert!((error_at(&xs, &es, 1.5) - 0.2).abs() < 1e-12);
        assert!((error_at(&xs, &es, 3.0) - 0.4).abs() < 1e-12);
        assert_eq!(error_at(&xs, &es, 9.0), 0.5);
    }
}
