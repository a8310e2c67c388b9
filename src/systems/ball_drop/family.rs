//! `[model] kind = "ball_drop"`: the drag-free ball drop with parameters
//! (g, v0), its library of candidate forces, and `[truth] kind = "ball_drop"`,
//! the ball with extra forces that made the mock data.

use super::{integrate, model_value, truth_state, BallDropSetup, Candidate, ExtraForces, CANDIDATES, MODEL_DT, OBSERVABLES};
use crate::base::config::{Config, ParamSpec};
use crate::engine::model::{CandidateModel, ModelFamily, Simulator, Units};
use anyhow::Result;
use std::sync::Arc;

pub struct BallDropFamily;

/// `[model]` of kind "ball_drop".
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelTable {
    /// Known initial height, m.
    #[serde(default = "default_h0")]
    h0: f64,
}

/// `[truth]` of kind "ball_drop": the extra forces of the true process.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthTable {
    /// k in `-k v|v|`, 1/m.
    #[serde(default)]
    quadratic_drag: f64,
    /// b in `-b v`, 1/s.
    #[serde(default)]
    linear_drag: f64,
    /// Initial height, m; by default the ball-drop model's (or 60 m when the
    /// model is of another kind, e.g. an emulator of the ball drop).
    h0: Option<f64>,
}

fn default_h0() -> f64 {
    60.0
}

fn h0(config: &Config) -> Result<f64> {
    Ok(config.decode_family_table::<ModelTable>(&config.model, "model")?.h0)
}

fn observable_names() -> Vec<String> {
    OBSERVABLES.iter().map(|s| s.to_string()).collect()
}

impl ModelFamily for BallDropFamily {
    fn kind(&self) -> &'static str {
        "ball_drop"
    }

    fn simulator(&self, config: &Config) -> Result<Arc<dyn Simulator>> {
        Ok(Arc::new(BallDropModel { h0: h0(config)?, forces: None }))
    }

    fn units(&self, _config: &Config) -> Units {
        let pairs = |v: &[(&str, &str)]| v.iter().map(|(k, u)| (k.to_string(), u.to_string())).collect();
        Units {
            x: "s".into(),
            observables: pairs(&[("height", "m"), ("velocity", "m/s"), ("acceleration", "m/s²")]),
            parameters: pairs(&[("g", "m/s²"), ("v0", "m/s")]),
        }
    }

    fn candidates(&self, config: &Config) -> Result<Vec<CandidateModel>> {
        let h0 = h0(config)?;
        Ok(CANDIDATES
            .iter()
            .map(|c| CandidateModel {
                name: c.name.to_string(),
                description: c.description.to_string(),
                extra_parameters: vec![(c.parameter.to_string(), ParamSpec { min: c.bounds.0, max: c.bounds.1, truth: None, units: c.units.to_string() })],
                simulator: Arc::new(AugmentedBallDrop { h0, candidate: *c }),
            })
            .collect())
    }

    fn true_process(&self, config: &Config, truth: &toml::Table) -> Result<Arc<dyn Simulator>> {
        let t: TruthTable = config.decode_family_table(truth, "truth")?;
        let forces = ExtraForces { quadratic_drag: t.quadratic_drag, linear_drag: t.linear_drag, ..ExtraForces::NONE };
        let h0 = match t.h0 {
            Some(h) => h,
            None if config.model_kind()? == self.kind() => h0(config)?,
            None => default_h0(),
        };
        Ok(Arc::new(BallDropModel { h0, forces: Some(forces) }))
    }
}

/// The ball drop with parameters (g, v0) and known h0: drag-free in closed
/// form (the model), or with extra forces integrated finely from t = 0 to
/// each time, NaN before the drop (the true process).
#[derive(Clone, Debug)]
pub struct BallDropModel {
    pub h0: f64,
    pub forces: Option<ExtraForces>,
}

impl Simulator for BallDropModel {
    fn parameter_names(&self) -> Vec<String> {
        vec!["g".into(), "v0".into()]
    }
    fn observable_names(&self) -> Vec<String> {
        observable_names()
    }
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let (g, v0) = (theta[0], theta[1]);
        match &self.forces {
            None => out.iter_mut().zip(x).for_each(|(o, &t)| *o = model_value(observable, self.h0, g, v0, t)),
            Some(forces) => {
                let setup = BallDropSetup { h0: self.h0, g, v0 };
                out.iter_mut().zip(x).for_each(|(o, &t)| *o = if t >= 0.0 { truth_state(&setup, forces, t)[observable] } else { f64::NAN });
            }
        }
    }
}

/// The ball drop augmented with one candidate correction: parameters
/// (g, v0, <candidate parameter>), solved by RK4.
#[derive(Clone, Debug)]
pub struct AugmentedBallDrop {
    pub h0: f64,
    pub candidate: Candidate,
}

impl Simulator for AugmentedBallDrop {
    fn parameter_names(&self) -> Vec<String> {
        vec!["g".into(), "v0".into(), self.candidate.parameter.into()]
    }
    fn observable_names(&self) -> Vec<String> {
        observable_names()
    }
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let setup = BallDropSetup { h0: self.h0, g: theta[0], v0: theta[1] };
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
        integrate(&setup, &forces, x, MODEL_DT, states);
        for (o, s) in out.iter_mut().zip(states.iter()) {
            *o = s[observable];
        }
    }
}
