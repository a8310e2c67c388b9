//! Fits that a diagnosis takes instead of sampling them again. A study
//! diagnoses again after refining the variant emulators its first verdict
//! listed; the base fits and the candidates whose emulators did not change
//! are then the same problems with the same seeds, and sampling them again
//! would give the same draws to the bit. And the study's calibrate stage has
//! already fitted the base problems, without and with MD, with other seeds
//! (`calibrate::results::stored`). A fit is taken only when its problem key (config,
//! data, kernel, observables, prior, sampler settings, and the model's
//! answers at probe points bit for bit) is the same.

use crate::engine::calibrate::{results::stored, Calibration, Problem};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Mutex;

/// Finished fits by key, when kept at all, and stored fits to look in.
pub struct Reuse {
    fits: Option<Mutex<HashMap<String, Calibration>>>,
    stored: Vec<PathBuf>,
}

impl Reuse {
    /// Keeps nothing: a single diagnosis (and no probe of its models).
    pub fn none() -> Reuse {
        Reuse { fits: None, stored: Vec::new() }
    }

    /// Keeps every fit for the diagnoses that follow, and takes a fit of
    /// the same problem from the calibrations written in `stored`.
    pub fn across_diagnoses(stored: Vec<PathBuf>) -> Reuse {
        Reuse { fits: Some(Mutex::default()), stored }
    }

    /// The fit made earlier for this name, problem and seed, or a stored fit
    /// of this problem, with where it came from.
    pub(super) fn get(&self, name: &str, problem: &Problem, seed: u64) -> Option<(Calibration, String)> {
        let fits = self.fits.as_ref()?;
        let key = key(name, problem, seed);
        if let Some(fit) = fits.lock().ok().and_then(|f| f.get(&key).cloned()) {
            return Some((fit, "the diagnosis before".into()));
        }
        stored::find(&self.stored, problem).map(|(dir, fit)| (fit, dir.display().to_string()))
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
    format!("{name}|{seed}|{}", stored::problem_key(problem))
}
