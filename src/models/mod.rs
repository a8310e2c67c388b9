//! Built-in simulators and the interface the calibration sees them through.

pub mod ball_drop;

/// A deterministic model `η(x, θ)` for a set of named observables.
///
/// `predict` writes into a caller buffer so that a likelihood evaluation does
/// not allocate.
pub trait Simulator: Send + Sync {
    /// Names of the calibration parameters θ, in order.
    fn parameter_names(&self) -> Vec<String>;
    /// Names of the observables this model predicts.
    fn observable_names(&self) -> Vec<String>;
    /// `η(x_i, θ)` for observable `observable` (an index into `observable_names`).
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]);
}

/// The drag-free ball-drop model with parameters (g, v0) and known h0.
#[derive(Clone, Debug)]
pub struct BallDropModel {
    pub h0: f64,
}

impl Simulator for BallDropModel {
    fn parameter_names(&self) -> Vec<String> {
        vec!["g".into(), "v0".into()]
    }
    fn observable_names(&self) -> Vec<String> {
        ball_drop::OBSERVABLES.iter().map(|s| s.to_string()).collect()
    }
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let (g, v0) = (theta[0], theta[1]);
        for (o, &t) in out.iter_mut().zip(x) {
            *o = ball_drop::model_value(observable, self.h0, g, v0, t);
        }
    }
}
