//! The integrations themselves: DOP853 over the data's grid, and
//! Dormand–Prince 5(4) with continuous output from any start (t0, or an
//! anchor of `shooting`).

use super::dense::Dense;
use super::grid::Grid;
use super::rhs::{Checks, Rhs, Watch};
use super::OdeModel;
use crate::systems::declared::declaration::MAX_NAMES;
use nalgebra::allocator::Allocator;
use nalgebra::{Const, DefaultAllocator, Dim, Dyn, OVector, U1};
use ode_solvers::continuous_output_model::ContinuousOutputModel;
use ode_solvers::{Dop853, Dopri5, OutputType};
use std::cell::Cell;

impl OdeModel {
    /// Dormand–Prince 5(4) from `y0` at `t_start` to `t_end`, its continuous
    /// output in stack vectors for up to four states; None when it fails.
    pub(super) fn integrate_from(&self, v: [f64; MAX_NAMES], t_start: f64, y0: &[f64], t_end: f64) -> Option<Dense> {
        match y0.len() {
            1 => self.integrate::<Const<1>>(v, t_start, y0, t_end).map(Dense::S1),
            2 => self.integrate::<Const<2>>(v, t_start, y0, t_end).map(Dense::S2),
            3 => self.integrate::<Const<3>>(v, t_start, y0, t_end).map(Dense::S3),
            4 => self.integrate::<Const<4>>(v, t_start, y0, t_end).map(Dense::S4),
            _ => self.integrate::<Dyn>(v, t_start, y0, t_end).map(Dense::Heap),
        }
    }

    /// DOP853 from t0 to the grid's end, interpolating the state at every
    /// grid point; `y0` ends with t0 when the rates read t. None when the
    /// integration fails or its watch stopped it (then true).
    pub(super) fn integrate_on_grid<D: Dim>(
        &self,
        values: [f64; MAX_NAMES],
        y0: &[f64],
        grid: Grid,
        watch: Option<(&Checks, f64)>,
    ) -> (Option<Dense>, bool)
    where
        DefaultAllocator: Allocator<D>,
        OVector<f64, D>: std::ops::Mul<f64, Output = OVector<f64, D>>,
    {
        let y = OVector::<f64, D>::from_iterator_generic(D::from_usize(y0.len()), U1, y0.iter().copied());
        let (rtol, atol) = self.precision.tolerances(&self.solver);
        // Half a grid step past the last point: the crate's interpolation
        // at the very end of an integration is off (1e-5 where 1e-8 was
        // asked, measured on the oscillator), inside a step it is right.
        let t_end = grid.end() + 0.5 * grid.dx;
        let span = t_end - self.t0;
        let exceeded = Cell::new(false);
        let watch = watch.map(|(checks, limit)| Watch::new(checks, limit, &exceeded));
        let rhs = Rhs::new(self, values, !self.autonomous, watch);
        // Hairer's defaults for DOP853: safety 0.9, no PI term, step factors
        // in [0.333, 6], stiffness tested every 1000 steps.
        let mut stepper = Dop853::from_param(
            rhs,
            self.t0,
            t_end,
            grid.dx,
            y,
            rtol,
            atol,
            0.9,
            0.0,
            0.333,
            6.0,
            span,
            0.0,
            self.solver.max_steps,
            1000,
            OutputType::Dense,
        );
        let ended = stepper.integrate().is_ok();
        if exceeded.get() {
            return (None, true);
        }
        let (times, ys) = stepper.results().get();
        // One state per grid point, t0 included; the solver's running sum of
        // dx must land on the grid.
        if !ended || ys.len() != grid.last + 1 || times.last().is_none_or(|t| grid.index(*t) != Some(grid.last)) {
            return (None, false);
        }
        let states = ys.iter().flat_map(|y| y.iter().copied()).collect();
        (Some(Dense::OnGrid { grid, states, stride: y0.len() }), false)
    }

    /// Dormand–Prince 5(4) from `t_start` to `t_end` with the state in
    /// vectors of dimension `D`; None when the integration fails.
    pub(super) fn integrate<D: Dim>(
        &self,
        values: [f64; MAX_NAMES],
        t_start: f64,
        y0: &[f64],
        t_end: f64,
    ) -> Option<ContinuousOutputModel<f64, OVector<f64, D>>>
    where
        DefaultAllocator: Allocator<D>,
        OVector<f64, D>: std::ops::Mul<f64, Output = OVector<f64, D>>,
    {
        let y = OVector::<f64, D>::from_iterator_generic(D::from_usize(y0.len()), U1, y0.iter().copied());
        let (rtol, atol) = self.precision.tolerances(&self.solver);
        let span = t_end - t_start;
        let rhs = Rhs::new(self, values, false, None);
        let mut stepper = Dopri5::from_param(
            rhs,
            t_start,
            t_end,
            span,
            y,
            rtol,
            atol,
            0.9,
            0.04,
            0.2,
            10.0,
            span,
            0.0,
            self.solver.max_steps,
            1000,
            OutputType::Dense,
        );
        let mut dense = ContinuousOutputModel::new();
        stepper.integrate_with_continuous_output_model(&mut dense).ok().map(|_| dense)
    }
}
