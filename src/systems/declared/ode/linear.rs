//! Equations of motion that are affine in the state, y' = A y + b with A and
//! b functions of θ and constants only (the drag-free ball, the harmonic
//! oscillator, first-order kinetics, and candidates such as linear drag or
//! a constant force), have an exact solution: over a grid step dx,
//! (y, 1) ← P (y, 1) with P = exp(M dx) and M = [[A, b], [0, 0]].
//!
//! One matrix exponential per θ (nalgebra's scaling-and-squaring Padé
//! method of Al-Mohy & Higham 2009, after scipy's `expm`) and one small
//! matrix–vector product per grid point replace the integration: exact to
//! rounding where DOP853 is exact to its tolerance, and on the declared ball
//! drop several times cheaper than the few adaptive steps it took.
//!
//! A and b are read off the compiled rates: b = f(0) and column j of A is
//! (f(s e_j) − b)/s, exact for an affine f up to rounding (s a power of two,
//! so the division is exact and the rounding of b is small beside A's).

use super::super::declaration::MAX_NAMES;
use super::super::formula::Formula;
use super::grid::Grid;
use nalgebra::allocator::Allocator;
use nalgebra::{Const, DefaultAllocator, Dim, DimMin, DimMinimum, OMatrix};

/// The probe's size along one state axis: large beside the rounding of b.
const PROBE: f64 = 1_048_576.0;

/// Largest ‖M dx‖₁ the propagator is used for: far beyond any mode the grid
/// resolves (a growing one has overflowed long before); past it, the
/// integrator decides.
const MAX_NORM: f64 = 1e6;

/// Most states the propagator handles (the augmented matrix is at most 5 × 5
/// on the stack); larger systems are integrated.
pub(super) const MAX_STATES: usize = 4;

/// Whether every rate is affine in the states (degree at most one, with
/// coefficients free of them) and none reads t.
pub(super) fn is_affine(rates: &[Formula], states: &[String], time: &str) -> bool {
    let is_state = |n: &str| states.iter().any(|s| s == n);
    let no_time = |f: &Formula| f.degree(&|n| n == time) == Some(0);
    states.len() <= MAX_STATES && rates.iter().all(|f| f.degree(&is_state).is_some_and(|d| d <= 1) && no_time(f))
}

/// The state at every point of `grid` from `y0` (row-major, `y0.len()` per
/// point, t0 first), with θ and constants in `values` and the states from
/// index `state_at`. None when A, b or P is not finite or ‖M dx‖₁ exceeds
/// [`MAX_NORM`]: then the integrator is asked instead.
pub(super) fn propagate(
    rates: &[Formula],
    mut values: [f64; MAX_NAMES],
    state_at: usize,
    y0: &[f64],
    grid: &Grid,
) -> Option<Vec<f64>> {
    let n = y0.len();
    let n1 = n + 1;
    // M dx, row-major, (n + 1) × (n + 1); its last row stays zero.
    let mut m = [0.0; (MAX_STATES + 1) * (MAX_STATES + 1)];
    values[state_at..state_at + n].fill(0.0);
    for (i, f) in rates.iter().enumerate() {
        m[i * n1 + n] = f.eval(&values) * grid.dx;
    }
    for j in 0..n {
        values[state_at + j] = PROBE;
        for (i, f) in rates.iter().enumerate() {
            m[i * n1 + j] = (f.eval(&values) * grid.dx - m[i * n1 + n]) / PROBE;
        }
        values[state_at + j] = 0.0;
    }
    let m = &m[..n1 * n1];
    let norm = (0..n1).map(|j| (0..n1).map(|i| m[i * n1 + j].abs()).sum::<f64>()).fold(0.0, f64::max);
    if !(norm <= MAX_NORM) {
        return None;
    }
    let mut p = [0.0; (MAX_STATES + 1) * (MAX_STATES + 1)];
    let p = &mut p[..n1 * n1];
    let finite = match n1 {
        2 => exponential::<Const<2>>(m, p),
        3 => exponential::<Const<3>>(m, p),
        4 => exponential::<Const<4>>(m, p),
        _ => exponential::<Const<5>>(m, p),
    };
    finite.then(|| walk(p, y0, grid.last))
}

/// exp(M) into `p` (both row-major); whether it is finite.
fn exponential<D>(m: &[f64], p: &mut [f64]) -> bool
where
    D: Dim + DimMin<D, Output = D>,
    DefaultAllocator: Allocator<D, D> + Allocator<DimMinimum<D, D>> + Allocator<D>,
{
    let k = D::from_usize((p.len() as f64).sqrt() as usize);
    let exp = OMatrix::<f64, D, D>::from_row_slice_generic(k, k, m).exp();
    for (i, row) in p.chunks_mut(k.value()).enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = exp[(i, j)];
        }
    }
    p.iter().all(|v| v.is_finite())
}

/// The states at grid points 0..=last: z ← P z from z = (y0, 1).
fn walk(p: &[f64], y0: &[f64], last: usize) -> Vec<f64> {
    let n = y0.len();
    let n1 = n + 1;
    let mut states = Vec::with_capacity(n * (last + 1));
    states.extend_from_slice(y0);
    let mut z = [0.0; MAX_STATES + 1];
    z[..n].copy_from_slice(y0);
    z[n] = 1.0;
    for _ in 0..last {
        let mut next = [0.0; MAX_STATES + 1];
        for (i, out) in next[..n].iter_mut().enumerate() {
            *out = p[i * n1..(i + 1) * n1].iter().zip(&z[..n1]).map(|(a, b)| a * b).sum();
        }
        next[n] = 1.0;
        z = next;
        states.extend_from_slice(&z[..n]);
    }
    states
}

#[cfg(test)]
mod tests {
    use crate::engine::model::Simulator;
    use std::sync::Arc;

    /// A declared ODE model from its `[model]` tables, with data at `times`
    /// for its one observable `y`.
    fn model(name: &str, tables: &str, parameters: &str, times: &[f64]) -> Arc<dyn Simulator> {
        let dir = std::env::temp_dir().join(format!("mdpipe-linear-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rows: String = times.iter().map(|t| format!("y,{t},1.0,0.1\n")).collect();
        std::fs::write(dir.join("data.csv"), format!("observable,x,value,error\n{rows}")).unwrap();
        let config = format!(
            "name = \"{name}\"\n[model]\nkind = \"ode\"\nt0 = 0.0\n{tables}\n[model.solver]\nrtol = 1e-10\natol = 1e-12\n\
             [data]\nmeasurements = \"data.csv\"\n{parameters}"
        );
        std::fs::write(dir.join("m.toml"), config).unwrap();
        let model = crate::systems::load(&dir.join("m.toml")).expect("the test model").simulator;
        std::fs::remove_dir_all(&dir).ok();
        model.check_inputs(0, times).unwrap();
        model
    }

    fn last_was_exact() -> bool {
        super::super::SOLVED.with(|c| c.borrow().as_ref().is_some_and(|s| s.exact))
    }

    /// The predictions at `theta`, given in the order of the config's tables.
    fn predictions(m: &dyn Simulator, times: &[f64], theta: &[f64]) -> Vec<f64> {
        assert!(m.parameter_names().windows(2).all(|w| w[0] < w[1]), "parameters in alphabetical order");
        let mut out = vec![0.0; times.len()];
        m.predict(0, times, theta, &mut out);
        out
    }

    /// A damped oscillator, x'' = −w²x − 2g x', from x0 at rest, against
    /// its closed form; solved by the propagator, not an integrator.
    #[test]
    fn a_damped_oscillator_is_solved_exactly() {
        let times: Vec<f64> = (1..=40).map(|k| 0.25 * k as f64).collect();
        let tables = "[model.initial]\nx = \"x0\"\nv = \"0\"\n[model.rates]\nx = \"v\"\nv = \"-w^2*x - 2*g*v\"\n\
                      [model.observables]\ny = \"x\"";
        let params = "[parameters.g]\nmin = 0.0\nmax = 0.4\n[parameters.w]\nmin = 0.5\nmax = 6.0\n\
                      [parameters.x0]\nmin = 0.1\nmax = 2.0\n";
        let m = model("damped", tables, params, &times);
        for (w, g, x0) in [(2.0, 0.1, 1.0), (0.5, 0.3, 1.5), (6.0, 0.0, 0.3), (3.3, 0.4, 2.0)] {
            let got = predictions(m.as_ref(), &times, &[g, w, x0]);
            assert!(last_was_exact(), "w = {w}, g = {g}");
            let wd: f64 = (w * w - g * g).sqrt();
            for (t, y) in times.iter().zip(&got) {
                let want = x0 * (-g * t).exp() * ((wd * t).cos() + g / wd * (wd * t).sin());
                assert!((y - want).abs() < 1e-11 * x0, "w = {w}, g = {g}, t = {t}: {y} vs {want}");
            }
        }
    }

    /// A falling ball with linear drag, v' = g − b v and h' = −v, against
    /// its closed form.
    #[test]
    fn linear_drag_is_solved_exactly() {
        let times: Vec<f64> = (0..=9).map(|k| k as f64 / 9.0).collect();
        let tables = "[model.initial]\nh = \"60\"\nv = \"v0\"\n[model.rates]\nh = \"-v\"\nv = \"g - b*v\"\n\
                      [model.observables]\ny = \"h\"";
        let params = "[parameters.b]\nmin = 0.01\nmax = 2.0\n[parameters.g]\nmin = 0.0\nmax = 20.0\n\
                      [parameters.v0]\nmin = -2.0\nmax = 2.0\n";
        let m = model("drag", tables, params, &times);
        for (g, b, v0) in [(9.8, 0.4, 0.0), (19.0, 0.01, -2.0), (1.0, 2.0, 1.5)] {
            let got = predictions(m.as_ref(), &times, &[b, g, v0]);
            assert!(last_was_exact());
            let vt = g / b;
            for (t, y) in times.iter().zip(&got) {
                let want = 60.0 - vt * t - (v0 - vt) * (1.0 - (-b * t).exp()) / b;
                assert!((y - want).abs() < 1e-11 * 60.0, "g = {g}, b = {b}, t = {t}: {y} vs {want}");
            }
        }
    }

    /// Rates that are not affine in the state, or read t, are integrated.
    #[test]
    fn other_rates_are_integrated() {
        let times: Vec<f64> = (1..=10).map(|k| 0.5 * k as f64).collect();
        let params = "[parameters.a]\nmin = 0.1\nmax = 2.0\n";
        for (name, rate) in [("cubic", "-a*y^3"), ("product", "-a*y*abs(y)"), ("clock", "-a*y + sin(t)")] {
            let tables =
                format!("[model.initial]\ny = \"1\"\n[model.rates]\ny = \"{rate}\"\n[model.observables]\ny = \"y\"");
            let m = model(name, &tables, params, &times);
            let got = predictions(m.as_ref(), &times, &[0.5]);
            assert!(!last_was_exact(), "{rate}");
            assert!(got.iter().all(|y| y.is_finite()), "{rate}");
        }
    }
}
