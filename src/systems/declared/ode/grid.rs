//! The data's times as a grid `t0 + k·dx`, so that an integration can hand
//! out the state at every data time as it passes them (the 8th-order
//! Dormand–Prince method of `ode_solvers` interpolates only on such a grid).

/// Most grid points an integration may interpolate: beyond this, data times
/// without a common spacing use the continuous output instead.
const MAX_POINTS: usize = 4096;

/// Relative distance from a grid point within which a time lies on it.
const ON_GRID: f64 = 1e-9;

/// Smallest spacing, relative to the times, of a grid: the solver walks it
/// by adding dx, which must move a time by many ulps (a dx lost in the
/// rounding of t would never advance and the walk would not end).
const MIN_RELATIVE_STEP: f64 = 1e-6;

/// Equally spaced times from t0 holding every data time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Grid {
    pub t0: f64,
    pub dx: f64,
    /// Index of the last point (the latest data time).
    pub last: usize,
    /// 1/dx: `index` multiplies, a division being several times slower and
    /// asked once per data point per likelihood evaluation.
    inverse_dx: f64,
    /// `last + 1` as a float, the bound `index` checks against.
    past_last: f64,
}

impl Grid {
    /// The coarsest grid from `t0` on which every time lies: the smallest gap
    /// between distinct times divided by 1, 2, … 64; None when there is no
    /// such grid of at most [`MAX_POINTS`] points and a spacing the times
    /// resolve, no time after t0, or t0 < 0.
    pub fn holding(t0: f64, times: &[f64]) -> Option<Grid> {
        // ode_solvers walks its output grid comparing |t|s (written for
        // integrating backwards): a walk that crosses zero never advances
        // (measured: calibrations from t0 = −0.5 s hung). Negative times
        // use the continuous output.
        if t0 < 0.0 {
            return None;
        }
        let mut offsets: Vec<f64> = times.iter().map(|t| t - t0).filter(|d| *d > 0.0).collect();
        offsets.sort_by(f64::total_cmp);
        offsets.dedup();
        let latest = *offsets.last()?;
        let smallest_gap = offsets
            .iter()
            .scan(0.0, |previous, d| {
                let gap = d - *previous;
                *previous = *d;
                Some(gap)
            })
            .fold(f64::INFINITY, f64::min);
        let scale = t0.abs().max((t0 + latest).abs());
        (1..=64).map(|m| smallest_gap / m as f64).take_while(|dx| *dx > MIN_RELATIVE_STEP * scale).find_map(|dx| {
            let last = (latest / dx).round();
            let grid = Grid { t0, dx, last: last as usize, inverse_dx: 1.0 / dx, past_last: last + 1.0 };
            (last <= MAX_POINTS as f64 && offsets.iter().all(|d| grid.index(t0 + d).is_some())).then_some(grid)
        })
    }

    /// The index of the grid point at `t`; None when t is not on the grid.
    pub fn index(&self, t: f64) -> Option<usize> {
        // The nearest point by truncation of a non-negative number: `round`
        // is a library call on the baseline x86-64 target, and this is asked
        // once per data point per likelihood evaluation.
        // q may differ from (t − t0)/dx + 0.5 in its last bit: that moves
        // the truncation only for times halfway between two points, which
        // the check below refuses either way.
        let q = (t - self.t0) * self.inverse_dx + 0.5;
        if !(q >= 0.0 && q < self.past_last) {
            return None;
        }
        // Through i32, not usize: the checks above bound q by MAX_POINTS,
        // and the unsigned 64-bit conversions each way cost a dozen
        // instructions on x86-64 (asked once per data point per evaluation).
        let k = q as i32;
        let point = self.t0 + f64::from(k) * self.dx;
        let k = k as usize;
        ((t - point).abs() <= ON_GRID * point.abs().max(self.dx)).then_some(k)
    }

    pub fn end(&self) -> f64 {
        self.t0 + self.last as f64 * self.dx
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evenly_spaced_times_give_their_spacing() {
        let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
        let g = Grid::holding(0.0, &times).expect("a grid");
        assert_eq!(g.last, 40);
        assert!((g.dx - 0.25).abs() < 1e-15);
        assert_eq!(g.index(2.5), Some(10));
        assert_eq!(g.index(2.6), None);
        assert_eq!(g.index(10.25), None, "past the last data time");
    }

    #[test]
    fn uneven_times_find_their_common_step() {
        // gaps 0.2 and 0.3: the common step is 0.1, found as 0.2 / 2
        let g = Grid::holding(1.0, &[1.2, 1.5, 1.5, 2.0]).expect("a grid");
        assert!((g.dx - 0.1).abs() < 1e-15);
        assert_eq!(g.index(1.5), Some(5));
        assert_eq!(g.last, 10);
    }

    #[test]
    fn times_without_a_common_step_have_no_grid() {
        assert_eq!(Grid::holding(0.0, &[1.0, std::f64::consts::PI]), None);
        assert_eq!(Grid::holding(0.0, &[0.0]), None, "no time after t0");
        assert_eq!(Grid::holding(0.0, &[]), None);
        // Times before zero: the solver's walk over them would not end.
        assert_eq!(Grid::holding(-0.5, &[-0.25, 0.0, 0.25]), None);
        // Spacing lost in the rounding of the times themselves.
        assert_eq!(Grid::holding(1e9, &[1e9 + 1e-4, 1e9 + 2e-4]), None);
    }
}
