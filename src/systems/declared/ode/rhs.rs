//! The equations of motion as `ode_solvers` sees them, and the watch an
//! integration over the data's grid may keep: the χ² of the data points it
//! has passed, so that it can stop once a θ misses the data by more than a
//! sampler could notice (`Simulator::chi_square_exceeds`).

use super::expanded::{ExpandedRates, MAX_COEFFICIENTS};
use super::grid::Grid;
use super::OdeModel;
use crate::engine::formula::polynomial::{fill_powers, MAX_DEGREE, MAX_VARIABLES};
use crate::engine::model::ObservedData;
use crate::systems::declared::declaration::MAX_NAMES;
use nalgebra::allocator::Allocator;
use nalgebra::{DefaultAllocator, Dim, OVector};
use ode_solvers::System;
use std::cell::{Cell, RefCell};

pub(super) struct Rhs<'a> {
    pub model: &'a OdeModel,
    /// θ and constants in place; t and the state are written per call (in
    /// place: a copy of the whole vector per call was a tenth of the time).
    pub values: RefCell<[f64; MAX_NAMES]>,
    /// t is the last state (dt/dt = 1) rather than the solver's time.
    pub clock: bool,
    pub watch: Option<Watch<'a>>,
    /// The expanded rates' coefficients at this θ, and a buffer of the
    /// state's powers (`expanded`).
    expanded: Option<(&'a ExpandedRates, [f64; MAX_COEFFICIENTS])>,
    powers: RefCell<[[f64; MAX_DEGREE]; MAX_VARIABLES]>,
}

impl<'a> Rhs<'a> {
    /// The rates at the θ and constants in `values`.
    pub fn new(model: &'a OdeModel, values: [f64; MAX_NAMES], clock: bool, watch: Option<Watch<'a>>) -> Rhs<'a> {
        let expanded = model.expanded.as_ref().map(|e| (e, e.coefficients(&values)));
        Rhs {
            model,
            values: RefCell::new(values),
            clock,
            watch,
            expanded,
            powers: RefCell::new([[0.0; MAX_DEGREE]; MAX_VARIABLES]),
        }
    }
}

/// The data points at each point of a grid: (observable, value, 1/error),
/// `entries[starts[k]..starts[k + 1]]` at grid point k.
pub(super) struct Checks {
    pub data: u64,
    pub grid: Grid,
    starts: Vec<usize>,
    entries: Vec<(usize, f64, f64)>,
}

impl Checks {
    /// The points of `data` on `grid`; None when one lies off it.
    pub fn of(data: &ObservedData, grid: Grid) -> Option<Checks> {
        let mut at: Vec<(usize, usize, f64, f64)> = Vec::new();
        for s in &data.series {
            for ((x, y), w) in s.x.iter().zip(&s.y).zip(&s.inv_error) {
                at.push((grid.index(*x)?, s.observable, *y, *w));
            }
        }
        at.sort_by_key(|a| a.0);
        let mut starts = vec![0; grid.last + 2];
        for a in &at {
            starts[a.0 + 1] += 1;
        }
        for k in 0..=grid.last {
            starts[k + 1] += starts[k];
        }
        let entries = at.into_iter().map(|(_, o, y, w)| (o, y, w)).collect();
        Some(Checks { data: data.id, grid, starts, entries })
    }

    fn at(&self, k: usize) -> &[(usize, f64, f64)] {
        &self.entries[self.starts[k]..self.starts[k + 1]]
    }
}

/// The χ² of the grid points an integration has passed, against a limit.
pub(super) struct Watch<'a> {
    pub checks: &'a Checks,
    pub limit: f64,
    chi_square: f64,
    /// The first grid point not yet counted.
    next: usize,
    /// Set when the χ² passed the limit (the solver owns the watch, its
    /// caller reads this).
    exceeded: &'a Cell<bool>,
}

impl<'a> Watch<'a> {
    pub fn new(checks: &'a Checks, limit: f64, exceeded: &'a Cell<bool>) -> Watch<'a> {
        exceeded.set(false);
        Watch { checks, limit, chi_square: 0.0, next: 0, exceeded }
    }

    /// The grid point whose state the solver output last, given the
    /// solver's time x; None where x is too near a grid point to tell
    /// whether the solver, walking the grid by a running sum, has output it.
    fn latest_point(&self, x: f64) -> Option<usize> {
        let g = &self.checks.grid;
        let q = (x - g.t0) / g.dx;
        let k = q.floor();
        (q - k > 1e-7 && k >= 0.0).then_some((k as usize).min(g.last))
    }
}

impl<D: Dim> System<f64, OVector<f64, D>> for Rhs<'_>
where
    DefaultAllocator: Allocator<D>,
{
    fn system(&self, t: f64, y: &OVector<f64, D>, dy: &mut OVector<f64, D>) {
        let n = self.model.rates.len();
        if let Some((expanded, c)) = &self.expanded {
            let mut powers = self.powers.borrow_mut();
            fill_powers(&y.as_slice()[..n], expanded.degree, &mut powers[..n]);
            for (k, rate) in expanded.rates.iter().enumerate() {
                if let Some((p, at)) = rate {
                    dy[k] = p.eval(&c[*at..], &powers[..n]);
                }
            }
            if expanded.all {
                if self.clock {
                    dy[n] = 1.0;
                }
                return;
            }
        }
        let mut v = self.values.borrow_mut();
        v[0] = if self.clock { y[n] } else { t };
        let at = self.model.variables.state_at;
        // A loop, not copy_from_slice: n is a handful and memcpy's call cost
        // more than the copy (perf, the ball drop with drag).
        for (slot, y) in v[at..at + n].iter_mut().zip(y.iter()) {
            *slot = *y;
        }
        let expanded = self.expanded.as_ref().map(|(e, _)| &e.rates);
        for (k, rate) in self.model.rates.iter().enumerate() {
            if expanded.is_none_or(|e| e[k].is_none()) {
                dy[k] = rate.eval(&v[..]);
            }
        }
        if self.clock {
            dy[n] = 1.0;
        }
    }

    /// After each accepted step: adds the data at the grid point the
    /// solver output last (`y`, its state) to the watch's χ², and stops the
    /// integration once that exceeds the limit. A step that passes several
    /// grid points shows only the last, so the sum is a lower bound of the
    /// χ² of the points passed: a stop is always right, if sometimes late.
    fn solout(&mut self, x: f64, y: &OVector<f64, D>, _dy: &OVector<f64, D>) -> bool {
        let Some(watch) = self.watch.as_mut() else {
            return false;
        };
        let Some(k) = watch.latest_point(x) else {
            return false;
        };
        if k < watch.next {
            return false;
        }
        watch.next = k + 1;
        let model = self.model;
        let v = self.values.get_mut();
        let (at, n) = (model.variables.state_at, model.rates.len());
        v[0] = watch.checks.grid.t0 + k as f64 * watch.checks.grid.dx;
        for (slot, y) in v[at..at + n].iter_mut().zip(y.iter()) {
            *slot = *y;
        }
        let mut rates_set = false;
        for &(observable, value, inv_error) in watch.checks.at(k) {
            if model.uses_rates[observable] && !rates_set {
                for (j, rate) in model.rates.iter().enumerate() {
                    v[model.variables.rate_at + j] = rate.eval(&v[..]);
                }
                rates_set = true;
            }
            let r = (value - model.formulas[observable].eval(&v[..])) * inv_error;
            if r.is_finite() {
                watch.chi_square += r * r;
            }
        }
        let exceeded = watch.chi_square > watch.limit;
        watch.exceeded.set(exceeded);
        exceeded
    }
}
