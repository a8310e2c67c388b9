//! A formula that is a polynomial in some of its names (an ODE's states),
//! expanded into monomials whose coefficients are formulas of the other
//! names (parameters and constants): `c_3*(c_1 + x_2*(x_0 - c_2))` is
//! `c_3*c_1 + c_3·x_0·x_2 − c_3*c_2·x_2`.
//!
//! Why: an integrator evaluates an ODE's rates a dozen times per step at
//! one θ, and a compiled formula pays one call per operation (perf on
//! ODEBench's Tyson cell cycle: 64% of a likelihood evaluation in the rates'
//! closures). Expanded, the coefficients are computed once per integration
//! and each evaluation is a few multiplications per monomial.
//!
//! The arithmetic is reassociated, so values differ from the formula's in
//! the last bits; a power or product of sums that mixes a constant with the
//! variables is expanded only up to degree 2 (`(x − a)³` expanded loses
//! ε·(a/(x − a))³ of relative precision, (x − a)² only ε·(a/(x − a))²);
//! beyond that, and for anything that is not a polynomial (a function of a
//! variable, a division by one, a variable power), the formula is left as
//! written.

use super::notation::Expr;
use super::{Formula, Scope};
use std::collections::BTreeMap;

/// The most variables, total degree and monomials a formula is expanded to.
pub const MAX_VARIABLES: usize = 8;
pub const MAX_DEGREE: usize = 6;
const MAX_TERMS: usize = 32;

/// Exponents of the variables, in their order.
type Exponents = [u8; MAX_VARIABLES];

/// Monomials and their coefficients' formulas, while expanding.
type Expansion = BTreeMap<Exponents, Expr>;

/// A formula as Σ_k c_k(θ) Π_i x_i^{e_ki}.
#[derive(Clone, Debug)]
pub struct Polynomial {
    coefficients: Vec<Formula>,
    monomials: Vec<Monomial>,
    degree: usize,
}

/// A product of powers: its factors (variable, index of the exponent in
/// the powers' table, e − 1), in place so that evaluating reads no heap.
#[derive(Clone, Copy, Debug)]
struct Monomial {
    factors: [(u8, u8); MAX_DEGREE],
    len: u8,
}

impl Polynomial {
    /// `expr` expanded in `variables` (names, in order of the values given
    /// to `eval`), its coefficients compiled in `scope`; None when it is not
    /// a polynomial within the limits above or reads a name in `excluded`
    /// (t, which changes along an integration).
    pub fn expand(
        expr: &Expr,
        variables: &[String],
        excluded: &[&str],
        scope: &Scope,
        place: &str,
    ) -> Option<Polynomial> {
        if variables.len() > MAX_VARIABLES {
            return None;
        }
        let var = |n: &str| variables.iter().position(|v| v == n);
        let expansion = expand(expr, &var, excluded)?;
        let mut out = Polynomial { coefficients: Vec::new(), monomials: Vec::new(), degree: 0 };
        for (exponents, coefficient) in expansion {
            out.coefficients.push(Formula::from_expr(place, coefficient, scope, place).ok()?);
            let mut m = Monomial { factors: [(0, 0); MAX_DEGREE], len: 0 };
            for (i, e) in exponents.iter().enumerate().filter(|(_, e)| **e > 0) {
                // At most MAX_DEGREE factors: the total degree is at most that.
                m.factors[m.len as usize] = (i as u8, *e - 1);
                m.len += 1;
                out.degree = out.degree.max(*e as usize);
            }
            out.monomials.push(m);
        }
        Some(out)
    }

    /// Monomials (and coefficients).
    pub fn len(&self) -> usize {
        self.coefficients.len()
    }

    pub fn is_empty(&self) -> bool {
        self.coefficients.is_empty()
    }

    /// The highest power of any one variable.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// The coefficients at `values` (the scope's vector) into `out`.
    pub fn coefficients_at(&self, values: &[f64], out: &mut [f64]) {
        for (c, f) in out.iter_mut().zip(&self.coefficients) {
            *c = f.eval(values);
        }
    }

    /// The value with coefficients `c` (from `coefficients_at`) and
    /// `powers[i][e - 1]` = x_i^e for e up to `degree`.
    #[inline]
    pub fn eval(&self, c: &[f64], powers: &[[f64; MAX_DEGREE]]) -> f64 {
        let mut sum = 0.0;
        for (m, c) in self.monomials.iter().zip(c) {
            let mut term = *c;
            for &(i, e) in &m.factors[..m.len as usize] {
                term *= powers[i as usize][e as usize];
            }
            sum += term;
        }
        sum
    }
}

/// `powers[i][e - 1] = x[i]^e` for e in 1..=degree.
#[inline]
pub fn fill_powers(x: &[f64], degree: usize, powers: &mut [[f64; MAX_DEGREE]]) {
    for (p, &x) in powers.iter_mut().zip(x) {
        p[0] = x;
        for e in 1..degree.min(MAX_DEGREE) {
            p[e] = p[e - 1] * x;
        }
    }
}

fn expand(e: &Expr, var: &dyn Fn(&str) -> Option<usize>, excluded: &[&str]) -> Option<Expansion> {
    let constant = |c: Expr| Some(Expansion::from([([0; MAX_VARIABLES], c)]));
    match e {
        Expr::Number(_) => constant(e.clone()),
        Expr::Name(n) if excluded.contains(&n.as_str()) => None,
        Expr::Name(n) => match var(n) {
            Some(i) => {
                let mut exponents = [0; MAX_VARIABLES];
                exponents[i] = 1;
                Some(Expansion::from([(exponents, Expr::Number(1.0))]))
            }
            None => constant(e.clone()),
        },
        Expr::Neg(a) => Some(expand(a, var, excluded)?.into_iter().map(|(k, c)| (k, Expr::Neg(Box::new(c)))).collect()),
        Expr::Binary(op, a, b) => {
            let (pa, pb) = (expand(a, var, excluded)?, expand(b, var, excluded)?);
            match op {
                '+' | '-' => Some(sum(pa, pb, *op)),
                '*' => product(&pa, &pb),
                '/' => {
                    let d = constant_of(&pb)?;
                    Some(
                        pa.into_iter().map(|(k, c)| (k, Expr::Binary('/', Box::new(c), Box::new(d.clone())))).collect(),
                    )
                }
                '^' => power(&pa, &pb, e),
                _ => None,
            }
        }
        Expr::Call(_, args) => {
            let free = args.iter().all(|a| expand(a, var, excluded).is_some_and(|p| constant_of(&p).is_some()));
            if free {
                constant(e.clone())
            } else {
                None
            }
        }
    }
}

/// The coefficient of a polynomial with no variable in it.
fn constant_of(p: &Expansion) -> Option<Expr> {
    match p.len() {
        0 => Some(Expr::Number(0.0)),
        1 => p.get(&[0; MAX_VARIABLES]).cloned(),
        _ => None,
    }
}

fn sum(mut a: Expansion, b: Expansion, op: char) -> Expansion {
    for (k, c) in b {
        let merged = match a.remove(&k) {
            Some(old) => Expr::Binary(op, Box::new(old), Box::new(c)),
            None if op == '-' => Expr::Neg(Box::new(c)),
            None => c,
        };
        a.insert(k, merged);
    }
    a
}

fn degree_of(k: &Exponents) -> usize {
    k.iter().map(|e| *e as usize).sum()
}

/// Whether a polynomial holds a constant and a variable term (`x − a`).
fn mixed(p: &Expansion) -> bool {
    p.contains_key(&[0; MAX_VARIABLES]) && p.len() > 1
}

fn product(a: &Expansion, b: &Expansion) -> Option<Expansion> {
    let top = |p: &Expansion| p.keys().map(degree_of).max().unwrap_or(0);
    if mixed(a) && mixed(b) && top(a) + top(b) > 2 {
        return None; // cancellation beyond degree 2 (module notes)
    }
    let mut out = Expansion::new();
    for (ka, ca) in a {
        for (kb, cb) in b {
            let mut k = [0u8; MAX_VARIABLES];
            for i in 0..MAX_VARIABLES {
                k[i] = ka[i].checked_add(kb[i])?;
            }
            if degree_of(&k) > MAX_DEGREE {
                return None;
            }
            let c = Expr::Binary('*', Box::new(ca.clone()), Box::new(cb.clone()));
            out = sum(out, Expansion::from([(k, c)]), '+');
        }
    }
    (out.len() <= MAX_TERMS).then_some(out)
}

/// `a^b`: as written when neither holds a variable, repeated products for a
/// whole power of one that does.
fn power(a: &Expansion, b: &Expansion, whole: &Expr) -> Option<Expansion> {
    if let (Some(_), Some(_)) = (constant_of(a), constant_of(b)) {
        return Some(Expansion::from([([0; MAX_VARIABLES], whole.clone())]));
    }
    let Expr::Binary(_, _, exponent) = whole else { return None };
    let Expr::Number(k) = exponent.as_ref() else { return None };
    if k.fract() != 0.0 || !(1.0..=MAX_DEGREE as f64).contains(k) {
        return None;
    }
    let mut out = a.clone();
    for _ in 1..*k as usize {
        out = product(&out, a)?;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::formula::notation::parse;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn scope() -> Scope {
        Scope::new(["t", "a", "b", "c", "x", "y", "z"].map(String::from))
    }

    fn expanded(text: &str) -> Option<Polynomial> {
        let vars: Vec<String> = ["x", "y", "z"].map(String::from).to_vec();
        Polynomial::expand(&parse(text).unwrap(), &vars, &["t"], &scope(), "test")
    }

    /// At random values of every name, the expansion equals the formula
    /// to a few units in the last place of the terms' sizes.
    #[test]
    fn an_expanded_polynomial_equals_its_formula() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        for text in [
            "c*(a + z*(x - b))",
            "-x - a*x^3 + a*b*y - a*b*x",
            "a*x*y/(b + 1) - sin(c)*z^2 + 4",
            "(x - a)^2 + x*(y + b)*z",
            "-(y*z) + c^2*x - a^b",
            "x^6 - y",
            "(a + b*x)*(c - y)",
        ] {
            let p = expanded(text).unwrap_or_else(|| panic!("{text} is a polynomial"));
            let f = Formula::parse(text, &scope(), "test").unwrap();
            for _ in 0..200 {
                let v: Vec<f64> = (0..7).map(|_| rng.random_range(-3.0..3.0)).collect();
                let mut c = vec![0.0; p.len()];
                p.coefficients_at(&v, &mut c);
                let mut powers = [[0.0; MAX_DEGREE]; 3];
                fill_powers(&v[4..7], p.degree(), &mut powers);
                let (want, got) = (f.eval(&v), p.eval(&c, &powers));
                if want.is_nan() {
                    // a^b at a < 0: undefined both ways.
                    assert!(got.is_nan(), "{text}: NaN vs {got}");
                    continue;
                }
                assert!((want - got).abs() <= 1e-12 * (1.0 + want.abs()) * 3f64.powi(6), "{text}: {want} vs {got}");
            }
        }
    }

    #[test]
    fn what_is_not_a_polynomial_is_left_as_written() {
        for text in [
            "sin(x)",    // a function of a variable
            "a/x",       // division by one
            "x^a",       // a variable power
            "x*t",       // t changes along an integration
            "(x - a)^3", // cancellation beyond degree 2
            "(x - a)*(y - b)*(z + c)",
            "x*abs(y)",
        ] {
            assert!(expanded(text).is_none(), "{text}");
        }
        // The same sums are expanded where no constant mixes in, or to degree 2.
        assert!(expanded("(x + y)^3").is_some());
        assert!(expanded("(x - a)^2").is_some());
    }
}
