//! A trained emulator seen as a calibration model (`model = { kind = "emulator" }`).
//! It predicts only at the x where it was trained (the analysis bins), and it
//! carries its own predictive covariance into the likelihood.

use super::{Emulator, PredictScratch};
use crate::engine::model::{LowRankModelCovariance, Simulator};
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
            .map(|name| {
                emulator
                    .outputs()
                    .iter()
                    .enumerate()
                    .filter(|(_, o)| &o.observable == name)
                    .map(|(j, o)| (o.x, j))
                    .collect()
            })
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
                        list.push(Cached {
                            id: self.id,
                            last_used: 0,
                            theta: Vec::new(),
                            means: vec![0.0; k],
                            vars: vec![0.0; k],
                            scratch: self.emulator.scratch(),
                        });
                        list.len() - 1
                    } else {
                        (0..list.len())
                            .filter(|&i| list[i].id == self.id)
                            .min_by_key(|&i| list[i].last_used)
                            .unwrap_or(0)
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
        self.outputs_by_observable[observable]
            .iter()
            .find(|(xo, _)| matches(*xo))
            .map(|&(_, j)| j)
            .unwrap_or_else(|| panic!("{} has no emulator output at x = {x}", self.observables[observable]))
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
                let have: Vec<String> =
                    self.emulator.outputs().iter().filter(|o| &o.observable == name).map(|o| o.x.to_string()).collect();
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
        let w = inv_scale2.sqrt();
        self.with_components(theta, |means, vars| {
            with_point_scratch(x.len(), self.emulator.n_components(), |idx, g, loading| {
                for (i, &xi) in x.iter().enumerate() {
                    idx[i] = self.output(observable, xi);
                    g[i] = w * self.emulator.output_mean_from_components(means, idx[i]).1;
                }
                self.emulator.add_points_covariance(vars, idx, g, lower, loading);
            })
        })
    }
    fn model_covariance_spans_observables(&self) -> bool {
        self.observables.len() > 1
    }
    fn add_joint_model_covariance(
        &self,
        points: &[(usize, f64)],
        inv_scales: &[f64],
        theta: &[f64],
        lower: &mut [f64],
    ) {
        self.with_components(theta, |means, vars| {
            with_point_scratch(points.len(), self.emulator.n_components(), |idx, g, loading| {
                for (i, &(observable, xi)) in points.iter().enumerate() {
                    idx[i] = self.output(observable, xi);
                    g[i] = inv_scales[i] * self.emulator.output_mean_from_components(means, idx[i]).1;
                }
                self.emulator.add_points_covariance(vars, idx, g, lower, loading);
            })
        })
    }
    fn joint_model_low_rank(&self, points: &[(usize, f64)], offsets: &[usize]) -> Option<LowRankModelCovariance> {
        let idx: Vec<usize> = points.iter().map(|&(o, x)| self.output(o, x)).collect();
        self.emulator.low_rank_covariance(&idx, offsets)
    }
    fn joint_model_factors(
        &self,
        points: &[(usize, f64)],
        inv_scales: &[f64],
        theta: &[f64],
        g: &mut [f64],
        w: &mut [f64],
    ) {
        self.with_components(theta, |means, vars| {
            for (i, &(observable, xi)) in points.iter().enumerate() {
                g[i] = inv_scales[i] * self.emulator.output_mean_from_components(means, self.output(observable, xi)).1;
            }
            self.emulator.component_weights(vars, w);
        })
    }
}

/// Output indices, per-point factors and loadings scratch (2 n K) for `n`
/// points, from a per-thread buffer that grows to the largest size asked
/// for, so that a likelihood evaluation does not allocate.
fn with_point_scratch<R>(n: usize, components: usize, f: impl FnOnce(&mut [usize], &mut [f64], &mut [f64]) -> R) -> R {
    thread_local! {
        static SCRATCH: RefCell<(Vec<usize>, Vec<f64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
    }
    SCRATCH.with(|cell| {
        let (idx, values) = &mut *cell.borrow_mut();
        let need = n + 2 * n * components;
        if idx.len() < n {
            idx.resize(n, 0);
        }
        if values.len() < need {
            values.resize(need, 0.0);
        }
        let (g, loadings) = values[..need].split_at_mut(n);
        f(&mut idx[..n], g, loadings)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::emulator::{train, EmulatorSettings, OutputKey, TrainingTable};
    use rand::SeedableRng;
    use rand_distr::Distribution;

    /// Two observables at two x each (one on a log scale), 3 of 4 components kept.
    fn emulator() -> Emulator {
        let n = 30;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        // Uniform points, not the design module: emulator may not import a sibling unit.
        let uniform = rand_distr::Uniform::new(0.0, 1.0).unwrap();
        let unit: Vec<f64> = (0..2 * n).map(|_| uniform.sample(&mut rng)).collect();
        let noise = rand_distr::Normal::new(0.0, 0.02).unwrap();
        let mut values = Vec::new();
        for u in unit.chunks(2) {
            values.extend([
                (2.0 * u[0] + u[1]).exp() * (1.0 + noise.sample(&mut rng)),
                (u[0] - u[1]).exp() * (1.0 + noise.sample(&mut rng)),
                u[0] * u[1] + noise.sample(&mut rng),
                u[0] + 0.3 * u[1] * u[1] + noise.sample(&mut rng),
            ]);
        }
        let key = |o: &str, x: f64| OutputKey { observable: o.into(), x };
        let table = TrainingTable {
            path: "synthetic".into(),
            parameter_names: vec!["a".into(), "b".into()],
            design_ids: (0..n as i64).collect(),
            inputs: unit.clone(),
            outputs: vec![key("y", 1.0), key("y", 2.0), key("z", 1.0), key("z", 2.0)],
            errors: vec![0.0; values.len()],
            noise_correlation: None,
            values,
        };
        let settings: EmulatorSettings =
            toml::from_str("parameters = [\"a\", \"b\"]\ncomponents = 3\nrestarts = 2\nlog_observables = [\"y\"]")
                .unwrap();
        train(&table, &settings, 1).unwrap().0
    }

    #[test]
    fn the_joint_model_covariance_is_the_emulators_predictive_covariance() {
        let model = EmulatedModel::new(emulator());
        assert!(model.model_covariance_spans_observables());
        let theta = [0.4, 0.7];
        let full = model.emulator.predict(&theta);
        let points = [(0, 1.0), (0, 2.0), (1, 1.0), (1, 2.0)];
        let inv_scales = [2.0, 2.0, 0.5, 0.5];
        let mut lower = vec![0.0; 16];
        model.add_joint_model_covariance(&points, &inv_scales, &theta, &mut lower);
        let m = model.emulator.n_outputs();
        let mut across = 0.0f64;
        for j in 0..4 {
            for i in j..4 {
                let (oi, oj) = (model.output(points[i].0, points[i].1), model.output(points[j].0, points[j].1));
                let expect = full.cov[oi * m + oj] * inv_scales[i] * inv_scales[j];
                assert!(
                    (lower[i + j * 4] - expect).abs() <= 1e-12 * expect.abs().max(1e-300),
                    "({i}, {j}): {} vs {expect}",
                    lower[i + j * 4]
                );
                if points[i].0 != points[j].0 {
                    across = across.max(expect.abs());
                }
            }
        }
        // The observables share components, so the covariance between them is not zero.
        assert!(across > 0.0);
        // One observable's block is the same as its block of the joint matrix.
        let mut block = vec![0.0; 4];
        model.add_model_covariance(1, &[1.0, 2.0], &theta, 0.25, &mut block);
        for (i, j) in [(0, 0), (1, 0), (1, 1)] {
            assert!((block[i + 2 * j] - lower[(2 + i) + (2 + j) * 4]).abs() < 1e-15);
        }
    }
}
