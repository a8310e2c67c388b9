//! One explanation per way of fitting the data: the screening's rule for
//! when two screened terms (or corrections) are the same explanation.

use crate::engine::model::fit::Fitted;
use crate::engine::model::{standardize_blocks, ScreeningData};

/// Two fits with as many parameters whose predictions differ by less than
/// this χ² are one explanation: the data cannot tell them apart by even
/// one standard deviation. When every merge reached ln N, a simpler
/// near-equivalent with as many parameters stood in for a better fit it
/// was not: `c*T*abs(T)` replaced `c*T^4` in screening at 5.5–8.6σ, was
/// calibrated alone and named, where both confirmed make the verdict
/// `ambiguous` with the measurement that separates them.
pub const SAME_FIT: f64 = 1.0;

/// A screened explanation as `distinct` compares them.
pub trait Explanation {
    fn fitted(&self) -> &Fitted;
    /// Parameters it adds to θ.
    fn added_parameters(&self) -> usize;
    /// Which is simpler (the smaller): parameters, then terms, then
    /// operations, then place in the grammar.
    fn complexity(&self) -> (usize, usize, usize, usize);
}

/// Of two fits whose predictions differ by less than the data can pay for
/// (their difference standardized by the data's errors or covariance), the
/// simpler stands for both. Between fits of different numbers of
/// parameters that is a χ² of ln N, BIC's price of one parameter: where the
/// data cannot pay for the exponent, `c*v*abs(v)` stands for `c*abs(v)^p`
/// and for `c*(abs(v)^p - abs(v0)^p)` with v0 near 0. Between fits with as
/// many parameters there is no parameter to pay for: they are one only
/// below `SAME_FIT` (a weak dead time's `rate/(1 + c*rate)` and
/// `rate + c*rate^2` are one), and otherwise rival explanations the
/// calibrations weigh (`c*T^4` and `c*T*abs(T)`).
pub fn distinct<E: Explanation>(ranked: Vec<E>, data: &ScreeningData) -> Vec<E> {
    let points: usize = data.blocks.iter().map(|b| b.x.len()).sum();
    let apart = |a: &E, b: &E| {
        let more_parameters = a.added_parameters() != b.added_parameters();
        let threshold = if more_parameters { (points as f64).ln() } else { SAME_FIT };
        let mut d: Vec<f64> = a.fitted().prediction.iter().zip(&b.fitted().prediction).map(|(a, b)| a - b).collect();
        standardize_blocks(&data.blocks, &mut d, 1.0);
        d.iter().map(|v| v.powi(2)).sum::<f64>() >= threshold
    };
    let mut kept: Vec<E> = Vec::new();
    for s in ranked {
        match kept.iter().position(|k| !apart(k, &s)) {
            None => kept.push(s),
            Some(i) if s.complexity() < kept[i].complexity() => kept[i] = s,
            Some(_) => {}
        }
    }
    kept
}
