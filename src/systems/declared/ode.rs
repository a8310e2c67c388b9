//! `[model] kind = "ode"`: state variables with initial values at `t0` and
//! equations of motion d(state)/dt, integrated by the Dormand–Prince 5(4)
//! method of the `ode_solvers` crate with error control and dense output;
//! each observable is a formula of t, θ, constants, the state and its rates.
//!
//! An integration that fails at some θ (too many steps, step-size underflow,
//! stiffness, a non-finite rate) makes every prediction there NaN, which the
//! likelihood turns into zero likelihood; the failures are counted and
//! reported in `summary.json`, never a panic or a hang (the step count is
//! bounded by `[model.solver] max_steps`).

use super::declaration::{check_parameters_used, corners, describe, Declared, SolverSettings, Variables, MAX_NAMES};
use super::formula::Formula;
use crate::engine::model::Simulator;
use anyhow::{bail, Result};
use nalgebra::allocator::Allocator;
use nalgebra::{Const, DefaultAllocator, Dim, Dyn, OVector, U1};
use ode_solvers::continuous_output_model::ContinuousOutputModel;
use ode_solvers::{Dopri5, OutputType, System};
use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};

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
    /// Where each initial value and each rate was written, for errors.
    initial_places: Vec<String>,
    rate_places: Vec<String>,
    variables: Variables,
    bounds: Vec<(f64, f64)>,
    t0: f64,
    solver: SolverSettings,
    /// The latest time any data asked for, so one integration serves every observable.
    horizon: AtomicU64,
    failures: AtomicU64,
}

/// One integration at one θ, kept per thread: the likelihood asks for each
/// observable in turn at the same θ.
struct Solved {
    model: u64,
    theta: Vec<f64>,
    t_end: f64,
    /// None when the integration failed.
    dense: Option<Dense>,
    y0: Vec<f64>,
}

/// Dense output of one integration. Up to four state variables live in
/// stack vectors, so neither the steps nor the evaluations allocate; more
/// use heap vectors.
enum Dense {
    Empty,
    S1(ContinuousOutputModel<f64, OVector<f64, Const<1>>>),
    S2(ContinuousOutputModel<f64, OVector<f64, Const<2>>>),
    S3(ContinuousOutputModel<f64, OVector<f64, Const<3>>>),
    S4(ContinuousOutputModel<f64, OVector<f64, Const<4>>>),
    Heap(ContinuousOutputModel<f64, OVector<f64, Dyn>>),
}

impl Dense {
    /// The state at t into `y`; false outside the solution.
    fn state_at(&self, t: f64, y: &mut [f64]) -> bool {
        fn copy<D: Dim>(d: &ContinuousOutputModel<f64, OVector<f64, D>>, t: f64, y: &mut [f64]) -> bool
        where
            DefaultAllocator: Allocator<D>,
        {
            d.evaluate(t).map(|s| y.copy_from_slice(s.as_slice())).is_some()
        }
        match self {
            Dense::Empty => false,
            Dense::S1(d) => copy(d, t, y),
            Dense::S2(d) => copy(d, t, y),
            Dense::S3(d) => copy(d, t, y),
            Dense::S4(d) => copy(d, t, y),
            Dense::Heap(d) => copy(d, t, y),
        }
    }
}

thread_local! {
    static SOLVED: RefCell<Option<Solved>> = const { RefCell::new(None) };
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
        Ok(OdeModel {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            parameters: d.parameters.clone(),
            observables: d.observables.iter().map(|(o, _)| o.clone()).collect(),
            states: d.states.iter().map(|s| s.name.clone()).collect(),
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
            horizon: AtomicU64::new(d.t0.to_bits()),
            failures: AtomicU64::new(0),
        })
    }

    /// Integrates from t0 to `t_end` at θ.
    fn solve(&self, theta: &[f64], t_end: f64) -> Solved {
        let v = self.variables.at(theta);
        let mut at_t0 = v;
        at_t0[0] = self.t0;
        let y0: Vec<f64> = self.initial.iter().map(|f| f.eval(&at_t0)).collect();
        let mut solved = Solved { model: self.id, theta: theta.to_vec(), t_end, dense: None, y0: y0.clone() };
        if y0.iter().any(|y| !y.is_finite()) {
            return solved;
        }
        if t_end <= self.t0 {
            solved.dense = Some(Dense::Empty);
            return solved;
        }
        solved.dense = match y0.len() {
            1 => self.integrate::<Const<1>>(v, &y0, t_end).map(Dense::S1),
            2 => self.integrate::<Const<2>>(v, &y0, t_end).map(Dense::S2),
            3 => self.integrate::<Const<3>>(v, &y0, t_end).map(Dense::S3),
            4 => self.integrate::<Const<4>>(v, &y0, t_end).map(Dense::S4),
            _ => self.integrate::<Dyn>(v, &y0, t_end).map(Dense::Heap),
        };
        solved
    }

    /// Dormand–Prince 5(4) from t0 to `t_end` with the state in vectors of
    /// dimension `D`; None when the integration fails.
    fn integrate<D: Dim>(
        &self,
        values: [f64; MAX_NAMES],
        y0: &[f64],
        t_end: f64,
    ) -> Option<ContinuousOutputModel<f64, OVector<f64, D>>>
    where
        DefaultAllocator: Allocator<D>,
        OVector<f64, D>: std::ops::Mul<f64, Output = OVector<f64, D>>,
    {
        let y = OVector::<f64, D>::from_iterator_generic(D::from_usize(y0.len()), U1, y0.iter().copied());
        let s = &self.solver;
        let span = t_end - self.t0;
        let rhs = Rhs { model: self, values: RefCell::new(values) };
        let mut stepper = Dopri5::from_param(
            rhs,
            self.t0,
            t_end,
            span,
            y,
            s.rtol,
            s.atol,
            0.9,
            0.04,
            0.2,
            10.0,
            span,
            0.0,
            s.max_steps,
            1000,
            OutputType::Dense,
        );
        let mut dense = ContinuousOutputModel::new();
        stepper.integrate_with_continuous_output_model(&mut dense).ok().map(|_| dense)
    }

    /// The state at each t of `x` from a solution; None where it is undefined.
    fn state_at(&self, solved: &Solved, t: f64, y: &mut [f64]) -> bool {
        if t == self.t0 {
            y.copy_from_slice(&solved.y0);
            return true;
        }
        match solved.dense.as_ref() {
            Some(d) if t > self.t0 && t <= solved.t_end => d.state_at(t, y),
            _ => false,
        }
    }

    fn horizon(&self) -> f64 {
        f64::from_bits(self.horizon.load(Ordering::Relaxed))
    }

    fn predict_from(&self, solved: &Solved, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let n = self.states.len();
        let formula = &self.formulas[observable];
        let mut v = self.variables.at(theta);
        let mut y = [0.0; MAX_NAMES];
        for (o, &t) in out.iter_mut().zip(x) {
            if !self.state_at(solved, t, &mut y[..n]) {
                *o = f64::NAN;
                continue;
            }
            v[0] = t;
            v[self.variables.state_at..self.variables.state_at + n].copy_from_slice(&y[..n]);
            if self.uses_rates[observable] {
                for (k, rate) in self.rates.iter().enumerate() {
                    v[self.variables.rate_at + k] = rate.eval(&v);
                }
            }
            *o = formula.eval(&v);
        }
    }
}

/// The equations of motion as ode_solvers sees them.
struct Rhs<'a> {
    model: &'a OdeModel,
    /// θ and constants in place; t and the state are written per call (in
    /// place: a copy of the whole vector per call was a tenth of the time).
    values: RefCell<[f64; MAX_NAMES]>,
}

impl<D: Dim> System<f64, OVector<f64, D>> for Rhs<'_>
where
    DefaultAllocator: Allocator<D>,
{
    fn system(&self, t: f64, y: &OVector<f64, D>, dy: &mut OVector<f64, D>) {
        let mut v = self.values.borrow_mut();
        v[0] = t;
        let at = self.model.variables.state_at;
        v[at..at + y.len()].copy_from_slice(y.as_slice());
        for (k, rate) in self.model.rates.iter().enumerate() {
            dy[k] = rate.eval(&v[..]);
        }
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
        let t_needed = x.iter().copied().fold(self.horizon(), f64::max);
        SOLVED.with(|cell| {
            let mut cache = cell.borrow_mut();
            let fresh = cache.as_ref().is_some_and(|s| s.model == self.id && s.theta == theta && s.t_end >= t_needed);
            if !fresh {
                let solved = self.solve(theta, t_needed);
                if solved.dense.is_none() {
                    self.failures.fetch_add(1, Ordering::Relaxed);
                }
                *cache = Some(solved);
            }
            self.predict_from(cache.as_ref().expect("just solved"), observable, x, theta, out);
        });
    }

    /// Records the latest data time (one integration then serves every
    /// observable) and checks that the initial values and rates are finite
    /// at t0 at every corner of the prior box: a division by zero there is a
    /// declaration error. Later failures only cost their θ its likelihood.
    fn check_inputs(&self, _observable: usize, x: &[f64]) -> Result<()> {
        if let Some(t) = x.iter().find(|t| **t < self.t0) {
            bail!("a data point at t = {t} lies before t0 = {} of the ODE model, where it has no state", self.t0);
        }
        let latest = x.iter().copied().fold(self.horizon(), f64::max);
        self.horizon.store(latest.to_bits(), Ordering::Relaxed);
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
}
