//! The prior over forms the search charges each discovered term: a form's
//! prior weight is exp(−Σ α_o n_o) over the kinds of operation o it uses
//! n_o times, with the costs α_o learned from a corpus of physics
//! equations, as in the Bayesian machine scientist (Guimerà et al. 2020,
//! Science Advances 6, eaav6971), whose prior was learned from published
//! equations. The corpus here is the 120 formulas of the Feynman
//! symbolic-regression database (`bench/prior/`), never the benchmark the
//! search is measured on; `operations.toml` holds the costs it gave.

use crate::engine::formula::notation::{self, Expr};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::OnceLock;

const LEARNED: &str = include_str!("operations.toml");

#[derive(serde::Deserialize)]
struct Learned {
    nats: BTreeMap<String, f64>,
}

/// The learned cost of each kind of operation, in nats.
fn costs() -> &'static BTreeMap<String, f64> {
    static COSTS: OnceLock<BTreeMap<String, f64>> = OnceLock::new();
    COSTS.get_or_init(|| {
        let learned: Learned =
            toml::from_str(LEARNED).expect("the bundled operations.toml parses (a unit test checks)");
        learned.nats
    })
}

/// The cost of a kind the corpus does not name (a function it never
/// uses): the dearest kind it does.
fn rare() -> f64 {
    costs().values().copied().fold(0.0, f64::max)
}

fn cost(kind: &str) -> f64 {
    costs().get(kind).copied().unwrap_or_else(rare)
}

/// A formula's prior cost in nats: each operation at its learned cost.
/// Signs, `abs` and `signum` are free: conventions of sign (v*abs(v) is a
/// square that keeps v's sign), which the corpus, written for positive
/// quantities, never needs. A formula that does not parse costs as the
/// rarest operation, once.
pub fn nats(formula: &str) -> f64 {
    notation::parse(formula).map_or_else(|_| rare(), |e| expr_nats(&e))
}

fn expr_nats(e: &Expr) -> f64 {
    match e {
        Expr::Number(_) | Expr::Name(_) => 0.0,
        Expr::Neg(a) => expr_nats(a),
        Expr::Binary('^', a, b) => {
            let power = match b.as_ref() {
                Expr::Number(k) if *k == 2.0 => cost("pow2"),
                Expr::Number(k) if *k == 3.0 => cost("pow3"),
                Expr::Number(k) if *k == 0.5 => cost("sqrt"),
                Expr::Number(k) if *k == -1.0 => cost("/"),
                Expr::Number(k) if *k == -2.0 => cost("/") + cost("pow2"),
                Expr::Neg(k) if matches!(k.as_ref(), Expr::Number(v) if *v == 1.0) => cost("/"),
                _ => cost("pow") + expr_nats(b),
            };
            power + expr_nats(a)
        }
        Expr::Binary(op, a, b) => {
            let kind = match op {
                '+' | '-' => "+",
                '/' => "/",
                _ => "*",
            };
            // A product with ±1 is a sign, not an operation.
            let sign = *op == '*' && [a, b].iter().any(|x| matches!(x.as_ref(), Expr::Number(v) if v.abs() == 1.0));
            (if sign { 0.0 } else { cost(kind) }) + expr_nats(a) + expr_nats(b)
        }
        Expr::Call(f, args) => {
            let own = match f.as_str() {
                "abs" | "signum" => 0.0,
                "ln" => cost("log"),
                name => cost(name),
            };
            own + args.iter().map(expr_nats).sum::<f64>()
        }
    }
}

/// The kind the corpus counts for a symbol used outside a sine, cosine or
/// tangent in an equation that uses it inside one: an angle (or a phase)
/// written bare. Its cost says how rarely physics does that.
const BARE_ANGLE: &str = "angle outside a trig function";

/// The cost of `formula` where the model it joins uses `angles` inside a
/// sine, cosine or tangent: `nats(formula)`, plus the learned cost of each
/// use, outside such a function, of a name the model or the formula itself
/// uses inside one. A law periodic in an angle stays periodic: the corpus
/// writes an angle bare 4 times in its 39 angles and phases.
pub fn nats_given(formula: &str, angles: &BTreeSet<String>) -> f64 {
    let Ok(e) = notation::parse(formula) else { return rare() };
    let mut all = angles.clone();
    inside_trig(&e, false, &mut all);
    expr_nats(&e) + bare_angle_nats(&e, &all)
}

/// The learned cost of the uses of `angles` in `e` outside a sine, cosine
/// or tangent.
pub fn bare_angle_nats(e: &Expr, angles: &BTreeSet<String>) -> f64 {
    bare_uses(e, angles) as f64 * cost(BARE_ANGLE)
}

/// Adds to `out` every name `e` uses inside a sine, cosine or tangent
/// (`within`: `e` is itself inside one).
pub fn inside_trig(e: &Expr, within: bool, out: &mut BTreeSet<String>) {
    match e {
        Expr::Number(_) => {}
        Expr::Name(n) => {
            if within {
                out.insert(n.clone());
            }
        }
        Expr::Neg(a) => inside_trig(a, within, out),
        Expr::Binary(_, a, b) => {
            inside_trig(a, within, out);
            inside_trig(b, within, out);
        }
        Expr::Call(f, args) => {
            let trig = within || is_trig(f);
            args.iter().for_each(|a| inside_trig(a, trig, out));
        }
    }
}

fn is_trig(f: &str) -> bool {
    matches!(f, "sin" | "cos" | "tan")
}

fn bare_uses(e: &Expr, angles: &BTreeSet<String>) -> usize {
    match e {
        Expr::Number(_) => 0,
        Expr::Name(n) => usize::from(angles.contains(n)),
        Expr::Neg(a) => bare_uses(a, angles),
        Expr::Binary(_, a, b) => bare_uses(a, angles) + bare_uses(b, angles),
        Expr::Call(f, _) if is_trig(f) => 0,
        Expr::Call(_, args) => args.iter().map(|a| bare_uses(a, angles)).sum(),
    }
}

/// The prior over forms. Weights are normalized over every term searched,
/// so the search as a whole still pays its look-elsewhere odds (the
/// singles' odds sum to one against the model as it is, as under the
/// uniform 1 : N), and where the data cannot tell two forms apart the
/// simpler leads.
pub struct FormPrior {
    total: f64,
    squares: f64,
}

impl FormPrior {
    fn weight(nats: f64) -> f64 {
        (-nats).exp()
    }

    /// The prior over every term searched, each given by its cost in nats.
    pub fn over(nats: &[f64]) -> FormPrior {
        let w = nats.iter().map(|k| FormPrior::weight(*k));
        FormPrior { total: w.clone().sum(), squares: w.map(|w| w * w).sum() }
    }

    /// Prior log odds of a term (or a pair) against the model as it is. The
    /// pairs were chosen after the data ranked the singles, so a pair pays
    /// for every pair the grammar could make, not only those fitted.
    pub fn log_odds(&self, terms: &[f64]) -> f64 {
        let own: f64 = terms.iter().map(|k| -k).sum();
        match terms.len() {
            1 => own - self.total.ln(),
            _ => own - (0.5 * (self.total * self.total - self.squares)).max(f64::MIN_POSITIVE).ln(),
        }
    }

    /// Prior log odds of corrections of several observables at once (of
    /// each of `observables`, all offered the same forms, none or one):
    /// normalized over every such choice of two or more, so that these too
    /// pay for every combination the grammar could make, as pairs do.
    pub fn log_odds_one_per_observable(&self, terms: &[f64], observables: usize) -> f64 {
        let own: f64 = terms.iter().map(|k| -k).sum();
        let m = observables.max(2) as f64;
        let w = self.total / m;
        let choices = (m * w.ln_1p()).exp_m1() - m * w;
        own - choices.max(f64::MIN_POSITIVE).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_learned_costs_read_and_rarer_operations_cost_more() {
        // The corpus uses products far more than powers of three, and sines more than logarithms.
        assert!(cost("*") < cost("pow3") && cost("sin") < cost("log"));
        // c*x: one product; c*x^2 adds a square; abs is free.
        assert!((nats("c*x") - cost("*")).abs() < 1e-12);
        assert!((nats("c*x*abs(x)") - 2.0 * cost("*")).abs() < 1e-12);
        let hill = cost("*") + cost("/") + cost("+") + 3.0 * cost("pow2");
        assert!((nats("c*x^2/(K^2 + x^2)") - hill).abs() < 1e-12, "{} vs {hill}", nats("c*x^2/(K^2 + x^2)"));
        // A free exponent is a general power; a function unknown to the corpus costs the most.
        assert!((nats("c*abs(x)^p") - (cost("*") + cost("pow"))).abs() < 1e-12);
        assert_eq!(nats("erf(x)"), rare());
        assert_eq!(nats("-x"), 0.0);
    }

    /// An angle the model writes inside a sine pays the corpus's price when
    /// a form uses it bare; inside a sine or cosine, or where the model never
    /// makes it an angle, it costs what it always did.
    #[test]
    fn an_angle_written_bare_costs_what_the_corpus_says() {
        let angles: BTreeSet<String> = ["x_0".to_string()].into();
        let bare = cost(BARE_ANGLE);
        assert!(bare > 2.0 && bare < 3.0, "{bare}");
        assert_eq!(nats_given("c*sin(x_0)", &angles), nats("c*sin(x_0)"));
        assert_eq!(nats_given("c*x_1", &angles), nats("c*x_1"));
        assert!((nats_given("c*x_0", &angles) - nats("c*x_0") - bare).abs() < 1e-12);
        assert!(
            (nats_given("c*x_0/(K + abs(x_0))", &angles) - nats("c*x_0/(K + abs(x_0))") - 2.0 * bare).abs() < 1e-12
        );
        // The form's own sine makes its name an angle too.
        let none = BTreeSet::new();
        assert!((nats_given("c*t*cos(w*t)", &none) - nats("c*t*cos(w*t)") - bare).abs() < 1e-12);
    }

    #[test]
    fn the_search_pays_its_look_elsewhere_odds_and_simpler_forms_lead() {
        let all = [0.0, 0.3, 0.3, 1.5, 1.5, 2.0, 3.5, 3.5];
        let prior = FormPrior::over(&all);
        // Singles' odds sum to one against the model as it is; so do pairs'.
        let singles: f64 = all.iter().map(|k| prior.log_odds(&[*k]).exp()).sum();
        assert!((singles - 1.0).abs() < 1e-12, "{singles}");
        let mut pairs = 0.0;
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                pairs += prior.log_odds(&[*a, *b]).exp();
            }
        }
        assert!((pairs - 1.0).abs() < 1e-12, "{pairs}");
        // Each nat of a form's cost is a nat of odds.
        assert!((prior.log_odds(&[0.3]) - prior.log_odds(&[1.5]) - 1.2).abs() < 1e-12);
        // With every form the same size it is the uniform 1 : N.
        assert!((FormPrior::over(&[2.0; 38]).log_odds(&[2.0]) + 38f64.ln()).abs() < 1e-12);
    }

    /// Corrections of two or more observables at once: their odds sum to one.
    #[test]
    fn corrections_of_several_observables_pay_for_every_combination() {
        let forms = [0.3, 1.0, 1.5, 1.5];
        let observables = 3;
        let all: Vec<f64> = (0..observables).flat_map(|_| forms).collect();
        let prior = FormPrior::over(&all);
        let choices: Vec<Option<f64>> = std::iter::once(None).chain(forms.iter().copied().map(Some)).collect();
        let mut sum = 0.0;
        for a in &choices {
            for b in &choices {
                for c in &choices {
                    let terms: Vec<f64> = [a, b, c].iter().filter_map(|t| **t).collect();
                    if terms.len() >= 2 {
                        sum += prior.log_odds_one_per_observable(&terms, observables).exp();
                    }
                }
            }
        }
        assert!((sum - 1.0).abs() < 1e-12, "{sum}");
    }
}
