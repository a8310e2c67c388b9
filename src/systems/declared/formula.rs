//! Formulas a user writes in a config (`"h0 - v0*t - 0.5*g*t^2"`), parsed
//! once by exmex and evaluated against a fixed vector of named variables.
//!
//! exmex sorts a formula's variables by name; a [`Formula`] keeps, for each
//! of them, its index in the caller's [`Scope`], so evaluation gathers the
//! values into a stack buffer and never allocates (exmex itself evaluates on
//! the stack for formulas of up to 32 numbers and variables).

use anyhow::{bail, Result};
use exmex::prelude::*;

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

/// The most variables one formula may use (the stack buffer's size).
const MAX_VARIABLES: usize = 32;

/// A parsed formula bound to a scope.
#[derive(Clone, Debug)]
pub struct Formula {
    text: String,
    expr: FlatEx<f64>,
    /// For each of exmex's variables (sorted by name), its index in the scope.
    slots: Vec<usize>,
}

impl Formula {
    /// Parses `text`; `place` names where it was written (file, table and
    /// key), for errors.
    pub fn parse(text: &str, scope: &Scope, place: &str) -> Result<Formula> {
        if text.trim().is_empty() {
            bail!("{place} = {text:?}: the formula is empty");
        }
        let expr = match exmex::parse::<f64>(text) {
            Ok(e) => e,
            Err(e) => bail!("{place} = {text:?}: not a formula ({e})"),
        };
        let mut slots = Vec::new();
        for name in expr.var_names() {
            match scope.index(name) {
                Some(i) => slots.push(i),
                None => bail!("{place} = {text:?}: unknown name '{name}' (known here: {})", scope.names().join(", ")),
            }
        }
        if slots.len() > MAX_VARIABLES {
            bail!("{place} = {text:?}: uses {} names; at most {MAX_VARIABLES} are allowed in one formula", slots.len());
        }
        Ok(Formula { text: text.to_string(), expr, slots })
    }

    pub fn text(&self) -> &str {
        &self.text
    }

    /// Whether the formula uses the scope's variable `index`.
    pub fn uses(&self, index: usize) -> bool {
        self.slots.contains(&index)
    }

    /// The formula's value with the scope's variables at `values`; NaN where
    /// it is undefined.
    #[inline]
    pub fn eval(&self, values: &[f64]) -> f64 {
        let mut gathered = [0.0; MAX_VARIABLES];
        for (g, &s) in gathered.iter_mut().zip(&self.slots) {
            *g = values[s];
        }
        self.expr.eval(&gathered[..self.slots.len()]).unwrap_or(f64::NAN)
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
        assert!((Formula::parse(&plus("g", "-v0"), &scope(), "p").unwrap().eval(&[0.0, 9.8, 0.3, 0.0]) - 9.5).abs() < 1e-12);
    }

    #[test]
    fn errors_name_the_place_and_the_formula() {
        let e = Formula::parse("g*t + k", &scope(), "m.toml: [model.observables] height").unwrap_err().to_string();
        assert!(e.contains("m.toml: [model.observables] height") && e.contains("unknown name 'k'") && e.contains("g*t + k"), "{e}");
        let e = Formula::parse("g*(t", &scope(), "m.toml: [model.rates] v").unwrap_err().to_string();
        assert!(e.contains("[model.rates] v") && e.contains("not a formula"), "{e}");
        assert!(Formula::parse("  ", &scope(), "p").unwrap_err().to_string().contains("empty"));
    }

    #[test]
    fn undefined_values_are_nan_not_a_panic() {
        let f = Formula::parse("log(g) / v0", &scope(), "p").unwrap();
        assert!(!f.eval(&[0.0, -1.0, 0.0, 0.0]).is_finite());
    }
}
