//! Equations of motion that are affine in the state, y' = A y + b with A and
//! b functions of θ and constants only (the drag-free ball, the harmonic
//! oscillator, first-order kinetics, and candidates such as linear drag or
//! a constant force), have an exact solution: over a grid step dx,
//! (y, 1) ← P (y, 1) with P = exp(M dx) and M = [[A, b], [0, 0]].
//!
//! A forcing that is a sinusoid of t, `a*sin(w*t + p)` with w and p free of
//! the state, joins in: sin and cos of the phase are two more states (s' =
//! w c, c' = −w s), which keeps the enlarged system affine and autonomous.
//! A driven oscillator, or kinetics with a periodic source, is then exact
//! too, at any frequency, where an integrator takes steps per period.
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

use super::super::declaration::{Variables, MAX_NAMES};
use super::grid::Grid;
use crate::engine::formula::notation::Expr;
use crate::engine::formula::{Formula, Scope};
use nalgebra::allocator::Allocator;
use nalgebra::{Const, DefaultAllocator, Dim, DimMin, DimMinimum, OMatrix};

/// The probe's size along one state axis: large beside the rounding of b.
const PROBE: f64 = 1_048_576.0;

/// Largest ‖M dx‖₁ the propagator takes: scaling and squaring halves M
/// log2(‖M‖) times, and far past this the halving would underflow. A
/// stiff decay (k = 1e9 over a step of 0.1) or a fast sinusoid is far
/// below it; a growing mode overflows long before.
const MAX_NORM: f64 = 1e100;

/// Most states, sinusoids' two included, the propagator handles (the
/// augmented matrix is at most 7 × 7, on the stack); larger systems are
/// integrated.
const MAX_STATES: usize = 6;
const MAX_SIDE: usize = MAX_STATES + 1;

/// An affine system ready to propagate.
pub(super) struct Affine {
    /// The rates with each sinusoid of t replaced by a name of its own (the
    /// value-vector slots after the states, which rates never read).
    rates: Vec<Formula>,
    /// Each sinusoid's phase, α t + β: a formula of t, θ and constants.
    phases: Vec<Formula>,
    /// Where the first sinusoid's sin sits in the value vector (then its
    /// cos, then the next sinusoid's).
    extra_at: usize,
}

impl Affine {
    /// The plan for `rates` (over the model's names up to its states), or
    /// None when some rate is not affine in the state once sinusoids of t
    /// are taken out, or reads t otherwise.
    pub(super) fn of(rates: &[Formula], variables: &Variables, states: &[String], time: &str) -> Option<Affine> {
        let is_state = |n: &str| states.iter().any(|s| s == n);
        let mut phases_found = Vec::new();
        let rewritten: Vec<Expr> =
            rates.iter().map(|f| take_sinusoids(f.expr(), &is_state, time, &mut phases_found)).collect();
        let extras: Vec<String> =
            (0..phases_found.len()).flat_map(|k| [format!("sin({k})"), format!("cos({k})")]).collect();
        let extra_at = variables.rate_at;
        if states.len() + extras.len() > MAX_STATES || extra_at + extras.len() > MAX_NAMES {
            return None;
        }
        let is_unknown = |n: &str| is_state(n) || extras.iter().any(|e| e == n);
        let affine = rewritten
            .iter()
            .all(|e| e.degree(&|n| n == time) == Some(0) && e.degree(&is_unknown).is_some_and(|d| d <= 1));
        if !affine {
            return None;
        }
        let base = variables.scope(variables.rate_at);
        let scope = Scope::new(base.names().iter().cloned().chain(extras.iter().cloned()));
        let before_state = variables.scope(variables.state_at);
        let rates = rewritten
            .into_iter()
            .zip(rates)
            .map(|(e, f)| Formula::from_expr(f.text(), e, &scope, "").ok())
            .collect::<Option<Vec<_>>>()?;
        let phases = phases_found
            .into_iter()
            .map(|e| Formula::from_expr("", e, &before_state, "").ok())
            .collect::<Option<Vec<_>>>()?;
        Some(Affine { rates, phases, extra_at })
    }

    /// The state at every point of `grid` from `y0` at its t0 into `states`
    /// (row-major, `y0.len()` per point, t0 first; its old contents are
    /// dropped, its allocation kept), with θ and constants in `values` and
    /// the states from index `state_at`. False when there is no solution at
    /// this θ: M undefined (a rate NaN or infinite) or P overflowing (a
    /// growing mode), where an integrator would fail too.
    pub(super) fn propagate(
        &self,
        values: &mut [f64; MAX_NAMES],
        state_at: usize,
        y0: &[f64],
        grid: &Grid,
        states: &mut Vec<f64>,
    ) -> bool {
        let n = y0.len();
        let k = 2 * self.phases.len();
        let (side, one) = (n + k + 1, n + k);
        // The unknowns' slots in the value vector: the states, then sin and cos of each phase.
        let slot = |j: usize| if j < n { state_at + j } else { self.extra_at + j - n };
        // Initial values, and each phase's rate α (its change over unit time).
        let mut z0 = [0.0; MAX_SIDE];
        z0[..n].copy_from_slice(y0);
        z0[one] = 1.0;
        let mut alpha = [0.0; MAX_STATES / 2];
        values[0] = grid.t0;
        for (p, f) in self.phases.iter().enumerate() {
            let at_t0 = f.eval(&values[..]);
            values[0] = grid.t0 + 1.0;
            alpha[p] = f.eval(&values[..]) - at_t0;
            values[0] = grid.t0;
            (z0[n + 2 * p], z0[n + 2 * p + 1]) = at_t0.sin_cos();
        }
        // M dx, row-major, side × side; its last row stays zero.
        let mut m = [0.0; MAX_SIDE * MAX_SIDE];
        for j in 0..one {
            values[slot(j)] = 0.0;
        }
        for (i, f) in self.rates.iter().enumerate() {
            m[i * side + one] = f.eval(&values[..]) * grid.dx;
        }
        for j in 0..one {
            values[slot(j)] = PROBE;
            for (i, f) in self.rates.iter().enumerate() {
                m[i * side + j] = (f.eval(&values[..]) * grid.dx - m[i * side + one]) / PROBE;
            }
            values[slot(j)] = 0.0;
        }
        for (p, a) in alpha[..self.phases.len()].iter().enumerate() {
            let (s, c) = (n + 2 * p, n + 2 * p + 1);
            m[s * side + c] = a * grid.dx;
            m[c * side + s] = -a * grid.dx;
        }
        let m = &m[..side * side];
        let norm = (0..side).map(|j| (0..side).map(|i| m[i * side + j].abs()).sum::<f64>()).fold(0.0, f64::max);
        if !(norm <= MAX_NORM) {
            return false;
        }
        let mut p = [0.0; MAX_SIDE * MAX_SIDE];
        let p = &mut p[..side * side];
        let finite = if nilpotent_exponential(m, side, p) {
            p.iter().all(|v| v.is_finite())
        } else {
            match side {
                2 => exponential::<Const<2>>(m, p),
                3 => exponential::<Const<3>>(m, p),
                4 => exponential::<Const<4>>(m, p),
                5 => exponential::<Const<5>>(m, p),
                6 => exponential::<Const<6>>(m, p),
                _ => exponential::<Const<7>>(m, p),
            }
        };
        finite && {
            walk(p, &z0[..side], n, grid.last, states);
            states.iter().all(|v| v.is_finite())
        }
    }
}

/// `e` with each sin or cos of a phase α t + β (α, β free of the state) replaced by
/// the name `sin(k)` or `cos(k)`, k the phase's place in `found`.
fn take_sinusoids(e: &Expr, is_state: &dyn Fn(&str) -> bool, time: &str, found: &mut Vec<Expr>) -> Expr {
    let mut again = |x: &Expr| take_sinusoids(x, is_state, time, found);
    match e {
        Expr::Call(f, args) if (f == "sin" || f == "cos") && args.len() == 1 => {
            let phase = &args[0];
            if phase.degree(&|n| n == time) != Some(1) || phase.degree(is_state) != Some(0) {
                return Expr::Call(f.clone(), vec![again(phase)]);
            }
            let k = found.iter().position(|p| p == phase).unwrap_or_else(|| {
                found.push(phase.clone());
                found.len() - 1
            });
            Expr::Name(format!("{f}({k})"))
        }
        Expr::Call(f, args) => Expr::Call(f.clone(), args.iter().map(again).collect()),
        Expr::Neg(a) => Expr::Neg(Box::new(again(a))),
        Expr::Binary(op, a, b) => {
            let a = again(a);
            Expr::Binary(*op, Box::new(a), Box::new(take_sinusoids(b, is_state, time, found)))
        }
        Expr::Number(_) | Expr::Name(_) => e.clone(),
    }
}

/// exp(M) into `p` (both row-major, side × side) as its finite Taylor
/// series when M is nilpotent, M^k = 0 for some k ≤ side: then the series
/// is exact, exp(M) = I + M + … + M^(k−1)/(k−1)!. The drag-free ball and a
/// constant force are (M strictly triangular, so its powers are zero to
/// the bit), and there this costs a few dozen products where the Padé
/// method's scaling, squaring and LU solve cost several hundred; on the
/// declared ball drop the propagator was a fifth of an evaluation. False,
/// with `p` overwritten, when M is not nilpotent; a nonzero diagonal says so
/// at once for the damped and driven systems that are not.
fn nilpotent_exponential(m: &[f64], side: usize, p: &mut [f64]) -> bool {
    if (0..side).any(|i| m[i * side + i] != 0.0) {
        return false;
    }
    let mut term = [0.0; MAX_SIDE * MAX_SIDE];
    let mut next = [0.0; MAX_SIDE * MAX_SIDE];
    let term = &mut term[..side * side];
    let next = &mut next[..side * side];
    term.copy_from_slice(m);
    p.copy_from_slice(m);
    for i in 0..side {
        p[i * side + i] += 1.0;
    }
    for k in 2..=side {
        // next = term · M / k, so that term is M^k / k! on the k-th pass.
        let inv_k = 1.0 / k as f64;
        for i in 0..side {
            for j in 0..side {
                let dot: f64 = (0..side).map(|l| term[i * side + l] * m[l * side + j]).sum();
                next[i * side + j] = dot * inv_k;
            }
        }
        if next.iter().all(|v| *v == 0.0) {
            return true;
        }
        for (a, b) in p.iter_mut().zip(next.iter()) {
            *a += b;
        }
        term.copy_from_slice(next);
    }
    false
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

/// The first `n` values of z at grid points 0..=last into `states`: z ← P z from `z0`.
fn walk(p: &[f64], z0: &[f64], n: usize, last: usize, states: &mut Vec<f64>) {
    let side = z0.len();
    states.clear();
    states.extend_from_slice(&z0[..n]);
    let mut z = [0.0; MAX_SIDE];
    z[..side].copy_from_slice(z0);
    for _ in 0..last {
        let mut next = [0.0; MAX_SIDE];
        for (i, out) in next[..side - 1].iter_mut().enumerate() {
            *out = p[i * side..(i + 1) * side].iter().zip(&z[..side]).map(|(a, b)| a * b).sum();
        }
        next[side - 1] = 1.0;
        z = next;
        states.extend_from_slice(&z[..n]);
    }
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
        super::super::SOLVED.with(|c| c.borrow().first().is_some_and(|s| s.exact))
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

    /// First-order kinetics with a periodic source, y' = −u y + a sin(w t + p),
    /// against its closed form: the sinusoid is carried as two more states.
    /// Up to w = 40 (six steps a period on this grid, where an integrator
    /// must resolve every period).
    #[test]
    fn a_periodic_source_is_solved_exactly() {
        let times: Vec<f64> = (1..=20).map(|k| 0.25 * k as f64).collect();
        let tables = "[model.initial]\ny = \"5\"\n[model.rates]\ny = \"-u*y + a*sin(w*t + p)\"\n\
                      [model.observables]\ny = \"y\"";
        let params = "[parameters.a]\nmin = 0.0\nmax = 2.0\n[parameters.p]\nmin = -3.2\nmax = 3.2\n\
                      [parameters.u]\nmin = 0.1\nmax = 3.0\n[parameters.w]\nmin = 0.5\nmax = 40.0\n";
        let m = model("source", tables, params, &times);
        for (a, p, u, w) in [(1.0, 0.0, 1.2, 9.0), (0.3, 2.0, 0.1, 0.5), (2.0, -3.0, 3.0, 40.0)] {
            let got = predictions(m.as_ref(), &times, &[a, p, u, w]);
            assert!(last_was_exact(), "w = {w}");
            let particular = |t: f64| a * (u * (w * t + p).sin() - w * (w * t + p).cos()) / (u * u + w * w);
            for (t, y) in times.iter().zip(&got) {
                let want = (-u * t).exp() * (5.0 - particular(0.0)) + particular(*t);
                assert!((y - want).abs() < 1e-11 * 5.0, "a = {a}, w = {w}, t = {t}: {y} vs {want}");
            }
        }
    }

    /// A stiff decay toward a fast sinusoid, k up to 1e9 and w up to 1e6 on a
    /// grid of 0.25: exact at every point (the particular solution, the
    /// transient long gone), where an integrator would need millions of
    /// steps; and a growing mode that overflows is a failure, not a panic.
    #[test]
    fn stiff_and_fast_systems_are_exact_and_overflow_is_a_failure() {
        let times: Vec<f64> = (1..=20).map(|k| 0.25 * k as f64).collect();
        let tables = "[model.initial]\ny = \"1\"\n[model.rates]\ny = \"-k*y + k*sin(w*t)\"\n\
                      [model.observables]\ny = \"y\"";
        let params = "[parameters.k]\nmin = -1e4\nmax = 1e9\n[parameters.w]\nmin = 0.0\nmax = 1e6\n";
        let m = model("stiff", tables, params, &times);
        for (k, w) in [(1e9, 1e6), (1e7, 3.0), (1e6, 1e5)] {
            let got = predictions(m.as_ref(), &times, &[k, w]);
            assert!(last_was_exact());
            for (t, y) in times.iter().zip(&got) {
                // y' = −k y + k sin(wt): past the transient, y = k (k sin wt − w cos wt)/(k² + w²).
                let want = k * (k * (w * t).sin() - w * (w * t).cos()) / (k * k + w * w);
                // Scaling and squaring is accurate to about ε‖M dx‖ (Higham
                // 2005), and a phase of wt radians carries rounding of order
                // ε·wt: allow 16 times their sum (measured: 4e-9 at k = 1e9,
                // w = 1e6; 4e-11 at k = 1e7).
                let tolerance = 1e-12 + 16.0 * f64::EPSILON * (k * 0.25 + w * t);
                assert!((y - want).abs() < tolerance, "k = {k}, w = {w}, t = {t}: {y} vs {want}");
            }
        }
        let failures = m.failures();
        let got = predictions(m.as_ref(), &times, &[-1e4, 1.0]);
        assert!(got.iter().all(|y| y.is_nan()), "e^(1e4 t) overflows: {got:?}");
        assert_eq!(m.failures(), failures + 1);
    }

    /// The finite series for a nilpotent M against nalgebra's Padé method:
    /// the drag-free ball's step, a strictly triangular 4 × 4 and one
    /// permuted out of triangular form agree to rounding; matrices that are
    /// not nilpotent (a rotation, a decay) are refused.
    #[test]
    fn nilpotent_steps_take_the_finite_series() {
        use super::{exponential, nilpotent_exponential};
        use nalgebra::Const;
        let dx = 1.0 / 9.0;
        let ball = [0.0, -dx, 0.0, 0.0, 0.0, 9.8 * dx, 0.0, 0.0, 0.0];
        let upper4 = [0.0, 1.5, -2.0, 0.3, 0.0, 0.0, 4.0, -1.0, 0.0, 0.0, 0.0, 2.5, 0.0, 0.0, 0.0, 0.0];
        // upper4 with its first and last indices swapped: P U P, nilpotent but not triangular.
        let swap = |i: usize| [3, 1, 2, 0][i];
        let permuted: Vec<f64> = (0..16).map(|k| upper4[swap(k / 4) * 4 + swap(k % 4)]).collect();
        let cases: [(&[f64], usize); 3] = [(&ball, 3), (&upper4, 4), (&permuted, 4)];
        for (m, side) in cases {
            let (mut series, mut pade) = (vec![0.0; side * side], vec![0.0; side * side]);
            assert!(nilpotent_exponential(m, side, &mut series), "{m:?}");
            match side {
                3 => assert!(exponential::<Const<3>>(m, &mut pade)),
                _ => assert!(exponential::<Const<4>>(m, &mut pade)),
            }
            for (a, b) in series.iter().zip(&pade) {
                assert!((a - b).abs() <= 1e-14 * b.abs().max(1.0), "{m:?}: {series:?} vs {pade:?}");
            }
        }
        // The drag-free step exactly: h ← h − v dx − g dx²/2, v ← v + g dx.
        let mut p = [0.0; 9];
        assert!(nilpotent_exponential(&ball, 3, &mut p));
        assert_eq!(p, [1.0, -dx, -9.8 * dx * dx / 2.0, 0.0, 1.0, 9.8 * dx, 0.0, 0.0, 1.0]);
        let rotation = [0.0, 1.0, 0.0, -4.0 * dx, 0.0, 0.0, 0.0, 0.0, 0.0];
        let decay = [-0.4 * dx, 0.0, dx, 0.0];
        assert!(!nilpotent_exponential(&rotation, 3, &mut [0.0; 9]));
        assert!(!nilpotent_exponential(&decay, 2, &mut [0.0; 4]));
    }

    /// Rates that are not affine in the state, or read t other than through
    /// a sinusoid, are integrated.
    #[test]
    fn other_rates_are_integrated() {
        let times: Vec<f64> = (1..=10).map(|k| 0.5 * k as f64).collect();
        let params = "[parameters.a]\nmin = 0.1\nmax = 2.0\n";
        let cases = [
            ("cubic", "-a*y^3"),
            ("product", "-a*y*abs(y)"),
            ("transient", "-a*y + exp(-t)"),
            ("chirp", "-a*y + sin(a*t^2)"),
            ("modulated", "-a*y*sin(t)"),
        ];
        for (name, rate) in cases {
            let tables =
                format!("[model.initial]\ny = \"1\"\n[model.rates]\ny = \"{rate}\"\n[model.observables]\ny = \"y\"");
            let m = model(name, &tables, params, &times);
            let got = predictions(m.as_ref(), &times, &[0.5]);
            assert!(!last_was_exact(), "{rate}");
            assert!(got.iter().all(|y| y.is_finite()), "{rate}");
        }
    }
}
