//! Screening where the data are: the mismatch read off the data along
//! them (for an ODE, the rate each law must supply where the states are
//! observed; for an expression, the observable itself) and regressed on
//! every term of the library at once. A linear coefficient comes by least
//! squares, a nonlinear parameter (an exponent, a scale, a rate) by
//! variable projection over its grid, and θ moves with each term to first
//! order about its own fit along the data. A model that is unstable, or
//! far from the data when integrated, is no obstacle: nothing here is
//! integrated. The best few are then fitted in full along the data (θ, the
//! coefficient and the nonlinear parameters together) and handed on.

use super::library::{Symbol, Term, Unary};
use crate::engine::model::fit::{Fitted, LeastSquares};
use crate::engine::model::{ScreeningBlock, Simulator};
use rayon::prelude::*;
use std::ops::Range;

/// A place a term may join (a law, an observable) and its rows of the data.
pub struct Place {
    pub name: String,
    pub rows: Range<usize>,
    /// The symbols terms are built from, with their values at `rows`.
    pub symbols: Vec<Symbol>,
}

/// The data along the places: what each row's place must supply, with its
/// 1σ error.
pub struct Along {
    pub target: Vec<f64>,
    pub sd: Vec<f64>,
    pub places: Vec<Place>,
}

/// The model along the rows at θ (NaN where it cannot be computed).
pub trait AlongModel: Send + Sync {
    fn predict(&self, theta: &[f64], out: &mut [f64]);
}

/// A term that explains part of the mismatch along the data.
#[derive(Clone, Debug)]
pub struct Found {
    pub place: usize,
    pub term: Term,
    /// Its fit along the data: θ, the coefficient, the nonlinear parameters.
    pub theta: Vec<f64>,
    pub coefficient: f64,
    pub nonlinear: Vec<f64>,
    /// χ² along the data without the term minus with it.
    pub delta_chi2: f64,
    /// The term's largest |value| over its rows without its coefficient, at `nonlinear`.
    pub unit_size: f64,
    /// The largest |mismatch| over its place's rows at θ's own fit, the term left out.
    pub mismatch: f64,
}

/// How many terms are fitted in full along the data, per term handed on.
const REFINED_PER_KEPT: usize = 3;

/// The model fitted along the data by least squares from the best of
/// `starts`, every parameter within `bounds`: a model with a term of its
/// own (a parameter that varies, a drive in t) screened where the data are.
pub fn fit(along: &Along, model: &dyn AlongModel, starts: &[Vec<f64>], bounds: &[(f64, f64)]) -> Option<Fitted> {
    let rows: Vec<f64> = (0..along.target.len()).map(|i| i as f64).collect();
    let block =
        [ScreeningBlock { model_index: 0, x: &rows, y: &along.target, error: &along.sd, covariance_factor: None }];
    let plain = AsSimulator { model, n_theta: bounds.len(), term: None, rows: along.target.len() };
    LeastSquares { blocks: &block, model: &plain, bounds: bounds.to_vec() }.best_of(starts)
}

/// The terms of `library(place)` that most lower χ² along the data, best
/// first, at most `keep` of them, each worth its parameters by BIC; with
/// the model's own fit along the data. None when the model cannot be
/// fitted along the data at all.
pub fn screen(
    along: &Along,
    model: &dyn AlongModel,
    library: &(dyn Fn(&Place) -> Vec<Term> + Sync),
    theta: &[f64],
    bounds: &[(f64, f64)],
    keep: usize,
) -> Option<(Fitted, Vec<Found>)> {
    let rows: Vec<f64> = (0..along.target.len()).map(|i| i as f64).collect();
    let block =
        [ScreeningBlock { model_index: 0, x: &rows, y: &along.target, error: &along.sd, covariance_factor: None }];
    let base = AsSimulator { model, n_theta: theta.len(), term: None, rows: along.target.len() };
    let fit = LeastSquares { blocks: &block, model: &base, bounds: bounds.to_vec() };
    let base_fit = fit.fit(theta)?;
    let linear = Linearized::at(&fit, &base_fit)?;
    let n = along.target.len() as f64;
    let mut candidates: Vec<(usize, Term, Vec<f64>, f64)> = along
        .places
        .par_iter()
        .enumerate()
        .flat_map(|(k, place)| {
            let linear = &linear;
            library(place).into_par_iter().filter_map(move |term| {
                let (nonlinear, gain) = linear.best_on_grid(along, place, &term)?;
                let bic = gain - (1 + term.nonlinear.len()) as f64 * n.ln();
                (bic > 0.0).then_some((k, term, nonlinear, gain))
            })
        })
        .collect();
    // ΔBIC/2 less the term's prior cost: about a log posterior odds, so that
    // of forms the data cannot tell apart the simpler leads.
    let score = |c: &(usize, Term, Vec<f64>, f64)| 0.5 * (c.3 - (1 + c.1.nonlinear.len()) as f64 * n.ln()) - c.1.nats;
    candidates.sort_by(|a, b| score(b).total_cmp(&score(a)));
    candidates.truncate(keep * REFINED_PER_KEPT);
    let mut found: Vec<Found> = candidates
        .into_par_iter()
        .filter_map(|(k, term, nonlinear, _)| refine(along, model, &base_fit, bounds, k, term, nonlinear))
        .collect();
    found.sort_by(|a, b| {
        let s = |f: &Found| 0.5 * (f.delta_chi2 - (1 + f.term.nonlinear.len()) as f64 * n.ln()) - f.term.nats;
        s(b).total_cmp(&s(a))
    });
    found.retain(|f| f.delta_chi2 - (1 + f.term.nonlinear.len()) as f64 * n.ln() > 0.0);
    found.truncate(keep);
    let whole: Vec<Found> = whole_powers(&found, along, library)
        .into_par_iter()
        .filter_map(|(k, term)| refine(along, model, &base_fit, bounds, k, term, Vec::new()))
        .filter(|f| f.delta_chi2 - n.ln() > 0.0)
        .collect();
    found.extend(whole);
    Some((base_fit, found))
}

/// The whole powers a free power holds (|s|^p at p = 1, 2, 3: s, s², s|s|,
/// s³), for each free power kept whose special cases were not kept with
/// it. The rate read off smoothed states carries the smoothing's bias,
/// and along the data a flexible form can lead the law it holds by more
/// than the free exponent's price: on one fall of a ball, |v/S|^p led the
/// drag v² by 18 in χ² along the data while through the model the two fit
/// alike. Handed on beside the free power, the whole power is fitted
/// through the model, where Occam's rule can prefer it.
fn whole_powers(found: &[Found], along: &Along, library: &(dyn Fn(&Place) -> Vec<Term> + Sync)) -> Vec<(usize, Term)> {
    const WHOLE: [Unary; 4] = [Unary::Id, Unary::Square, Unary::SignedSquare, Unary::Cube];
    let name = |k: usize, t: &Term| t.name(&along.places[k].symbols);
    let mut out: Vec<(usize, Term)> = Vec::new();
    for f in found {
        let [free] = f.term.factors.as_slice() else { continue };
        if free.unary != Unary::Power {
            continue;
        }
        let held = library(&along.places[f.place])
            .into_iter()
            .filter(|t| matches!(t.factors.as_slice(), [w] if w.symbol == free.symbol && WHOLE.contains(&w.unary)));
        for t in held {
            let known = found.iter().any(|g| g.place == f.place && name(g.place, &g.term) == name(f.place, &t))
                || out.iter().any(|(k, u)| *k == f.place && name(*k, u) == name(f.place, &t));
            if !known {
                out.push((f.place, t));
            }
        }
    }
    out
}

/// The base fit along the data, linearized in θ: the standardized
/// residual r, the standardized Jacobian J and the factor of JᵀJ, so that
/// a term's column g lowers χ² by (gᵀPr)²/(gᵀPg), P = I − J(JᵀJ)⁻¹Jᵀ.
struct Linearized {
    residual: Vec<f64>,
    /// Columns of J, each standardized.
    jacobian: Vec<Vec<f64>>,
    /// (JᵀJ)⁻¹, row-major; empty without θ.
    inverse: Vec<f64>,
}

impl Linearized {
    fn at(fit: &LeastSquares, base: &Fitted) -> Option<Linearized> {
        let b = &fit.blocks[0];
        let residual: Vec<f64> = (0..b.y.len()).map(|i| (b.y[i] - base.prediction[i]) / b.error[i]).collect();
        let mut jacobian: Vec<Vec<f64>> = Vec::new();
        for (k, (lo, hi)) in fit.bounds.iter().enumerate() {
            // A θ held at its prior's edge cannot move with a term: a term
            // that does what it would do beyond the edge is new physics.
            let edge = 1e-6 * (hi - lo);
            if base.phi[k] - lo <= edge || hi - base.phi[k] <= edge {
                continue;
            }
            let mut h = 1e-6 * (hi - lo).max(1e-12);
            if base.phi[k] + h > *hi {
                h = -h;
            }
            let mut moved = base.phi.clone();
            moved[k] += h;
            let p = fit.predict(&moved)?;
            let column: Vec<f64> = (0..p.len()).map(|i| (p[i] - base.prediction[i]) / (h * b.error[i])).collect();
            // A θ the laws do not read (an initial value) moves nothing here.
            if column.iter().any(|v| *v != 0.0) {
                jacobian.push(column);
            }
        }
        let k = jacobian.len();
        let mut jtj = vec![0.0; k * k];
        for i in 0..k {
            for j in 0..k {
                jtj[i * k + j] = dot(&jacobian[i], &jacobian[j]);
            }
            // A θ the rates do not see (or barely) must not make JᵀJ singular.
            jtj[i * k + i] += 1e-9 * jtj[i * k + i].max(1e-300);
        }
        let inverse = invert(jtj, k)?;
        Some(Linearized { residual, jacobian, inverse })
    }

    /// χ² gained by the standardized column g with θ free to first order;
    /// 0 when g lies in θ's span (the model has the term already).
    fn gain(&self, g: &[f64]) -> f64 {
        let k = self.jacobian.len();
        let jg: Vec<f64> = self.jacobian.iter().map(|j| dot(j, g)).collect();
        let jr: Vec<f64> = self.jacobian.iter().map(|j| dot(j, &self.residual)).collect();
        let mut gpg = dot(g, g);
        let mut gpr = dot(g, &self.residual);
        for a in 0..k {
            for b in 0..k {
                gpg -= jg[a] * self.inverse[a * k + b] * jg[b];
                gpr -= jg[a] * self.inverse[a * k + b] * jr[b];
            }
        }
        if !(gpg > 1e-10 * dot(g, g)) || !gpr.is_finite() {
            return 0.0;
        }
        gpr * gpr / gpg
    }

    /// The term's best grid point on `place` and the χ² it gains there.
    fn best_on_grid(&self, along: &Along, place: &Place, term: &Term) -> Option<(Vec<f64>, f64)> {
        let rows = place.rows.clone();
        let mut column = vec![0.0; rows.len()];
        let mut g = vec![0.0; along.target.len()];
        let mut best: Option<(Vec<f64>, f64)> = None;
        for p in term.grid() {
            term.column(&place.symbols, &p, &mut column);
            if column.iter().any(|v| !v.is_finite()) {
                continue;
            }
            for (i, row) in rows.clone().enumerate() {
                g[row] = column[i] / along.sd[row];
            }
            let gain = self.gain(&g);
            if best.as_ref().is_none_or(|(_, b)| gain > *b) {
                best = Some((p, gain));
            }
        }
        best.filter(|(_, gain)| *gain > 0.0)
    }
}

/// The term fitted in full along the data from its grid point, θ from the base fit.
fn refine(
    along: &Along,
    model: &dyn AlongModel,
    base: &Fitted,
    bounds: &[(f64, f64)],
    k: usize,
    term: Term,
    nonlinear: Vec<f64>,
) -> Option<Found> {
    let place = &along.places[k];
    let rows: Vec<f64> = (0..along.target.len()).map(|i| i as f64).collect();
    let block =
        [ScreeningBlock { model_index: 0, x: &rows, y: &along.target, error: &along.sd, covariance_factor: None }];
    let n_theta = base.phi.len();
    let with = AsSimulator { model, n_theta, term: Some((&term, place)), rows: along.target.len() };
    let mut box_ = bounds.to_vec();
    box_.push((f64::NEG_INFINITY, f64::INFINITY));
    box_.extend(term.nonlinear.iter().map(|p| (p.min, p.max)));
    let coefficient = first_coefficient(along, place, &term, &nonlinear, &base.prediction);
    let start: Vec<f64> = base.phi.iter().copied().chain([coefficient]).chain(nonlinear.iter().copied()).collect();
    // The coefficient has no box: its Jacobian step is a fixed fraction of its start's size.
    let scale = coefficient.abs().max(1e-12);
    box_[n_theta] = (-1e3 * scale, 1e3 * scale);
    let fit = LeastSquares { blocks: &block, model: &with, bounds: box_ }.fit(&start)?;
    let nonlinear = fit.phi[n_theta + 1..].to_vec();
    let mut column = vec![0.0; place.rows.len()];
    term.column(&place.symbols, &nonlinear, &mut column);
    let unit_size = column.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mismatch = place.rows.clone().map(|i| (along.target[i] - base.prediction[i]).abs()).fold(0.0, f64::max);
    Some(Found {
        place: k,
        theta: fit.phi[..n_theta].to_vec(),
        coefficient: fit.phi[n_theta],
        nonlinear,
        delta_chi2: base.chi2 - fit.chi2,
        unit_size,
        mismatch,
        term,
    })
}

/// The coefficient that best fits the mismatch at the base fit alone.
fn first_coefficient(along: &Along, place: &Place, term: &Term, nonlinear: &[f64], base: &[f64]) -> f64 {
    let mut column = vec![0.0; place.rows.len()];
    term.column(&place.symbols, nonlinear, &mut column);
    let (mut num, mut den) = (0.0, 0.0);
    for (i, row) in place.rows.clone().enumerate() {
        let w = 1.0 / (along.sd[row] * along.sd[row]);
        num += w * column[i] * (along.target[row] - base[row]);
        den += w * column[i] * column[i];
    }
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

/// The model along the rows as a `Simulator` of one observable over row
/// indices, with a term added on its place's rows: φ = (θ, c, nonlinear).
struct AsSimulator<'a> {
    model: &'a dyn AlongModel,
    n_theta: usize,
    term: Option<(&'a Term, &'a Place)>,
    rows: usize,
}

impl Simulator for AsSimulator<'_> {
    fn parameter_names(&self) -> Vec<String> {
        Vec::new()
    }

    fn observable_names(&self) -> Vec<String> {
        vec!["along".into()]
    }

    fn predict(&self, _observable: usize, _x: &[f64], phi: &[f64], out: &mut [f64]) {
        debug_assert_eq!(out.len(), self.rows);
        self.model.predict(&phi[..self.n_theta], out);
        if let Some((term, place)) = self.term {
            let c = phi[self.n_theta];
            let mut column = vec![0.0; place.rows.len()];
            term.column(&place.symbols, &phi[self.n_theta + 1..], &mut column);
            for (i, row) in place.rows.clone().enumerate() {
                out[row] += c * column[i];
            }
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The inverse of a small symmetric positive matrix (row-major), by
/// Gauss–Jordan with partial pivoting; None when singular.
fn invert(mut a: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    let mut inv: Vec<f64> = (0..n * n).map(|i| if i % (n + 1) == 0 { 1.0 } else { 0.0 }).collect();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if !(a[pivot * n + col].abs() > 1e-300) {
            return None;
        }
        for j in 0..n {
            a.swap(col * n + j, pivot * n + j);
            inv.swap(col * n + j, pivot * n + j);
        }
        let d = a[col * n + col];
        for j in 0..n {
            a[col * n + j] /= d;
            inv[col * n + j] /= d;
        }
        for row in 0..n {
            if row != col {
                let f = a[row * n + col];
                for j in 0..n {
                    a[row * n + j] -= f * a[col * n + j];
                    inv[row * n + j] -= f * inv[col * n + j];
                }
            }
        }
    }
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::discover::library::{self, Unary};

    /// dy/dt = −k y − b y² along a known trajectory, the model −k y: the
    /// screening names the square of y and recovers b and k.
    struct Decay {
        y: Vec<f64>,
    }
    impl AlongModel for Decay {
        fn predict(&self, theta: &[f64], out: &mut [f64]) {
            for (o, y) in out.iter_mut().zip(&self.y) {
                *o = -theta[0] * y;
            }
        }
    }

    #[test]
    fn a_missing_square_is_found_with_its_coefficient_and_theta_moves_with_it() {
        let (k, b) = (0.7, 0.3);
        let y: Vec<f64> = (0..30).map(|i| 3.0 * (-0.1 * i as f64).exp()).collect();
        let target: Vec<f64> = y.iter().map(|y| -k * y - b * y * y).collect();
        let sd = vec![0.01; y.len()];
        let symbol = Symbol::of("y", &y, false).unwrap();
        let along =
            Along { target, sd, places: vec![Place { name: "dy/dt".into(), rows: 0..30, symbols: vec![symbol] }] };
        let model = Decay { y };
        let (_, found) = screen(&along, &model, &|p| library::terms(&p.symbols), &[1.0], &[(0.0, 5.0)], 3).unwrap();
        let best = &found[0];
        assert_eq!(
            best.term.factors[0].unary,
            Unary::Square,
            "{:?}",
            found.iter().map(|f| &f.term).collect::<Vec<_>>()
        );
        assert!((best.coefficient + b).abs() < 1e-4 && (best.theta[0] - k).abs() < 1e-4, "{best:?}");
    }

    #[test]
    fn the_inverse_of_a_small_matrix_is_exact() {
        let a = vec![4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let inv = invert(a.clone(), 3).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let v: f64 = (0..3).map(|k| a[i * 3 + k] * inv[k * 3 + j]).sum();
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(invert(vec![1.0, 2.0, 2.0, 4.0], 2).is_none());
    }
}
