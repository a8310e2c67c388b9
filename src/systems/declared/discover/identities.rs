//! Whether a rate that reads as a kinematic identity (`dx/dt = ±v`) is one
//! on these data. A definition is exact, so the search never adds a term to
//! it; but a law written short reads the same way: a glider's angle in its
//! own units obeys dθ/dt = v − cos θ / v, and declared without the second
//! term it is dθ/dt = v. Where x and v are both observed, x's rate read off
//! its smoothed series must equal ±v within the errors if the rate is a
//! definition; far beyond them, it is a law, and the search may complete it.

use super::along::{observed_series, RATE_FLOOR};
use super::grammar::kinematic_identity;
use crate::engine::formula::notation::{parse, Expr};
use crate::engine::model::{ScreeningBlock, ScreeningData};
use crate::systems::declared::declaration::Declared;

/// The mean departure of x's rate from ±v, in standard deviations, beyond
/// which the identity is read as a law. A mean, not a root mean square:
/// where a state oscillates, the smoother's derivative lags and overshoots
/// it and departs from a true definition by up to 9σ at single points
/// (root mean square 4.3 on one ODEBench pendulum), but about zero on
/// average; a term left out of the law (a constant source) shifts the
/// rate one way all along. Taking a definition for a law would add terms
/// to what is exact, so the bar is high; a left-out term that oscillates
/// about zero is not found this way.
const CONTRADICTED_BIAS: f64 = 5.0;
/// Fewer points than this prove nothing either way.
const MIN_POINTS: usize = 8;

/// A rate read as a law because the data contradict it as a definition.
pub(super) struct Contradicted {
    /// The state whose rate it is.
    pub state: usize,
    /// The mean of x's rate − (±v), in standard deviations.
    pub bias_sigma: f64,
}

/// Every rate of `d` that reads as a kinematic identity and that the data contradict.
pub(super) fn contradicted(d: &Declared, data: &ScreeningData) -> Vec<Contradicted> {
    let series = observed_series(d, data);
    let mut out = Vec::new();
    for (k, state) in d.states.iter().enumerate() {
        let Some((v, sign)) = kinematic_identity(d, &state.name, &state.rate.text) else { continue };
        let (Some((t, x)), Some(vb)) = (series.get(&k), observed(d, data, v)) else { continue };
        if vb.x != t.as_slice() || t.len() < MIN_POINTS {
            continue;
        }
        let floor = RATE_FLOOR * x.rate.iter().fold(0.0f64, |m, r| m.max(r.abs()));
        let z: Vec<f64> = (0..t.len())
            .map(|i| {
                let sd = (x.rate_sd[i].powi(2) + floor.powi(2) + vb.error[i].powi(2)).sqrt();
                (x.rate[i] - sign * vb.y[i]) / sd
            })
            .collect();
        let bias_sigma = z.iter().sum::<f64>() / z.len() as f64;
        if bias_sigma.abs() > CONTRADICTED_BIAS {
            out.push(Contradicted { state: k, bias_sigma });
        }
    }
    out
}

/// The data's block observing state `k` as itself, if any.
fn observed<'d>(d: &Declared, data: &'d ScreeningData, k: usize) -> Option<&'d ScreeningBlock<'d>> {
    data.blocks.iter().find(|b| {
        d.observables
            .get(b.model_index)
            .is_some_and(|(_, f)| matches!(parse(&f.text), Ok(Expr::Name(n)) if n == d.states[k].name))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::systems::declared::declaration::{State, Written};

    fn written(text: &str) -> Written {
        Written { text: text.into(), place: "test".into() }
    }

    /// x and v observed at 40 times, with dx/dt = v declared.
    fn model() -> Declared {
        let state = |n: &str, rate: &str| State {
            name: n.into(),
            initial: written("0"),
            rate: written(rate),
            law_by_data: false,
        };
        Declared {
            input: "t".into(),
            parameters: Vec::new(),
            declared_at: Vec::new(),
            bounds: Vec::new(),
            constants: Vec::new(),
            observables: vec![("x".into(), written("x")), ("v".into(), written("v"))],
            states: vec![state("x", "v"), state("v", "-2*x")],
            t0: 0.0,
            solver: Default::default(),
            shooting: None,
        }
    }

    /// The identity's verdict on x = sin t (+ `drift`·t, a rate v does not
    /// carry) and v = cos t, with errors of 0.01.
    fn verdict(drift: f64) -> Vec<usize> {
        let t: Vec<f64> = (1..=40).map(|i| 0.25 * i as f64).collect();
        let x: Vec<f64> = t.iter().map(|t| t.sin() + drift * t).collect();
        let v: Vec<f64> = t.iter().map(|t| t.cos()).collect();
        let error = vec![0.01; t.len()];
        let block = |k: usize, y: &'static [f64]| ScreeningBlock {
            model_index: k,
            x: Box::leak(t.clone().into_boxed_slice()),
            y,
            error: Box::leak(error.clone().into_boxed_slice()),
            covariance_factor: None,
        };
        let (x, v): (&'static [f64], &'static [f64]) =
            (Box::leak(x.into_boxed_slice()), Box::leak(v.into_boxed_slice()));
        let data = ScreeningData { blocks: vec![block(0, x), block(1, v)], theta: Vec::new(), bounds: Vec::new() };
        contradicted(&model(), &data).iter().map(|c| c.state).collect()
    }

    #[test]
    fn a_definition_the_data_keep_stays_one_and_one_they_break_is_a_law() {
        assert!(verdict(0.0).is_empty(), "dx/dt = v holds on these data");
        // A drift of 0.3 in x's rate, all along, is 30 of v's errors: a law written short.
        assert_eq!(verdict(0.3), [0]);
    }
}
