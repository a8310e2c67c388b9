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
    /// How the explanation reads to a physicist: its formula, what it
    /// means, and its parameters at the screening's fit.
    fn reading(&self) -> String;
    /// The readings of the explanations merged into this one.
    fn readings_mut(&mut self) -> &mut Vec<String>;
}

/// `other` merged into `kept`: its reading, and those merged into it
/// before, become readings of `kept` (one explanation, each reading named).
fn merge<E: Explanation>(kept: &mut E, mut other: E) {
    let mut read = vec![other.reading()];
    read.append(other.readings_mut());
    let own = kept.reading();
    let readings = kept.readings_mut();
    for r in read {
        if r != own && !readings.contains(&r) {
            readings.push(r);
        }
    }
}

/// Of two fits whose predictions differ by less than the data can pay for
/// (their difference standardized by the data's errors or covariance), the
/// simpler stands for both, and the other is kept as its reading
/// (`Explanation::readings_mut`), so that the verdict names both. Between fits of different numbers of
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
            Some(i) if s.complexity() < kept[i].complexity() => {
                let richer = std::mem::replace(&mut kept[i], s);
                merge(&mut kept[i], richer);
            }
            Some(i) => merge(&mut kept[i], s),
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::model::ScreeningBlock;

    /// A screened form: its name, parameters added, and its prediction at the points.
    struct Form {
        name: &'static str,
        parameters: usize,
        fitted: Fitted,
        readings: Vec<String>,
    }

    impl Explanation for Form {
        fn fitted(&self) -> &Fitted {
            &self.fitted
        }
        fn added_parameters(&self) -> usize {
            self.parameters
        }
        fn complexity(&self) -> (usize, usize, usize, usize) {
            (self.parameters, 1, 0, 0)
        }
        fn reading(&self) -> String {
            self.name.to_string()
        }
        fn readings_mut(&mut self) -> &mut Vec<String> {
            &mut self.readings
        }
    }

    fn form(name: &'static str, parameters: usize, prediction: &[f64]) -> Form {
        Form {
            name,
            parameters,
            fitted: Fitted { phi: Vec::new(), chi2: 0.0, prediction: prediction.to_vec() },
            readings: Vec::new(),
        }
    }

    #[test]
    fn a_merged_form_is_kept_as_a_reading_of_the_simpler() {
        let (x, y, error) = ([0.0; 4], [0.0; 4], [1.0; 4]);
        let block = ScreeningBlock { model_index: 0, x: &x, y: &y, error: &error, covariance_factor: None };
        let data = ScreeningData { blocks: vec![block], theta: Vec::new(), bounds: Vec::new() };
        // A free power ranked first, a cube 0.5 apart in χ² (below ln 4, the
        // price of its exponent), a square with as many parameters 0.8 from
        // the cube (below SAME_FIT), and a line far from all three.
        let ranked = vec![
            form("free power", 2, &[1.0, 2.0, 3.0, 4.0]),
            form("cube", 1, &[1.5, 2.0, 3.0, 4.0]),
            form("square", 1, &[1.5, 2.0, 3.0, 3.1]),
            form("line", 1, &[9.0, 9.0, 9.0, 9.0]),
        ];
        let kept = distinct(ranked, &data);
        let names: Vec<&str> = kept.iter().map(|k| k.name).collect();
        assert_eq!(names, ["cube", "line"]);
        // The richer form the cube replaced, and the square merged into the cube.
        assert_eq!(kept[0].readings, ["free power", "square"]);
        assert!(kept[1].readings.is_empty());
    }
}
