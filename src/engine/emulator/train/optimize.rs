//! Maximizing a component GP's log marginal likelihood over its log
//! hyperparameters: argmin's L-BFGS with More–Thuente line search from
//! random and default starts, the negative log marginal likelihood with its
//! gradient (clamped to the bounds), and the fit with the noise fixed.

use super::*;

pub(super) fn log_bounds(d: usize) -> Vec<(f64, f64)> {
    let lb = |b: (f64, f64)| (b.0.ln(), b.1.ln());
    let mut v = vec![lb(SIGNAL_VAR_BOUNDS)];
    v.extend(std::iter::repeat_n(lb(LENGTH_BOUNDS), d));
    v.push(lb(CONSTANT_BOUNDS));
    v.push(lb(NOISE_BOUNDS));
    v
}

/// A negative log marginal likelihood and its gradient from one evaluation;
/// [`Lbfgs`] hands it to argmin.
pub(super) trait CostAndGradient {
    fn evaluate(&self, p: &[f64]) -> (f64, Vec<f64>);
}

/// Any [`CostAndGradient`] as an argmin problem.
pub(super) struct Lbfgs<P>(pub(super) P);

impl<P: CostAndGradient> CostFunction for Lbfgs<P> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, p: &Self::Param) -> Result<f64, argmin::core::Error> {
        Ok(self.0.evaluate(p).0)
    }
}

impl<P: CostAndGradient> Gradient for Lbfgs<P> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, p: &Self::Param) -> Result<Vec<f64>, argmin::core::Error> {
        Ok(self.0.evaluate(p).1)
    }
}

/// Negative log marginal likelihood, with a quadratic wall outside the
/// bounds so that L-BFGS (unconstrained) stays in the box.
pub(super) struct NegLogMarginal<'a> {
    pub(super) kernel: ArdKernel,
    pub(super) x: &'a [f64],
    pub(super) y: &'a [f64],
    pub(super) bounds: Vec<(f64, f64)>,
    /// argmin asks for cost and gradient at the same point; both come from one factorization.
    pub(super) cache: RefCell<Option<(Vec<f64>, f64, Vec<f64>)>>,
    pub(super) evaluations: &'a std::cell::Cell<u64>,
}

pub(super) const WALL: f64 = 1e3;

/// Stop when the log marginal likelihood changes by less than this between
/// iterations: scipy L-BFGS-B's default relative `ftol` (2.2e-9) at
/// |log L| ≈ 5000, and looser below. Tighter only burns line-search
/// evaluations on rounding noise.
pub(super) const COST_TOLERANCE: f64 = 1e-5;

/// How far (in log units) outside the bounds the likelihood is still evaluated.
pub(super) const CLAMP_MARGIN: f64 = 2.0;

impl CostAndGradient for NegLogMarginal<'_> {
    fn evaluate(&self, p: &[f64]) -> (f64, Vec<f64>) {
        if let Some((q, c, g)) = self.cache.borrow().as_ref() {
            if q.as_slice() == p {
                return (*c, g.clone());
            }
        }
        self.evaluations.set(self.evaluations.get() + 1);
        // Far outside the box exp() overflows, so the likelihood is taken at the
        // point clamped to a margin around it and the wall does the rest.
        let clamped: Vec<f64> =
            p.iter().zip(&self.bounds).map(|(&v, &(lo, hi))| v.clamp(lo - CLAMP_MARGIN, hi + CLAMP_MARGIN)).collect();
        let mut grad = vec![0.0; p.len()];
        let hyper = ArdHyper { log_params: clamped.clone() };
        let (cost, grad) = match ard_log_marginal_likelihood(self.kernel, &hyper, self.x, self.y, Some(&mut grad)) {
            Ok(lml) if lml.is_finite() => {
                let mut cost = -lml;
                let mut g: Vec<f64> = grad.iter().map(|v| -v).collect();
                for (k, &(lo, hi)) in self.bounds.iter().enumerate() {
                    if clamped[k] != p[k] {
                        g[k] = 0.0;
                    }
                    let excess = if p[k] < lo {
                        p[k] - lo
                    } else if p[k] > hi {
                        p[k] - hi
                    } else {
                        0.0
                    };
                    cost += WALL * excess * excess;
                    g[k] += 2.0 * WALL * excess;
                }
                (cost, g)
            }
            // Not factorizable even with jitter: a large finite cost makes the line search step back.
            _ => (1e300, vec![0.0; p.len()]),
        };
        *self.cache.borrow_mut() = Some((p.to_vec(), cost, grad.clone()));
        (cost, grad)
    }
}

/// Where one optimizer start ended.
pub(super) struct Optimum {
    pub(super) log_params: Vec<f64>,
    pub(super) log_marginal_likelihood: f64,
    pub(super) iterations: u64,
    pub(super) evaluations: u64,
    pub(super) outcome: String,
}

pub(super) fn optimize(kernel: ArdKernel, x: &[f64], y: &[f64], start: Vec<f64>, max_iters: u64) -> Result<Optimum> {
    let d = start.len() - 3;
    let evaluations = std::cell::Cell::new(0);
    let problem =
        NegLogMarginal { kernel, x, y, bounds: log_bounds(d), cache: RefCell::new(None), evaluations: &evaluations };
    minimize(problem, start, max_iters, &evaluations)
}

/// The same fit with the white-noise variance held at `exp(log_noise)`:
/// `start` is every other log-hyperparameter, and the optimum's parameters
/// come back with the fixed one appended.
pub(super) fn optimize_fixed_noise(
    kernel: ArdKernel,
    x: &[f64],
    y: &[f64],
    start: Vec<f64>,
    log_noise: f64,
    max_iters: u64,
) -> Result<Optimum> {
    let d = start.len() - 2;
    let evaluations = std::cell::Cell::new(0);
    let full =
        NegLogMarginal { kernel, x, y, bounds: log_bounds(d), cache: RefCell::new(None), evaluations: &evaluations };
    let mut optimum = minimize(FixedNoise { full, log_noise }, start, max_iters, &evaluations)?;
    optimum.log_params.push(log_noise);
    Ok(optimum)
}

/// The marginal likelihood over every log-hyperparameter but the noise's.
pub(super) struct FixedNoise<'a> {
    pub(super) full: NegLogMarginal<'a>,
    pub(super) log_noise: f64,
}

impl CostAndGradient for FixedNoise<'_> {
    fn evaluate(&self, p: &[f64]) -> (f64, Vec<f64>) {
        let mut q = p.to_vec();
        q.push(self.log_noise);
        let (cost, mut grad) = self.full.evaluate(&q);
        grad.pop();
        (cost, grad)
    }
}

/// L-BFGS on a negative log marginal likelihood from `start`.
pub(super) fn minimize<P: CostAndGradient>(
    problem: P,
    start: Vec<f64>,
    max_iters: u64,
    evaluations: &std::cell::Cell<u64>,
) -> Result<Optimum> {
    let solver =
        LBFGS::new(MoreThuenteLineSearch::new(), 10).with_tolerance_grad(1e-5)?.with_tolerance_cost(COST_TOLERANCE)?;
    let res =
        Executor::new(Lbfgs(problem), solver).configure(|s| s.param(start).max_iters(max_iters)).timer(false).run()?;
    let state = res.state();
    let best = state.get_best_param().cloned().ok_or_else(|| anyhow!("no parameters returned"))?;
    let outcome = match state.get_termination_reason() {
        Some(TerminationReason::MaxItersReached) => "max_iters".to_string(),
        // At the optimum, rounding makes the quasi-Newton direction fail the descent test.
        Some(TerminationReason::SolverExit(s)) if s.contains("descent direction") => {
            "converged (line search at optimum)".to_string()
        }
        Some(TerminationReason::SolverExit(s)) => format!("exit: {s}"),
        _ => "converged".to_string(),
    };
    Ok(Optimum {
        log_params: best,
        log_marginal_likelihood: -state.get_best_cost(),
        iterations: state.get_iter(),
        evaluations: evaluations.get(),
        outcome,
    })
}

pub(super) fn random_start(d: usize, rng: &mut impl Rng) -> Vec<f64> {
    let u = |rng: &mut dyn rand::RngCore, lo: f64, hi: f64| lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln());
    let mut v = vec![u(rng, 0.1, 10.0)];
    for _ in 0..d {
        v.push(u(rng, 0.05, 2.0));
    }
    v.push(u(rng, 1e-3, 1.0));
    v.push(u(rng, 1e-6, 1e-1));
    v
}

pub(super) fn default_start(d: usize) -> Vec<f64> {
    let (sf, l, c, n) = DEFAULT_START;
    let mut v = vec![sf.ln()];
    v.extend(std::iter::repeat_n(l.ln(), d));
    v.push(c.ln());
    v.push(n.ln());
    v
}
