//! The solution of one integration at one θ, as the predictions read it:
//! the states at the data grid's points, or a continuous output.

use super::grid::Grid;
use nalgebra::allocator::Allocator;
use nalgebra::{Const, DefaultAllocator, Dim, Dyn, OVector};
use ode_solvers::continuous_output_model::ContinuousOutputModel;

/// Dense output of one integration: the states at the grid's points, or a
/// continuous output (up to four state variables in stack vectors, more in
/// heap vectors).
pub(super) enum Dense {
    Empty,
    /// `states[k·stride..]` begins with the state at grid point k.
    OnGrid {
        grid: Grid,
        states: Vec<f64>,
        /// Values per grid point: the state, then t when DOP853 carried it.
        stride: usize,
    },
    S1(ContinuousOutputModel<f64, OVector<f64, Const<1>>>),
    S2(ContinuousOutputModel<f64, OVector<f64, Const<2>>>),
    S3(ContinuousOutputModel<f64, OVector<f64, Const<3>>>),
    S4(ContinuousOutputModel<f64, OVector<f64, Const<4>>>),
    Heap(ContinuousOutputModel<f64, OVector<f64, Dyn>>),
}

impl Dense {
    /// The state at t into `y`; false outside the solution. The grid's case
    /// is inlined: it is asked once per data point per likelihood evaluation.
    #[inline]
    pub(super) fn state_at(&self, t: f64, y: &mut [f64]) -> bool {
        match self {
            Dense::OnGrid { grid, states, stride } => match grid.index(t) {
                Some(k) => {
                    copy_state(&states[k * stride..k * stride + y.len()], y);
                    true
                }
                None => false,
            },
            _ => self.continuous_state_at(t, y),
        }
    }

    #[inline(never)]
    fn continuous_state_at(&self, t: f64, y: &mut [f64]) -> bool {
        fn copy<D: Dim>(d: &ContinuousOutputModel<f64, OVector<f64, D>>, t: f64, y: &mut [f64]) -> bool
        where
            DefaultAllocator: Allocator<D>,
        {
            d.evaluate(t).map(|s| y.copy_from_slice(s.as_slice())).is_some()
        }
        match self {
            Dense::Empty | Dense::OnGrid { .. } => false,
            Dense::S1(d) => copy(d, t, y),
            Dense::S2(d) => copy(d, t, y),
            Dense::S3(d) => copy(d, t, y),
            Dense::S4(d) => copy(d, t, y),
            Dense::Heap(d) => copy(d, t, y),
        }
    }
}

/// `y.copy_from_slice(from)`, inlined for the few numbers of a small state:
/// a call to memcpy per data point cost more than the copy.
#[inline]
fn copy_state(from: &[f64], y: &mut [f64]) {
    match (y, from) {
        ([y0], [a]) => *y0 = *a,
        ([y0, y1], [a, b]) => (*y0, *y1) = (*a, *b),
        ([y0, y1, y2], [a, b, c]) => (*y0, *y1, *y2) = (*a, *b, *c),
        (y, from) => y.copy_from_slice(from),
    }
}
