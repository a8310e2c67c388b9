//! Built-in simulators and the interface the calibration sees them through.

pub mod ball_drop;
pub mod emulated;
pub mod heavy_ion;

pub use emulated::EmulatedModel;

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

    /// Rejects measurement points the model cannot predict (an emulator knows only its bins).
    fn check_inputs(&self, _observable: usize, _x: &[f64]) -> anyhow::Result<()> {
        Ok(())
    }
    /// Whether `predict` works at any x (false for emulators: no prediction grid).
    fn predicts_any_x(&self) -> bool {
        true
    }
    /// Whether the model carries its own predictive covariance (emulators).
    fn has_model_covariance(&self) -> bool {
        false
    }
    /// Adds `inv_scale2 ×` the model's predictive covariance at (x, θ) to the
    /// lower triangle of `lower` (column-major n × n).
    fn add_model_covariance(&self, _observable: usize, _x: &[f64], _theta: &[f64], _inv_scale2: f64, _lower: &mut [f64]) {}
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

/// The ball drop augmented with one candidate correction: parameters
/// (g, v0, <candidate parameter>), solved by RK4.
#[derive(Clone, Debug)]
pub struct AugmentedBallDrop {
    pub h0: f64,
    pub candidate: ball_drop::Candidate,
}

impl Simulator for AugmentedBallDrop {
    fn parameter_names(&self) -> Vec<String> {
        vec!["g".into(), "v0".into(), self.candidate.parameter.into()]
    }
    fn observable_names(&self) -> Vec<String> {
        ball_drop::OBSERVABLES.iter().map(|s| s.to_string()).collect()
    }
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let setup = ball_drop::BallDropSetup { h0: self.h0, g: theta[0], v0: theta[1] };
        let forces = (self.candidate.forces)(theta[2]);
        // Stack buffer for the usual data sizes, so sampling does not allocate.
        let mut stack = [[0.0; 3]; 64];
        let mut heap = Vec::new();
        let states: &mut [[f64; 3]] = if x.len() <= stack.len() {
            &mut stack[..x.len()]
        } else {
            heap.resize(x.len(), [0.0; 3]);
            &mut heap
        };
        ball_drop::integrate(&setup, &forces, x, ball_drop::MODEL_DT, states);
        for (o, s) in out.iter_mut().zip(states.iter()) {
            *o = s[observable];
        }
    }
}

/// The true curve of `observable` at `xs` when the config names the process
/// that made the data (`[truth]`) and every parameter has a `truth` value.
pub fn truth_curve(config: &crate::config::Config, observable: &str, xs: &[f64]) -> Option<Vec<f64>> {
    use crate::config::{ModelConfig, TruthConfig};
    let truths: Vec<(String, f64)> = config.parameters.iter().map(|(n, p)| p.truth.map(|t| (n.clone(), t))).collect::<Option<_>>()?;
    let get = |n: &str| truths.iter().find(|(k, _)| k == n).map(|(_, v)| *v);
    match config.truth.as_ref()? {
        TruthConfig::BallDrop { quadratic_drag, linear_drag } => {
            let h0 = match config.model {
                ModelConfig::BallDrop { h0 } => h0,
                _ => 60.0,
            };
            let k = ball_drop::OBSERVABLES.iter().position(|o| *o == observable)?;
            let setup = ball_drop::BallDropSetup { h0, g: get("g")?, v0: get("v0")? };
            let forces = ball_drop::ExtraForces { quadratic_drag: *quadratic_drag, linear_drag: *linear_drag, ..ball_drop::ExtraForces::NONE };
            Some(xs.iter().map(|&t| if t >= 0.0 { ball_drop::truth_state(&setup, &forces, t)[k] } else { f64::NAN }).collect())
        }
        TruthConfig::HeavyIon { delta_f } => {
            let params = heavy_ion::HeavyIonParams::from_named(&truths).ok()?;
            let df: heavy_ion::DeltaF = delta_f.parse().ok()?;
            heavy_ion::observables(&params, df, xs).into_iter().find(|(n, _)| *n == observable).map(|(_, v)| v)
        }
    }
}
