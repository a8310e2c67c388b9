//! Fits that one diagnosis hands to the next. A study diagnoses again after
//! refining the variant emulators its first verdict listed; the base fits and
//! the candidates whose emulators did not change are then the same problems
//! with the same seeds, and sampling them again would give the same draws to
//! the bit. A fit is taken from here only when its name, its checkpoint key
//! (config, data, kernel, observables, prior, sampler settings, seed) and its
//! model's answers at probe points (every prediction and, for an emulator,
//! its covariance, compared bit for bit) are all the same: a retrained
//! emulator answers differently at every θ.

use crate::engine::calibrate::{checkpoint_key, Calibration, Problem};
use crate::engine::model::Simulator;
use std::collections::HashMap;
use std::sync::Mutex;

/// Finished fits by key, when kept at all.
pub struct Reuse {
    fits: Option<Mutex<HashMap<String, Calibration>>>,
}

impl Reuse {
    /// Keeps nothing: a single diagnosis (and no probe of its models).
    pub fn none() -> Reuse {
        Reuse { fits: None }
    }

    /// Keeps every fit for the diagnoses that follow.
    pub fn across_diagnoses() -> Reuse {
        Reuse { fits: Some(Mutex::default()) }
    }

    /// The fit made earlier for this name, problem and seed, if any.
    pub(super) fn get(&self, name: &str, problem: &Problem, seed: u64) -> Option<Calibration> {
        let fits = self.fits.as_ref()?;
        let key = key(name, problem, seed);
        fits.lock().ok()?.get(&key).cloned()
    }

    pub(super) fn keep(&self, name: &str, problem: &Problem, seed: u64, fit: &Calibration) {
        let Some(fits) = &self.fits else { return };
        let key = key(name, problem, seed);
        if let Ok(mut fits) = fits.lock() {
            fits.insert(key, fit.clone());
        }
    }
}

fn key(name: &str, problem: &Problem, seed: u64) -> String {
    let material = format!("{name}|{}|{}", checkpoint_key(problem, seed), model_digest(problem));
    crate::base::artifacts::sha256_hex(material.as_bytes())
}

/// The model's predictions (and model covariance, when it has one) at the
/// data's x for three θ inside the prior box, as bit patterns.
fn model_digest(problem: &Problem) -> String {
    let sim: &dyn Simulator = problem.simulator.as_ref();
    let dim = sim.parameter_names().len();
    let (lo, hi) = (&problem.prior.lower[..dim], &problem.prior.upper[..dim]);
    let mut bits: Vec<u64> = Vec::new();
    for t in [0.5, 0.3, 0.7] {
        let theta: Vec<f64> = lo.iter().zip(hi).enumerate().map(|(i, (l, h))| point(*l, *h, t, i)).collect();
        for b in &problem.likelihood.blocks {
            let mut out = vec![0.0; b.x.len()];
            sim.predict(b.model_index, &b.x, &theta, &mut out);
            bits.extend(out.iter().map(|v| v.to_bits()));
            if sim.has_model_covariance() {
                let mut lower = vec![0.0; b.x.len() * b.x.len()];
                sim.add_model_covariance(b.model_index, &b.x, &theta, 1.0, &mut lower);
                bits.extend(lower.iter().map(|v| v.to_bits()));
            }
        }
    }
    crate::base::artifacts::sha256_hex(&bits.iter().flat_map(|b| b.to_le_bytes()).collect::<Vec<u8>>())
}

/// A point at fraction t of [lo, hi], mirrored in every other coordinate so
/// that the probes are not all on the box's diagonal.
fn point(lo: f64, hi: f64, t: f64, i: usize) -> f64 {
    let t = if i % 2 == 0 { t } else { 1.0 - t };
    lo + t * (hi - lo)
}
