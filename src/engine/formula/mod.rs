//! Formulas a user writes in a config (`"h0 - v0*t - 0.5*g*t^2"`), parsed
//! once by the mathematical conventions (`notation`: `-w^2*x` is −(w²)·x)
//! and compiled (`tape`) to evaluate against the caller's vector of named
//! values in place, without allocation.

mod closures;
pub mod notation;
mod ops;
pub mod polynomial;
pub mod tape;
pub mod terms;

use anyhow::{bail, Result};
use tape::Tape;

/// The names a formula may use, in the order of the value vectors passed to
/// [`Formula::eval`].
#[derive(Clone, Debug, Default)]
pub struct Scope {
    names: Vec<String>,
}

impl Scope {
    pub fn new(names: impl IntoIterator<Item = String>) -> Scope {
        Scope { names: names.into_iter().collect() }
    }

    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }
}

/// A parsed formula bound to a scope.
#[derive(Clone, Debug)]
pub struct Formula {
    text: String,
    tape: Tape,
    /// The scope's indices of the variables the formula uses.
    slots: Vec<usize>,
    expr: notation::Expr,
}

impl Formula {
    /// Parses `text`; `place` names where it was written (file, table and
    /// key), for errors.
    pub fn parse(text: &str, scope: &Scope, place: &str) -> Result<Formula> {
        if text.trim().is_empty() {
            bail!("{place} = {text:?}: the formula is empty");
        }
        let expr = match notation::parse(text) {
            Ok(e) => e,
            Err(e) => bail!("{place} = {text:?}: not a formula ({e})"),
        };
        Formula::from_expr(text, expr, scope, place)
    }

    /// A formula from its parsed tree (`text` is what errors quote).
    pub fn from_expr(text: &str, expr: notation::Expr, scope: &Scope, place: &str) -> Result<Formula> {
        let mut names = Vec::new();
        expr.names(&mut names);
        if let Some(unknown) = names.iter().find(|n| scope.index(n).is_none() && Tape::constant(n).is_none()) {
            bail!("{place} = {text:?}: unknown name '{unknown}' (known here: {})", scope.names().join(", "));
        }
        let tape = match Tape::compile(&expr, &|n| scope.index(n)) {
            Ok(t) => t,
            Err(e) => bail!("{place} = {text:?}: not a formula ({e})"),
        };
        let slots = names.iter().filter(|n| Tape::constant(n).is_none()).filter_map(|n| scope.index(n)).collect();
        Ok(Formula { text: text.to_string(), tape, slots, expr })
    }

    pub fn text(&self) -> &str {
        &self.text
    }

    /// The parsed tree.
    pub fn expr(&self) -> &notation::Expr {
        &self.expr
    }

    /// The formula's degree as a polynomial in the names `of` picks out;
    /// None when it is not one (`notation::Expr::degree`).
    pub fn degree(&self, of: &dyn Fn(&str) -> bool) -> Option<u32> {
        self.expr.degree(of)
    }

    /// Whether the formula uses the scope's variable `index`.
    pub fn uses(&self, index: usize) -> bool {
        self.slots.contains(&index)
    }

    /// The formula's value with the scope's variables at `values`; NaN where
    /// it is undefined.
    #[inline]
    pub fn eval(&self, values: &[f64]) -> f64 {
        self.tape.eval(values)
    }
}

/// `base` with `term` added, as one formula's text: a candidate's correction.
pub fn plus(base: &str, term: &str) -> String {
    format!("({base}) + ({term})")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scope() -> Scope {
        Scope::new(["t", "g", "v0", "h0"].map(String::from))
    }

    #[test]
    fn evaluates_with_variables_in_any_order() {
        let f = Formula::parse("h0 - v0*t - 0.5*g*t^2", &scope(), "m.toml: [model.observables] height").unwrap();
        let (t, g, v0, h0) = (0.7, 9.8, 0.3, 60.0);
        let want = h0 - v0 * t - 0.5 * g * t * t;
        assert!((f.eval(&[t, g, v0, h0]) - want).abs() < 1e-12);
        assert!(f.uses(0) && !Formula::parse("g", &scope(), "p").unwrap().uses(0));
        let f = Formula::parse("-g*abs(t)*sqrt(h0) + max(v0, 1)", &scope(), "p").unwrap();
        assert!((f.eval(&[-2.0, 9.8, 0.3, 4.0]) - (-9.8 * 2.0 * 2.0 + 1.0)).abs() < 1e-12);
        assert!(
            (Formula::parse(&plus("g", "-v0"), &scope(), "p").unwrap().eval(&[0.0, 9.8, 0.3, 0.0]) - 9.5).abs() < 1e-12
        );
    }

    #[test]
    fn errors_name_the_place_and_the_formula() {
        let e = Formula::parse("g*t + k", &scope(), "m.toml: [model.observables] height").unwrap_err().to_string();
        assert!(
            e.contains("m.toml: [model.observables] height") && e.contains("unknown name 'k'") && e.contains("g*t + k"),
            "{e}"
        );
        let e = Formula::parse("g*(t", &scope(), "m.toml: [model.rates] v").unwrap_err().to_string();
        assert!(e.contains("[model.rates] v") && e.contains("not a formula"), "{e}");
        assert!(Formula::parse("  ", &scope(), "p").unwrap_err().to_string().contains("empty"));
    }

    /// Each formula against the meaning a physicist gives it, written in Rust.
    #[test]
    fn formulas_mean_what_mathematics_says() {
        let (t, g, v0, h0) = (1.5, 2.0, -0.7, 3.0);
        let at = [t, g, v0, h0];
        let table: [(&str, f64); 12] = [
            ("-g^2*t", -(g * g) * t),
            ("-g^2", -(g * g)),
            ("g^t^h0", g.powf(t.powf(h0))),
            ("g^-t", g.powf(-t)),
            ("-g^-t^2", -(g.powf(-(t * t)))),
            ("2 - g^2", 2.0 - g * g),
            ("t*-g", t * -g),
            ("h0/g*t", h0 / g * t),
            ("h0/g/t", h0 / g / t),
            ("h0 - g - t", h0 - g - t),
            ("max(v0, -g^2) + min(t, 1)", v0.max(-(g * g)) + t.min(1.0)),
            ("-exp(-t^2/2)", -(-(t * t) / 2.0).exp()),
        ];
        for (text, want) in table {
            let got = Formula::parse(text, &scope(), "p").unwrap().eval(&at);
            assert!((got - want).abs() < 1e-12 * want.abs().max(1.0), "{text}: {got} against {want}");
        }
        let e = Formula::parse("2g*t", &scope(), "p").unwrap_err().to_string();
        assert!(e.contains("write the multiplication out"), "{e}");
    }

    /// The compiled tape against exmex, an independent evaluator, given the
    /// same grouping (exmex's own precedence differs: see `notation`).
    #[test]
    fn the_tape_agrees_with_exmex() {
        use exmex::prelude::*;
        let scope = scope();
        let at = [0.37, 9.81, -1.3, 62.0];
        for text in [
            "h0 - v0*t - 0.5*g*t^2",
            "-g*v0*abs(v0) + h0^-1.5 - t^3 + t^-2 + 2^t^2",
            "(1 - exp(-1/(2*0.25))) * (1000*g*t^3 + 1900*t^2 + 2092*t + 60) / (100*v0*t^3 + 500*t^2 + 4*t + 20)",
            "g*(10*t^2 + 4*0.25^2)/(50*t*0.25 + 10)",
            "v0*g - v0*g/(1 + h0*g) + sin(PI*t) - cos(2*π*t/TAU) + e^t",
            "atan2(v0, t) + min(g, h0) * max(-t, t) + tanh(v0) + log(g) + sqrt(h0) + signum(v0)",
            "-t^0.5 + cbrt(g) - log10(h0) * ln(g) / log2(h0)",
        ] {
            let expr = notation::parse(text).unwrap();
            let flat = exmex::parse::<f64>(&expr.explicit()).unwrap();
            let vals: Vec<f64> = flat
                .var_names()
                .iter()
                .map(|n| at[scope.index(n).unwrap_or_else(|| panic!("{text}: exmex sees a variable {n}"))])
                .collect();
            let want = flat.eval(&vals).unwrap();
            let got = Formula::parse(text, &scope, "p").unwrap().eval(&at);
            assert!((got - want).abs() <= 1e-13 * want.abs().max(1.0), "{text}: tape {got}, exmex {want}");
        }
    }

    #[test]
    fn unknown_functions_and_wrong_arities_are_named() {
        let e = Formula::parse("foo(t)", &scope(), "p").unwrap_err().to_string();
        assert!(e.contains("unknown function 'foo'"), "{e}");
        let e = Formula::parse("max(t)", &scope(), "p").unwrap_err().to_string();
        assert!(e.contains("max takes two arguments"), "{e}");
    }

    #[test]
    fn undefined_values_are_nan_not_a_panic() {
        let f = Formula::parse("log(g) / v0", &scope(), "p").unwrap();
        assert!(!f.eval(&[0.0, -1.0, 0.0, 0.0]).is_finite());
    }
}
