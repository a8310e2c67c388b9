//! A correction of a model's output by formulas, y' = f(x, y, θ, φ): the
//! physics of the measurement a simulator leaves out (a counting loss
//! `rate/(1 + tau*rate)`, a background, a gain), declared as a candidate
//! of an emulated model without running the simulator again
//! (`[[candidates]] correction = { rate = "rate/(1 + tau*rate)" }`).
//!
//! The model's predictive covariance is carried through the correction to
//! first order: C' = J C J with J = diag(∂f/∂y) at each point, so an
//! emulator's uncertainty still widens the likelihood where it should.

use crate::engine::formula::{Formula, Scope};
use crate::engine::model::{LowRankModelCovariance, Simulator};
use anyhow::{bail, Result};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Most names a correction's scope holds (x, y, θ and φ): the values sit
/// in a stack array, so a prediction does not allocate.
const MAX_NAMES: usize = 64;

pub struct CorrectedModel {
    inner: Arc<dyn Simulator>,
    /// For each of `inner`'s observables, its correction if it has one.
    corrections: Vec<Option<Formula>>,
    /// θ of `inner`, then the correction's own parameters.
    names: Vec<String>,
    inner_parameters: usize,
}

impl CorrectedModel {
    /// `inner` with `corrections` (observable → formula of `x`, the
    /// observable's own name, θ and `extra`); `place` names where they were
    /// written, for errors.
    pub fn new(
        inner: Arc<dyn Simulator>,
        corrections: &BTreeMap<String, String>,
        extra: &[String],
        place: &str,
    ) -> Result<CorrectedModel> {
        let observables = inner.observable_names();
        let theta = inner.parameter_names();
        let names: Vec<String> = theta.iter().chain(extra).cloned().collect();
        if names.len() + 2 > MAX_NAMES {
            bail!("{place}: {} parameters; a correction takes at most {}", names.len(), MAX_NAMES - 2);
        }
        if let Some(o) = corrections.keys().find(|o| !observables.contains(o)) {
            bail!("{place}: correction.{o}: the model has no observable '{o}' (it has {})", observables.join(", "));
        }
        let mut out = Vec::new();
        for o in &observables {
            out.push(match corrections.get(o) {
                None => None,
                Some(text) => {
                    let scope = Scope::new(["x".to_string(), o.clone()].into_iter().chain(names.iter().cloned()));
                    Some(Formula::parse(text, &scope, &format!("{place}: correction.{o}"))?)
                }
            });
        }
        for (k, p) in extra.iter().enumerate() {
            if !out.iter().flatten().any(|f| f.uses(2 + theta.len() + k)) {
                bail!("{place}: parameter '{p}' is used by no correction");
            }
        }
        Ok(CorrectedModel { inner, corrections: out, names, inner_parameters: theta.len() })
    }

    /// The corrected value and ∂f/∂y at (x, y), θ and φ in `values[2..]`.
    fn value_and_slope(f: &Formula, values: &mut [f64; MAX_NAMES], x: f64, y: f64) -> (f64, f64) {
        values[0] = x;
        values[1] = y;
        let v = f.eval(values);
        let h = 1e-6 * y.abs().max(1e-3);
        values[1] = y + h;
        let up = f.eval(values);
        values[1] = y - h;
        let down = f.eval(values);
        (v, (up - down) / (2.0 * h))
    }

    fn values(&self, theta: &[f64]) -> [f64; MAX_NAMES] {
        let mut values = [0.0; MAX_NAMES];
        values[2..2 + theta.len()].copy_from_slice(theta);
        values
    }

    /// ∂f/∂y at each point of observable `o` (1 where it has no correction).
    fn slopes(&self, o: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let Some(f) = &self.corrections[o] else {
            out.fill(1.0);
            return;
        };
        self.inner.predict(o, x, &theta[..self.inner_parameters], out);
        let mut values = self.values(theta);
        for (i, y) in out.iter_mut().enumerate() {
            *y = CorrectedModel::value_and_slope(f, &mut values, x[i], *y).1;
        }
    }
}

thread_local! {
    /// Scratch for the covariance methods: one observable's slopes (or the
    /// points' scales) and its uncorrected covariance, reused across calls.
    static SCRATCH: RefCell<(Vec<f64>, Vec<f64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

impl Simulator for CorrectedModel {
    fn parameter_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn observable_names(&self) -> Vec<String> {
        self.inner.observable_names()
    }

    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        self.inner.predict(observable, x, &theta[..self.inner_parameters], out);
        if let Some(f) = &self.corrections[observable] {
            let mut values = self.values(theta);
            for (i, y) in out.iter_mut().enumerate() {
                values[0] = x[i];
                values[1] = *y;
                *y = f.eval(&values);
            }
        }
    }

    fn check_inputs(&self, observable: usize, x: &[f64]) -> Result<()> {
        self.inner.check_inputs(observable, x)
    }

    fn note_measurements(&self, observable: usize, values: &[f64], errors: &[f64]) {
        self.inner.note_measurements(observable, values, errors)
    }

    fn numerics(&self) -> Option<String> {
        self.inner.numerics()
    }

    fn predicts_any_x(&self) -> bool {
        self.inner.predicts_any_x()
    }

    fn has_model_covariance(&self) -> bool {
        self.inner.has_model_covariance()
    }

    fn failures(&self) -> u64 {
        self.inner.failures()
    }

    fn add_model_covariance(&self, observable: usize, x: &[f64], theta: &[f64], inv_scale2: f64, lower: &mut [f64]) {
        let n = x.len();
        SCRATCH.with(|s| {
            let (slopes, c) = &mut *s.borrow_mut();
            slopes.resize(n, 0.0);
            c.clear();
            c.resize(n * n, 0.0);
            self.slopes(observable, x, theta, slopes);
            self.inner.add_model_covariance(observable, x, &theta[..self.inner_parameters], inv_scale2, c);
            for j in 0..n {
                for i in j..n {
                    lower[i + j * n] += slopes[i] * slopes[j] * c[i + j * n];
                }
            }
        });
    }

    fn model_covariance_spans_observables(&self) -> bool {
        self.inner.model_covariance_spans_observables()
    }

    fn add_joint_model_covariance(
        &self,
        points: &[(usize, f64)],
        inv_scales: &[f64],
        theta: &[f64],
        lower: &mut [f64],
    ) {
        SCRATCH.with(|s| {
            let scales = &mut s.borrow_mut().0;
            self.point_scales(points, inv_scales, theta, scales);
            self.inner.add_joint_model_covariance(points, scales, &theta[..self.inner_parameters], lower);
        });
    }

    fn joint_model_low_rank(&self, points: &[(usize, f64)], offsets: &[usize]) -> Option<LowRankModelCovariance> {
        self.inner.joint_model_low_rank(points, offsets)
    }

    fn joint_model_factors(
        &self,
        points: &[(usize, f64)],
        inv_scales: &[f64],
        theta: &[f64],
        g: &mut [f64],
        w: &mut [f64],
    ) {
        SCRATCH.with(|s| {
            let scales = &mut s.borrow_mut().0;
            self.point_scales(points, inv_scales, theta, scales);
            self.inner.joint_model_factors(points, scales, &theta[..self.inner_parameters], g, w);
        });
    }
}

impl CorrectedModel {
    /// Each point's scale times its slope ∂f/∂y: the joint covariance's
    /// diagonal factor G carries the correction's Jacobian.
    fn point_scales(&self, points: &[(usize, f64)], inv_scales: &[f64], theta: &[f64], out: &mut Vec<f64>) {
        out.clear();
        out.extend_from_slice(inv_scales);
        let mut y = [0.0];
        let mut values = self.values(theta);
        for (k, &(o, x)) in points.iter().enumerate() {
            if let Some(f) = &self.corrections[o] {
                self.inner.predict(o, &[x], &theta[..self.inner_parameters], &mut y);
                out[k] *= CorrectedModel::value_and_slope(f, &mut values, x, y[0]).1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// y = a·x with a variance of (0.1·y)² at each point, independent.
    struct Line;

    impl Simulator for Line {
        fn parameter_names(&self) -> Vec<String> {
            vec!["a".into()]
        }
        fn observable_names(&self) -> Vec<String> {
            vec!["rate".into(), "other".into()]
        }
        fn predict(&self, _o: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
            for (o, x) in out.iter_mut().zip(x) {
                *o = theta[0] * x;
            }
        }
        fn has_model_covariance(&self) -> bool {
            true
        }
        fn add_model_covariance(&self, _o: usize, x: &[f64], theta: &[f64], s: f64, lower: &mut [f64]) {
            let n = x.len();
            for i in 0..n {
                lower[i + i * n] += s * (0.1 * theta[0] * x[i]).powi(2);
            }
        }
    }

    #[test]
    fn a_dead_time_correction_changes_the_prediction_and_its_covariance() {
        let corrections = BTreeMap::from([("rate".to_string(), "rate/(1 + tau*rate)".to_string())]);
        let m =
            CorrectedModel::new(Arc::new(Line), &corrections, &["tau".into()], "c.toml: [[candidates]] dt").unwrap();
        assert_eq!(m.parameter_names(), ["a", "tau"]);
        let (x, theta) = ([1.0, 10.0], [5.0, 0.01]);
        let mut out = [0.0; 2];
        m.predict(0, &x, &theta, &mut out);
        for (o, x) in out.iter().zip(x) {
            let y = 5.0 * x;
            assert!((o - y / (1.0 + 0.01 * y)).abs() < 1e-12);
        }
        // The other observable is left as it is.
        m.predict(1, &x, &theta, &mut out);
        assert_eq!(out, [5.0, 50.0]);
        // C' = J C J, J = 1/(1 + tau y)².
        let mut lower = [0.0; 4];
        m.add_model_covariance(0, &x, &theta, 1.0, &mut lower);
        for (i, x) in x.iter().enumerate() {
            let y = 5.0 * x;
            let want = (0.1 * y).powi(2) / (1.0 + 0.01 * y).powi(4);
            assert!((lower[i + 2 * i] - want).abs() < 1e-6 * want, "{} against {want}", lower[i + 2 * i]);
        }
    }

    #[test]
    fn a_correction_names_what_is_wrong() {
        let bad = |text: &str, extra: &[String]| {
            let c = BTreeMap::from([("rate".to_string(), text.to_string())]);
            format!("{:#}", CorrectedModel::new(Arc::new(Line), &c, extra, "c.toml: [[candidates]] dt").err().unwrap())
        };
        assert!(bad("rate/(1 + k*rate)", &["tau".into()]).contains("unknown name 'k'"));
        assert!(bad("rate", &["tau".into()]).contains("'tau' is used by no correction"));
        let c = BTreeMap::from([("count".to_string(), "count".to_string())]);
        let e = CorrectedModel::new(Arc::new(Line), &c, &[], "c.toml").err().unwrap().to_string();
        assert!(e.contains("no observable 'count'") && e.contains("rate, other"), "{e}");
    }
}
