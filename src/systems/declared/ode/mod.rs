//! `[model] kind = "ode"`: state variables with initial values at `t0` and
//! equations of motion d(state)/dt, integrated by the `ode_solvers` crate
//! with error control; each observable is a formula of t, θ, constants, the
//! state and its rates.
//!
//! Rates affine in the state (sinusoids of t allowed) are solved exactly on
//! the data's grid, by one matrix exponential per θ (`linear`); the others
//! are integrated.
//!
//! When the data's times lie on a grid `t0 + k·dx` (they usually do), the
//! 8th-order Dormand–Prince method (DOP853) integrates and interpolates the
//! state at every grid point as it passes: at the tolerances the bundled
//! configs ask for it takes 3–6 times fewer steps than the 5th-order method.
//! Times off that grid (a figure's smooth curve) are served by Dormand–Prince
//! 5(4) with its continuous output.
//!
//! A system whose rates read t is given to DOP853 in autonomous form, with t
//! as one more state (dt/dt = 1): ode_solvers 0.6.2 evaluates DOP853's
//! twelfth stage at x instead of x + h (its tableau has c12 = 0, not 1;
//! upstream pull request srenevey/ode-solvers#42, open), so the time it
//! passes cannot be trusted, while the stage's state, built from the
//! tableau's correct rows, carries the right time. Given t directly, a
//! periodic kinetics source took 972 steps where scipy's DOP853 takes 6.
//!
//! An integration that fails at some θ (too many steps, step-size underflow,
//! stiffness, a non-finite rate) makes every prediction there NaN, which the
//! likelihood turns into zero likelihood; the failures are counted and
//! reported in `summary.json`, never a panic or a hang (the step count is
//! bounded by `[model.solver] max_steps`).

mod dense;
mod expanded;
mod grid;
mod integrate;
mod linear;
mod rhs;
mod shooting;
mod tolerance;

use super::declaration::{check_parameters_used, corners, describe, Declared, SolverSettings, Variables, MAX_NAMES};
use crate::engine::formula::Formula;
use crate::engine::model::{ObservedData, Simulator};
use anyhow::{bail, Result};
use dense::Dense;
use grid::Grid;
use nalgebra::{Const, Dyn};
use rhs::Checks;
use shooting::Shooting;
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use tolerance::Precision;

pub struct OdeModel {
    /// Tells this model's solutions apart in the per-thread cache.
    id: u64,
    parameters: Vec<String>,
    observables: Vec<String>,
    states: Vec<String>,
    initial: Vec<Formula>,
    rates: Vec<Formula>,
    formulas: Vec<Formula>,
    /// Whether an observable uses a rate `d_<state>` (then rates are evaluated for it).
    uses_rates: Vec<bool>,
    /// No rate reads t; otherwise DOP853 carries t as a state (module notes).
    autonomous: bool,
    /// The rates are affine in the state (sinusoids of t allowed): solved
    /// exactly on a grid (`linear`).
    affine: Option<linear::Affine>,
    /// The rates that are polynomials in the state, expanded for the integrator.
    expanded: Option<expanded::ExpandedRates>,
    /// Where each initial value and each rate was written, for errors.
    initial_places: Vec<String>,
    rate_places: Vec<String>,
    variables: Variables,
    bounds: Vec<(f64, f64)>,
    t0: f64,
    solver: SolverSettings,
    /// The data's finest relative error, which unset tolerances follow.
    precision: Precision,
    /// Whether each observable is a state itself (its formula the state's name).
    observed_states: Vec<bool>,
    /// The latest time any data asked for, so one integration serves every observable.
    horizon: AtomicU64,
    /// Every data time seen by `check_inputs`, and the grid that holds them.
    data_times: Mutex<Vec<f64>>,
    grid: RwLock<Option<Grid>>,
    /// The latest data samplers watched the χ² of, on the grid (fits of
    /// different data may run at once).
    checks: RwLock<Vec<Arc<Checks>>>,
    failures: AtomicU64,
    /// Multiple shooting from the data (`shooting`): discovery's screening
    /// of a flow one trajectory cannot follow.
    shooting: Option<Shooting>,
}

/// One integration at one θ, kept per thread: the likelihood asks for each
/// observable in turn at the same θ.
struct Solved {
    model: u64,
    /// The tolerance it was integrated to (the data's notes may change it).
    rtol: f64,
    theta: Vec<f64>,
    t_end: f64,
    /// None when the integration failed.
    dense: Option<Dense>,
    /// Made by the affine propagator, not an integrator.
    #[cfg_attr(not(test), allow(dead_code))]
    exact: bool,
    /// The integration stopped early, its χ² against the data of this id
    /// past this limit (`dense` is None, and is no failure).
    far: Option<(u64, f64)>,
    y0: Vec<f64>,
    /// The value vector at θ, kept so that each observable's predictions
    /// write t, the state and the rates into it instead of copying it.
    values: [f64; MAX_NAMES],
}

impl Solved {
    /// A solution of no model yet: the buffers `OdeModel::solve` fills.
    fn empty() -> Solved {
        Solved {
            model: 0,
            rtol: f64::NAN,
            theta: Vec::new(),
            t_end: f64::NAN,
            dense: None,
            exact: false,
            far: None,
            y0: Vec::new(),
            values: [0.0; MAX_NAMES],
        }
    }
}

/// Solutions kept per thread. A sampler's sweep proposes two points (the
/// joint move and the shared parameters' move) and then moves each
/// observable's discrepancy parameters at the particle's current θ: with
/// three kept, the current θ's solution is still there when both
/// proposals were rejected, and those moves integrate nothing.
const KEPT: usize = 3;

/// Data sets whose points on the grid are kept (`checks_for`).
const KEPT_DATA: usize = 8;

thread_local! {
    /// The latest solutions on this thread, the most recently used first.
    static SOLVED: RefCell<Vec<Solved>> = const { RefCell::new(Vec::new()) };
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

impl OdeModel {
    pub fn compile(file: &str, d: &Declared) -> Result<OdeModel> {
        let variables = Variables::of(file, d)?;
        let before_state = variables.scope(variables.state_at);
        let with_state = variables.scope(variables.rate_at);
        let everything = variables.scope(variables.len);
        let initial = d
            .states
            .iter()
            .map(|s| Formula::parse(&s.initial.text, &before_state, &s.initial.place))
            .collect::<Result<Vec<_>>>()?;
        let rates = d
            .states
            .iter()
            .map(|s| Formula::parse(&s.rate.text, &with_state, &s.rate.place))
            .collect::<Result<Vec<_>>>()?;
        let formulas = d
            .observables
            .iter()
            .map(|(_, w)| Formula::parse(&w.text, &everything, &w.place))
            .collect::<Result<Vec<_>>>()?;
        check_parameters_used(file, d, &initial.iter().chain(&rates).chain(&formulas).collect::<Vec<_>>())?;
        let uses_rates = formulas.iter().map(|f| (variables.rate_at..variables.len).any(|i| f.uses(i))).collect();
        let autonomous = !rates.iter().any(|f| f.uses(0));
        let states: Vec<String> = d.states.iter().map(|s| s.name.clone()).collect();
        let affine = linear::Affine::of(&rates, &variables, &states, &d.input);
        let expanded = expanded::ExpandedRates::of(&rates, &states, &with_state);
        Ok(OdeModel {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            autonomous,
            affine,
            expanded,
            parameters: d.parameters.clone(),
            observables: d.observables.iter().map(|(o, _)| o.clone()).collect(),
            states,
            initial,
            rates,
            formulas,
            uses_rates,
            initial_places: d.states.iter().map(|s| s.initial.place.clone()).collect(),
            rate_places: d.states.iter().map(|s| s.rate.place.clone()).collect(),
            variables,
            bounds: d.bounds.clone(),
            t0: d.t0,
            solver: d.solver,
            precision: Precision::unseen(),
            observed_states: d
                .observables
                .iter()
                .map(|(_, w)| d.states.iter().any(|s| s.name == w.text.trim()))
                .collect(),
            horizon: AtomicU64::new(d.t0.to_bits()),
            data_times: Mutex::new(Vec::new()),
            grid: RwLock::new(None),
            checks: RwLock::new(Vec::new()),
            failures: AtomicU64::new(0),
            shooting: d.shooting.map(|every| {
                let state_of = d.observables.iter().map(|(_, w)| d.states.iter().position(|s| s.name == w.text.trim()));
                Shooting::new(every, state_of.collect(), d.states.len())
            }),
        })
    }

    /// Integrates from t0 at θ into `solved`: over the grid when one is
    /// given (its end must reach `t_end`), else continuously to `t_end`. The
    /// previous solution's buffers are reused, so the exact path allocates
    /// nothing per θ (and nothing the size of the value vector is moved).
    /// With a watch (the data's points on the grid and a χ² limit), an
    /// integration stops once the points passed exceed the limit.
    fn solve(&self, solved: &mut Solved, theta: &[f64], t_end: f64, grid: Option<Grid>, watch: Option<(&Checks, f64)>) {
        solved.model = self.id;
        solved.rtol = self.precision.tolerances(&self.solver).0;
        solved.theta.clear();
        solved.theta.extend_from_slice(theta);
        solved.t_end = t_end;
        solved.exact = false;
        solved.far = None;
        let states = match solved.dense.take() {
            Some(Dense::OnGrid { states, .. }) => states,
            _ => Vec::new(),
        };
        let v = &mut solved.values;
        self.variables.set_theta(theta, v);
        v[0] = self.t0;
        solved.y0.clear();
        solved.y0.extend(self.initial.iter().map(|f| f.eval(&v[..])));
        let y0 = &solved.y0;
        if y0.iter().any(|y| !y.is_finite()) {
            return;
        }
        if t_end <= self.t0 {
            solved.dense = Some(Dense::Empty);
            return;
        }
        if let Some(grid) = grid {
            solved.t_end = grid.end();
            if let Some(affine) = &self.affine {
                let mut states = states;
                let ok = affine.propagate(v, self.variables.state_at, y0, &grid, &mut states);
                solved.dense = ok.then_some(Dense::OnGrid { grid, states, stride: y0.len() });
                solved.exact = true;
                return;
            }
            // The clock: t as the last state when a rate reads it.
            let y0: Vec<f64> = y0.iter().copied().chain((!self.autonomous).then_some(self.t0)).collect();
            let v = *v;
            let (dense, exceeded) = match y0.len() {
                1 => self.integrate_on_grid::<Const<1>>(v, &y0, grid, watch),
                2 => self.integrate_on_grid::<Const<2>>(v, &y0, grid, watch),
                3 => self.integrate_on_grid::<Const<3>>(v, &y0, grid, watch),
                4 => self.integrate_on_grid::<Const<4>>(v, &y0, grid, watch),
                _ => self.integrate_on_grid::<Dyn>(v, &y0, grid, watch),
            };
            solved.dense = dense;
            solved.far = watch.filter(|_| exceeded).map(|(checks, limit)| (checks.data, limit));
            return;
        }
        solved.dense = self.integrate_from(*v, self.t0, y0, t_end);
    }

    /// Moves this model's kept solution at θ to the front of `kept` (true),
    /// or else the least recently used slot, whose buffers a new solution
    /// reuses (false).
    fn to_front(&self, kept: &mut Vec<Solved>, theta: &[f64]) -> bool {
        let rtol = self.precision.tolerances(&self.solver).0;
        let found = kept.iter().position(|s| s.model == self.id && s.rtol == rtol && s.theta == theta);
        let slot = found.unwrap_or_else(|| {
            if kept.len() < KEPT {
                kept.push(Solved::empty());
            }
            kept.len() - 1
        });
        kept[..=slot].rotate_right(1);
        found.is_some()
    }

    /// The points of `data` on the data's grid, made once per data; None
    /// when there is no grid, it does not reach them, or the model solves
    /// exactly (nothing to stop).
    fn checks_for(&self, data: &ObservedData) -> Option<Arc<Checks>> {
        if self.affine.is_some() || self.shooting.is_some() {
            return None;
        }
        let grid = (*self.grid.read().unwrap_or_else(|e| e.into_inner()))?;
        let known = self.checks.read().unwrap_or_else(|e| e.into_inner()).iter().find(|c| c.data == data.id).cloned();
        if let Some(c) = known.filter(|c| c.grid == grid) {
            return Some(c);
        }
        let made = Arc::new(Checks::of(data, grid)?);
        let mut kept = self.checks.write().unwrap_or_else(|e| e.into_inner());
        kept.retain(|c| c.data != data.id);
        if kept.len() >= KEPT_DATA {
            kept.remove(0);
        }
        kept.push(made.clone());
        Some(made)
    }

    /// Adds data times and finds the grid that holds all of them.
    fn remember_times(&self, x: &[f64]) {
        let mut times = self.data_times.lock().unwrap_or_else(|e| e.into_inner());
        times.extend_from_slice(x);
        times.sort_by(f64::total_cmp);
        times.dedup();
        *self.grid.write().unwrap_or_else(|e| e.into_inner()) = Grid::holding(self.t0, &times);
    }

    /// The state at `t` from a solution (its initial state `y0`, its dense
    /// output reaching `t_end`) into `y`: None when the solution does not
    /// reach t (off its grid, or past its end), Some(false) where the state
    /// is undefined (a failed integration).
    #[inline]
    fn state_at(&self, (y0, dense, t_end): (&[f64], &Option<Dense>, f64), t: f64, y: &mut [f64]) -> Option<bool> {
        if t == self.t0 {
            y.copy_from_slice(y0);
            return Some(true);
        }
        match dense {
            None => Some(false),
            Some(d @ Dense::OnGrid { .. }) => d.state_at(t, y).then_some(true),
            Some(_) if t > t_end => None,
            Some(d) => Some(t > self.t0 && d.state_at(t, y)),
        }
    }

    /// The data's grid when every time of `x` lies on it and it reaches
    /// `t_needed`.
    fn grid_for(&self, x: &[f64], t_needed: f64) -> Option<Grid> {
        let grid = (*self.grid.read().unwrap_or_else(|e| e.into_inner()))?;
        let on_grid = x.iter().all(|t| *t == self.t0 || grid.index(*t).is_some());
        // t_needed is the latest data time or a time of x, so on the grid.
        (on_grid && grid.index(t_needed).is_some()).then_some(grid)
    }

    fn horizon(&self) -> f64 {
        f64::from_bits(self.horizon.load(Ordering::Relaxed))
    }

    /// The observable at each t of `x` into `out` (NaN where undefined);
    /// false, with `out` unfinished, when `solved` does not reach some t.
    fn predict_from(&self, solved: &mut Solved, observable: usize, x: &[f64], out: &mut [f64]) -> bool {
        let (at, n) = (self.variables.state_at, self.states.len());
        let formula = &self.formulas[observable];
        let Solved { y0, dense, t_end, values: v, .. } = solved;
        for (o, &t) in out.iter_mut().zip(x) {
            match self.state_at((y0, dense, *t_end), t, &mut v[at..at + n]) {
                None => return false,
                Some(false) => {
                    *o = f64::NAN;
                    continue;
                }
                Some(true) => {}
            }
            v[0] = t;
            if self.uses_rates[observable] {
                for (k, rate) in self.rates.iter().enumerate() {
                    v[self.variables.rate_at + k] = rate.eval(&v[..]);
                }
            }
            *o = formula.eval(&v[..]);
        }
        true
    }
}

impl Simulator for OdeModel {
    fn parameter_names(&self) -> Vec<String> {
        self.parameters.clone()
    }

    fn observable_names(&self) -> Vec<String> {
        self.observables.clone()
    }

    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        if let Some(shooting) = &self.shooting {
            return self.predict_shot(shooting, observable, x, theta, out);
        }
        SOLVED.with(|cell| {
            let mut kept = cell.borrow_mut();
            let found = self.to_front(&mut kept, theta);
            let solved = &mut kept[0];
            // The likelihood asks for each observable in turn at one θ: the
            // solution made for the first serves the others (not one its
            // watch stopped).
            if found && solved.far.is_none() && self.predict_from(solved, observable, x, out) {
                return;
            }
            let t_needed = x.iter().copied().fold(self.horizon(), f64::max);
            let grid = self.grid_for(x, t_needed);
            self.solve(solved, theta, t_needed, grid, None);
            if solved.dense.is_none() {
                self.failures.fetch_add(1, Ordering::Relaxed);
            }
            // A fresh solution reaches every t of x (on its grid, or
            // integrated to the latest); NaN should one not.
            if !self.predict_from(solved, observable, x, out) {
                out.fill(f64::NAN);
            }
        });
    }

    /// Records the latest data time (one integration then serves every
    /// observable) and checks that the initial values and rates are finite
    /// at t0 at every corner of the prior box: a division by zero there is a
    /// declaration error. Later failures only cost their θ its likelihood.
    fn note_measurements(&self, observable: usize, values: &[f64], errors: &[f64]) {
        let state = self.observed_states.get(observable).copied().unwrap_or(false);
        self.precision.note(values, errors, state);
        if let Some(shooting) = &self.shooting {
            shooting.note_values(observable, values, self.t0);
        }
    }

    fn numerics(&self) -> Option<String> {
        let tolerances = self.precision.describe(&self.solver);
        if let Some(shooting) = &self.shooting {
            return Some(format!(
                "ODE by multiple shooting from the data: restarted from the measured states at {} anchors about {} apart, each stretch integrated by Dormand–Prince 5(4) at {tolerances}",
                shooting.anchors().list.len(),
                shooting.every
            ));
        }
        Some(if self.affine.is_some() {
            format!("ODE affine in its state: solved exactly on the data's time grid, else integrated at {tolerances}")
        } else {
            format!("ODE integrated by DOP853 on the data's time grid, else Dormand–Prince 5(4), at {tolerances}")
        })
    }

    fn check_inputs(&self, observable: usize, x: &[f64]) -> Result<()> {
        if let Some(t) = x.iter().find(|t| **t < self.t0) {
            bail!("a data point at t = {t} lies before t0 = {} of the ODE model, where it has no state", self.t0);
        }
        let latest = x.iter().copied().fold(self.horizon(), f64::max);
        self.horizon.store(latest.to_bits(), Ordering::Relaxed);
        self.remember_times(x);
        if let Some(shooting) = &self.shooting {
            shooting.note_times(observable, x);
        }
        for theta in corners(&self.bounds) {
            let mut v = self.variables.at(&theta);
            v[0] = self.t0;
            for (k, f) in self.initial.iter().enumerate() {
                v[self.variables.state_at + k] = f.eval(&v);
            }
            let formulas = self.initial.iter().chain(&self.rates);
            let places = self.initial_places.iter().chain(&self.rate_places);
            for (f, place) in formulas.zip(places) {
                if !f.eval(&v).is_finite() {
                    bail!(
                        "{place} = {:?} is not finite at t0 = {} with {} (a corner or the centre of the prior box): a division by zero or a function outside its domain; narrow the prior or rewrite the formula",
                        f.text(),
                        self.t0,
                        describe(&self.parameters, &theta)
                    );
                }
            }
        }
        Ok(())
    }

    fn failures(&self) -> u64 {
        self.failures.load(Ordering::Relaxed)
    }

    /// Integrates at θ over the data's grid, watching the χ² of the points
    /// passed, and keeps the solution for `predict` (a stopped one only to
    /// answer this again). Without a grid holding every point, answers false.
    fn chi_square_exceeds(&self, theta: &[f64], data: &ObservedData, limit: f64) -> bool {
        let Some(checks) = self.checks_for(data) else {
            return false;
        };
        SOLVED.with(|cell| {
            let mut kept = cell.borrow_mut();
            let found = self.to_front(&mut kept, theta);
            let solved = &mut kept[0];
            if found {
                match solved.far {
                    None => return false,
                    Some((id, stopped_at)) if id == data.id && stopped_at >= limit => return true,
                    Some(_) => {}
                }
            }
            self.solve(solved, theta, checks.grid.end(), Some(checks.grid), Some((&checks, limit)));
            if solved.dense.is_none() && solved.far.is_none() {
                self.failures.fetch_add(1, Ordering::Relaxed);
            }
            solved.far.is_some()
        })
    }
}

#[cfg(test)]
mod tests;
