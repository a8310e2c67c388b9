//! A declared model's data as the discovery engine screens them (`engine::
//! discover::along`): for an ODE, each law's rate where its state is
//! observed (or, through a kinematic identity dx/dt = v, where x is), read
//! off the data by smoothing, with every state's value at those times; for
//! an expression model, each observable as measured, its symbol the input.

use super::super::declaration::{Declared, Variables, MAX_NAMES};
use super::grammar::{angles, kinematic_identity};
use crate::engine::discover::along::{Along, AlongModel, Place};
use crate::engine::discover::library::Symbol;
use crate::engine::discover::smooth::{smooth, Smoothed};
use crate::engine::formula::notation::{parse, Expr};
use crate::engine::formula::Formula;
use crate::engine::model::{ScreeningData, Simulator};
use std::collections::BTreeMap;
use std::sync::Arc;

/// A smoothed series may not claim a rate more precise than this fraction
/// of the largest rate it carries: the smoother's own error (a process
/// that is not quite a Gaussian process) is not in its variance.
pub(super) const RATE_FLOOR: f64 = 0.01;

/// The data along the places of a declared model, and the model along them.
pub struct DeclaredAlong {
    pub along: Along,
    pub model: Box<dyn AlongModel>,
    /// Each place's target: the state whose law it is, or the observable.
    pub targets: Vec<String>,
}

/// Each state's values and rate along some times, read off the data: a
/// state observed as itself, or the rate of one observed through a
/// kinematic identity (`dx/dt = v`, x observed: v is x's rate, and v's rate
/// is x's second derivative). Read once; every model with these states
/// (the base and each candidate) is screened against them.
pub struct Observed {
    /// State index → times, values, rates and the rates' errors.
    known: BTreeMap<usize, (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>)>,
}

impl Observed {
    pub fn read(d: &Declared, data: &ScreeningData) -> Observed {
        let series = observed_series(d, data);
        let mut known = BTreeMap::new();
        for (k, (t, s)) in &series {
            known.insert(*k, (t.clone(), s.value.clone(), s.rate.clone(), s.rate_sd.clone()));
        }
        for (k, state) in d.states.iter().enumerate() {
            if let (Some((t, s)), Some((v, sign))) =
                (series.get(&k), kinematic_identity(d, &state.name, &state.rate.text))
            {
                // v = sign·dx/dt: its values are x's rate, its rate x's second derivative.
                let signed = |values: &[f64]| values.iter().map(|r| sign * r).collect::<Vec<f64>>();
                known.entry(v).or_insert_with(|| (t.clone(), signed(&s.rate), signed(&s.second), s.second_sd.clone()));
            }
        }
        Observed { known }
    }
}

/// An ODE's laws along the data (the model `d`: the base, or the base with
/// a candidate in); `None` when no law's rate can be read off the data (no
/// state observed).
pub fn ode(
    file: &str,
    d: &Declared,
    data: &ScreeningData,
    observed: &Observed,
    trajectory: &dyn Fn(&str) -> Option<Vec<f64>>,
) -> Option<DeclaredAlong> {
    let known = &observed.known;
    let angles = angles(d);
    let variables = Variables::of(file, d).ok()?;
    let scope = variables.scope(variables.rate_at);
    let (mut target, mut sd, mut places, mut targets, mut laws) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut states_at: Vec<Vec<f64>> = Vec::new();
    let mut times: Vec<f64> = Vec::new();
    for (k, state) in d.states.iter().enumerate() {
        let Some((t, _, rate, rate_sd)) = known.get(&k) else { continue };
        if kinematic_identity(d, &state.name, &state.rate.text).is_some() {
            continue;
        }
        let values: Vec<Vec<f64>> = d
            .states
            .iter()
            .enumerate()
            .map(|(j, s)| match known.get(&j) {
                Some((tj, v, _, _)) if tj == t => Some(v.clone()),
                _ => trajectory(&s.name).and_then(|all| at_times(data, &all, t)),
            })
            .collect::<Option<_>>()?;
        let formula = Formula::parse(&state.rate.text, &scope, &state.rate.place).ok()?;
        let floor = RATE_FLOOR * rate.iter().fold(0.0f64, |m, r| m.max(r.abs()));
        let start = target.len();
        for i in 0..t.len() {
            target.push(rate[i]);
            sd.push(rate_sd[i].hypot(floor).max(f64::MIN_POSITIVE));
            times.push(t[i]);
            states_at.push(values.iter().map(|v| v[i]).collect());
        }
        let symbols = d
            .states
            .iter()
            .zip(&values)
            .filter_map(|(s, v)| Symbol::of(&s.name, v, angles.contains(&s.name)))
            .collect();
        places.push(Place { name: format!("d{}/dt", state.name), rows: start..target.len(), symbols });
        targets.push(state.name.clone());
        laws.push(formula);
    }
    if places.is_empty() {
        return None;
    }
    let mut law_of = vec![0; target.len()];
    for (k, p) in places.iter().enumerate() {
        p.rows.clone().for_each(|r| law_of[r] = k);
    }
    let model = Laws { variables, laws, law_of, times, states: states_at };
    Some(DeclaredAlong { along: Along { target, sd, places }, model: Box::new(model), targets })
}

/// An expression model's observables along the data, its input the symbol.
pub fn expression(d: &Declared, data: &ScreeningData, model: Arc<dyn Simulator>) -> Option<DeclaredAlong> {
    let (mut target, mut sd, mut places, mut targets, mut blocks) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let angles = angles(d);
    for b in &data.blocks {
        let (name, _) = d.observables.get(b.model_index)?;
        let symbols = vec![Symbol::of(&d.input, b.x, angles.contains(&d.input))?];
        let start = target.len();
        target.extend_from_slice(b.y);
        sd.extend_from_slice(b.error);
        places.push(Place { name: name.clone(), rows: start..target.len(), symbols });
        targets.push(name.clone());
        blocks.push((b.model_index, b.x.to_vec()));
    }
    (!places.is_empty()).then(|| DeclaredAlong {
        along: Along { target, sd, places },
        model: Box::new(Observables { model, blocks }),
        targets,
    })
}

/// Each state observed as itself (an observable whose formula is the
/// state's name), smoothed along its data.
pub(super) fn observed_series(d: &Declared, data: &ScreeningData) -> BTreeMap<usize, (Vec<f64>, Smoothed)> {
    let mut out = BTreeMap::new();
    for b in &data.blocks {
        let Some((_, formula)) = d.observables.get(b.model_index) else { continue };
        let Ok(Expr::Name(name)) = parse(&formula.text) else { continue };
        let Some(k) = d.states.iter().position(|s| s.name == name) else { continue };
        if out.contains_key(&k) || b.x.windows(2).any(|w| w[1] <= w[0]) {
            continue;
        }
        if let Some(s) = smooth(b.x, b.y, b.error) {
            out.insert(k, (b.x.to_vec(), s));
        }
    }
    // A rate measured as itself (`acceleration = "d_v"`) is the law's value
    // at its times, with its own errors: better than the derivative of a
    // smoothed state, whose error over a few points can hide the effect.
    for b in &data.blocks {
        let Some((_, formula)) = d.observables.get(b.model_index) else { continue };
        let Ok(Expr::Name(name)) = parse(&formula.text) else { continue };
        let Some(k) = name.strip_prefix("d_").and_then(|n| d.states.iter().position(|s| s.name == n)) else {
            continue;
        };
        if let Some((t, s)) = out.get_mut(&k).filter(|(t, _)| t.as_slice() == b.x) {
            debug_assert_eq!(t.len(), b.y.len());
            s.rate = b.y.to_vec();
            s.rate_sd = b.error.to_vec();
        }
    }
    out
}

/// Values of a series given at every point of the data (blocks in a row)
/// at the times `t`, taken from the first block that has them all.
fn at_times(data: &ScreeningData, all: &[f64], t: &[f64]) -> Option<Vec<f64>> {
    let mut offset = 0;
    for b in &data.blocks {
        if b.x == t {
            return Some(all[offset..offset + b.x.len()].to_vec());
        }
        offset += b.x.len();
    }
    None
}

/// The laws' rates at the states read off the data.
struct Laws {
    variables: Variables,
    laws: Vec<Formula>,
    law_of: Vec<usize>,
    times: Vec<f64>,
    states: Vec<Vec<f64>>,
}

impl AlongModel for Laws {
    fn predict(&self, theta: &[f64], out: &mut [f64]) {
        let mut v: [f64; MAX_NAMES] = self.variables.at(theta);
        for (i, o) in out.iter_mut().enumerate() {
            v[0] = self.times[i];
            v[self.variables.state_at..self.variables.state_at + self.states[i].len()].copy_from_slice(&self.states[i]);
            *o = self.laws[self.law_of[i]].eval(&v);
        }
    }
}

/// An expression model's observables at the data.
struct Observables {
    model: Arc<dyn Simulator>,
    blocks: Vec<(usize, Vec<f64>)>,
}

impl AlongModel for Observables {
    fn predict(&self, theta: &[f64], out: &mut [f64]) {
        let mut offset = 0;
        for (index, x) in &self.blocks {
            self.model.predict(*index, x, theta, &mut out[offset..offset + x.len()]);
            offset += x.len();
        }
    }
}
