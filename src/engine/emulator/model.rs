//! A trained emulator seen as a calibration model (`model = { kind = "emulator" }`).
//! It predicts only at the x where it was trained (the analysis bins), and it
//! carries its own predictive covariance into the likelihood.

use crate::engine::model::Simulator;
use super::{Emulator, PredictScratch};
use anyhow::{bail, Result};
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};

pub struct EmulatedModel {
    id: u64,
    pub emulator: Emulator,
    observables: Vec<String>,
    /// Per observable, its outputs as (x, output index): the likelihood asks for
    /// them at every evaluation, so no string search happens there.
    outputs_by_observable: Vec<Vec<(f64, usize)>>,
}

/// Component predictions at the last three θ seen by this thread for one model:
/// the likelihood asks for every observable block at one θ in turn, and a
/// sampler that has just rejected proposals goes back to its current θ.
struct Cached {
    id: u64,
    last_used: u64,
    theta: Vec<f64>,
    means: Vec<f64>,
    vars: Vec<f64>,
    scratch: PredictScratch,
}

const CACHED_THETAS_PER_MODEL: usize = 3;

thread_local! {
    static CACHE: RefCell<(u64, Vec<Cached>)> = const { RefCell::new((0, Vec::new())) };
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

impl EmulatedModel {
    pub fn new(emulator: Emulator) -> Self {
        let observables = emulator.observable_names();
        let outputs_by_observable = observables
            .iter()
            .map(|name| emulator.outputs().iter().enumerate().filter(|(_, o)| &o.observable == name).map(|(j, o)| (o.x, j)).collect())
            .collect();
        EmulatedModel { id: NEXT_ID.fetch_add(1, Ordering::Relaxed), emulator, observables, outputs_by_observable }
    }

    pub fn load(dir: &std::path::Path) -> Result<Self> {
        Ok(Self::new(crate::engine::emulator::store::load(dir)?))
    }

    fn with_components<R>(&self, theta: &[f64], f: impl FnOnce(&[f64], &[f64]) -> R) -> R {
        CACHE.with(|cell| {
            let (clock, list) = &mut *cell.borrow_mut();
            *clock += 1;
            let pos = match list.iter().position(|c| c.id == self.id && c.theta.as_slice() == theta) {
                Some(p) => p,
                None => {
                    let mine = list.iter().filter(|c| c.id == self.id).count();
                    let slot = if mine < CACHED_THETAS_PER_MODEL {
                        if list.len() >= 8 * CACHED_THETAS_PER_MODEL {
                            // Forget the least recently used entry of any model.
                            let lru = (0..list.len()).min_by_key(|&i| list[i].last_used).unwrap_or(0);
                            list.remove(lru);
                        }
                        let k = self.emulator.n_components();
                        list.push(Cached { id: self.id, last_used: 0, theta: Vec::new(), means: vec![0.0; k], vars: vec![0.0; k], scratch: self.emulator.scratch() });
                        list.len() - 1
                    } else {
                        (0..list.len()).filter(|&i| list[i].id == self.id).min_by_key(|&i| list[i].last_used).unwrap_or(0)
                    };
                    let c = &mut list[slot];
                    self.emulator.predict_components(theta, &mut c.means, &mut c.vars, &mut c.scratch);
                    c.theta.clear();
                    c.theta.extend_from_slice(theta);
                    slot
                }
            };
            let c = &mut list[pos];
            c.last_used = *clock;
            f(&c.means, &c.vars)
        })
    }

    fn output(&self, observable: usize, x: f64) -> usize {
        // check_inputs has verified every x the likelihood will ask for.
        let matches = |xo: f64| (xo - x).abs() <= 1e-9 * x.abs().max(1.0);
        self.outputs_by_observable[observable].iter().find(|(xo, _)| matches(*xo)).map(|&(_, j)| j).unwrap_or_else(|| panic!("{} has no emulator output at x = {x}", self.observables[observable]))
    }
}

impl Simulator for EmulatedModel {
    fn parameter_names(&self) -> Vec<String> {
        self.emulator.parts.parameter_names.clone()
    }
    fn observable_names(&self) -> Vec<String> {
        self.observables.clone()
    }
    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        self.with_components(theta, |means, _| {
            for (o, &xi) in out.iter_mut().zip(x) {
                *o = self.emulator.output_mean_from_components(means, self.output(observable, xi)).0;
            }
        })
    }
    fn check_inputs(&self, observable: usize, x: &[f64]) -> Result<()> {
        let name = &self.observables[observable];
        for &xi in x {
            if self.emulator.output_index(name, xi).is_none() {
                let have: Vec<String> = self.emulator.outputs().iter().filter(|o| &o.observable == name).map(|o| o.x.to_string()).collect();
                bail!("observable '{name}' is measured at x = {xi}, where the emulator has no output (it was trained at x = {})", have.join(", "));
            }
        }
        Ok(())
    }
    fn predicts_any_x(&self) -> bool {
        false
    }
    fn has_model_covariance(&self) -> bool {
        true
    }
    fn add_model_covariance(&self, observable: usize, x: &[f64], theta: &[f64], inv_scale2: f64, lower: &mut [f64]) {
        let n = x.len();
        self.with_components(theta, |means, vars| {
            // Indices and Jacobians on the stack for the usual bin counts.
            let (mut idx_stack, mut jac_stack) = ([0usize; 64], [0.0f64; 64]);
            let (mut idx_heap, mut jac_heap) = (Vec::new(), Vec::new());
            let (idx, jac): (&mut [usize], &mut [f64]) = if n <= 64 {
                (&mut idx_stack[..n], &mut jac_stack[..n])
            } else {
                idx_heap.resize(n, 0);
                jac_heap.resize(n, 0.0);
                (&mut idx_heap, &mut jac_heap)
            };
            for i in 0..n {
                idx[i] = self.output(observable, x[i]);
                jac[i] = self.emulator.output_mean_from_components(means, idx[i]).1;
            }
            for j in 0..n {
                for i in j..n {
                    lower[i + j * n] += inv_scale2 * self.emulator.output_cov_from_components(vars, idx[i], idx[j], jac[i], jac[j]);
                }
            }
        })
    }
}
