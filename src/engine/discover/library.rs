//! Terms built by composition, not by list: a term is a coefficient times
//! a product of at most two primitive functions of the place's symbols
//! (powers, fractional or free; exp, log, sin and cos; saturating and Hill
//! forms; a logistic step), or three of the symbols themselves. Every
//! symbol enters scaled by its own range on the data about a reference
//! value, so a temperature in kelvin is as easy to vary as a quantity near
//! zero, and a coefficient means the same whatever a free exponent is
//! (`c*abs(s/S)^p`: c is the term's size at |s| = S).

use super::prior;
use crate::engine::formula::notation;

/// A symbol a term may be built from, with its values at the screening's
/// points and the scales read off them.
#[derive(Clone, Debug)]
pub struct Symbol {
    pub name: String,
    pub values: Vec<f64>,
    pub scale: Scale,
    /// The model uses it inside a sine, cosine or tangent (an angle or a
    /// phase): a form that uses it bare pays the prior's price for that.
    pub angle: bool,
}

impl Symbol {
    /// `name` at `values`, `None` where they give it no scale (not finite,
    /// or zero throughout).
    pub fn of(name: &str, values: &[f64], angle: bool) -> Option<Symbol> {
        Some(Symbol { name: name.to_string(), scale: Scale::of(values)?, values: values.to_vec(), angle })
    }
}

/// A symbol's size and range on the data.
#[derive(Clone, Copy, Debug)]
pub struct Scale {
    /// The largest |s|.
    pub largest: f64,
    pub lo: f64,
    pub hi: f64,
    /// The reference about which the symbol is centred: its mean on the data.
    pub reference: f64,
    /// Keeps one sign (values of the other within 1% of the largest count as zero).
    pub one_signed: bool,
    /// Keeps one sign and stays away from zero (|s| above 2% of the largest):
    /// 1/s and log|s| are defined over the data.
    pub away_from_zero: bool,
}

impl Scale {
    pub fn of(values: &[f64]) -> Option<Scale> {
        let finite = values.iter().all(|v| v.is_finite());
        let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
        let largest = hi.max(-lo);
        if !finite || values.is_empty() || largest <= 0.0 {
            return None;
        }
        let one_signed = lo >= -0.01 * largest || hi <= 0.01 * largest;
        let smallest = values.iter().fold(f64::INFINITY, |m, v| m.min(v.abs()));
        let reference = values.iter().sum::<f64>() / values.len() as f64;
        Some(Scale { largest, lo, hi, reference, one_signed, away_from_zero: one_signed && smallest > 0.02 * largest })
    }

    /// The symbol's span on the data, or its size where it does not vary.
    pub fn span(&self) -> f64 {
        let span = self.hi - self.lo;
        if span > 1e-9 * self.largest {
            span
        } else {
            self.largest
        }
    }
}

/// A primitive function of one symbol.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Unary {
    Id,
    Square,
    SignedSquare,
    Cube,
    /// |s/S|^p, p free.
    Power,
    Reciprocal,
    /// exp(a (s − R)/S), a free.
    Exp,
    Log,
    Sin,
    Cos,
    Sin2,
    Cos2,
    /// s/(K + |s|), K free.
    Saturating,
    /// s²/(K² + s²), K free.
    Hill,
    /// 1/(1 + exp(a (s − b)/S)), a and b free.
    Logistic,
    /// s·log(K/|s|), K free: growth that slows as the log of the distance
    /// to a scale (Gompertz), or an entropy's s·ln s.
    XLog,
}

/// A nonlinear parameter of a term: its prior range and the grid the
/// screening profiles it over.
#[derive(Clone, Debug)]
pub struct Nonlinear {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub grid: Vec<f64>,
}

/// Points spread evenly (`log`: geometrically) over [lo, hi].
fn spread(lo: f64, hi: f64, n: usize, log: bool) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let f = (i as f64 + 0.5) / n as f64;
            if log {
                lo * (hi / lo).powf(f)
            } else {
                lo + (hi - lo) * f
            }
        })
        .collect()
}

impl Unary {
    pub const ALL: [Unary; 16] = [
        Unary::Id,
        Unary::Square,
        Unary::SignedSquare,
        Unary::Cube,
        Unary::Power,
        Unary::Reciprocal,
        Unary::Exp,
        Unary::Log,
        Unary::Sin,
        Unary::Cos,
        Unary::Sin2,
        Unary::Cos2,
        Unary::Saturating,
        Unary::Hill,
        Unary::Logistic,
        Unary::XLog,
    ];
    /// Those a product of two symbols' functions is built from.
    pub const IN_PRODUCTS: [Unary; 9] = [
        Unary::Id,
        Unary::Square,
        Unary::Sin,
        Unary::Cos,
        Unary::Sin2,
        Unary::Cos2,
        Unary::Reciprocal,
        Unary::Saturating,
        Unary::Exp,
    ];

    /// Whether the function is defined, and distinct from a simpler one,
    /// over a symbol of this scale.
    pub fn applies(self, s: &Scale) -> bool {
        match self {
            // Where s keeps one sign, s|s| is ±s².
            Unary::SignedSquare => !s.one_signed,
            Unary::Reciprocal | Unary::Log | Unary::XLog => s.away_from_zero,
            _ => true,
        }
    }

    fn key(self) -> &'static str {
        match self {
            Unary::Id => "linear",
            Unary::Square => "square",
            Unary::SignedSquare => "signed_square",
            Unary::Cube => "cube",
            Unary::Power => "power",
            Unary::Reciprocal => "reciprocal",
            Unary::Exp => "exp",
            Unary::Log => "log",
            Unary::Sin => "sin",
            Unary::Cos => "cos",
            Unary::Sin2 => "sin2",
            Unary::Cos2 => "cos2",
            Unary::Saturating => "saturating",
            Unary::Hill => "hill",
            Unary::Logistic => "logistic",
            Unary::XLog => "xlog",
        }
    }

    /// The function as a physicist writes it, for the prior over forms:
    /// scales and references are not operations of the form.
    fn canonical(self) -> &'static str {
        match self {
            Unary::Id => "s",
            Unary::Square => "s^2",
            Unary::SignedSquare => "s*abs(s)",
            Unary::Cube => "s^3",
            Unary::Power => "abs(s)^p",
            Unary::Reciprocal => "1/s",
            Unary::Exp => "exp(a*s)",
            Unary::Log => "log(s)",
            Unary::Sin => "sin(s)",
            Unary::Cos => "cos(s)",
            Unary::Sin2 => "sin(s)^2",
            Unary::Cos2 => "cos(s)^2",
            Unary::Saturating => "s/(K + s)",
            Unary::Hill => "s^2/(K^2 + s^2)",
            Unary::Logistic => "1/(1 + exp(a*s - b))",
            Unary::XLog => "s*log(K/s)",
        }
    }

    /// Its nonlinear parameters on a symbol of this scale, named with `tag`.
    pub fn nonlinear(self, s: &Scale, tag: &str) -> Vec<Nonlinear> {
        let named = |n: &str| format!("{n}{tag}");
        match self {
            Unary::Power => {
                vec![Nonlinear { name: named("p"), min: 0.25, max: 5.0, grid: spread(0.25, 5.0, 20, false) }]
            }
            Unary::Exp => {
                let mut grid = spread(-12.0, 12.0, 24, false);
                grid.retain(|a| a.abs() > 0.2);
                vec![Nonlinear { name: named("a"), min: -12.0, max: 12.0, grid }]
            }
            Unary::Saturating | Unary::Hill => {
                let (lo, hi) = (0.01 * s.largest, 30.0 * s.largest);
                vec![Nonlinear { name: named("K"), min: 0.0, max: hi, grid: spread(lo, hi, 16, true) }]
            }
            Unary::XLog => {
                // log(K/|s|) is finite only for K > 0: the prior stops at the grid's smallest scale.
                let (lo, hi) = (0.01 * s.largest, 30.0 * s.largest);
                vec![Nonlinear { name: named("K"), min: lo, max: hi, grid: spread(lo, hi, 16, true) }]
            }
            Unary::Logistic => {
                let mut rates = spread(0.5, 16.0, 6, true);
                rates.extend(rates.clone().iter().map(|a| -a));
                vec![
                    Nonlinear { name: named("a"), min: -16.0, max: 16.0, grid: rates },
                    Nonlinear { name: named("b"), min: s.lo, max: s.hi, grid: spread(s.lo, s.hi, 6, false) },
                ]
            }
            _ => Vec::new(),
        }
    }

    /// The function of `s` as a formula, its parameters named `p`.
    pub fn render(self, s: &str, scale: &Scale, p: &[String]) -> String {
        let (big, span, reference) = (number(scale.largest), number(scale.span()), number(scale.reference));
        match self {
            Unary::Id => s.to_string(),
            Unary::Square => format!("{s}^2"),
            Unary::SignedSquare => format!("{s}*abs({s})"),
            Unary::Cube => format!("{s}^3"),
            Unary::Power => format!("abs({s}/{big})^{}", p[0]),
            Unary::Reciprocal => format!("1/{s}"),
            Unary::Exp => format!("exp({}*({s} - {reference})/{span})", p[0]),
            Unary::Log => format!("log(abs({s}))"),
            Unary::Sin => format!("sin({s})"),
            Unary::Cos => format!("cos({s})"),
            Unary::Sin2 => format!("sin({s})^2"),
            Unary::Cos2 => format!("cos({s})^2"),
            Unary::Saturating => format!("{s}/({} + abs({s}))", p[0]),
            Unary::Hill => format!("{s}^2/({}^2 + {s}^2)", p[0]),
            Unary::Logistic => format!("1/(1 + exp({}*({s} - {})/{span}))", p[0], p[1]),
            Unary::XLog => format!("{s}*log({}/abs({s}))", p[0]),
        }
    }

    /// The function's value at `v`, its parameters at `p`.
    pub fn eval(self, v: f64, scale: &Scale, p: &[f64]) -> f64 {
        match self {
            Unary::Id => v,
            Unary::Square => v * v,
            Unary::SignedSquare => v * v.abs(),
            Unary::Cube => v * v * v,
            Unary::Power => (v / scale.largest).abs().powf(p[0]),
            Unary::Reciprocal => 1.0 / v,
            Unary::Exp => (p[0] * (v - scale.reference) / scale.span()).exp(),
            Unary::Log => v.abs().ln(),
            Unary::Sin => v.sin(),
            Unary::Cos => v.cos(),
            Unary::Sin2 => v.sin().powi(2),
            Unary::Cos2 => v.cos().powi(2),
            Unary::Saturating => v / (p[0] + v.abs()),
            Unary::Hill => v * v / (p[0] * p[0] + v * v),
            Unary::Logistic => 1.0 / (1.0 + (p[0] * (v - p[1]) / scale.span()).exp()),
            Unary::XLog => v * (p[0] / v.abs()).ln(),
        }
    }

    /// What the function says of s, in words.
    fn phrase(self, s: &str) -> String {
        match self {
            Unary::Id => format!("proportional to {s}"),
            Unary::Square => format!("growing as the square of {s}"),
            Unary::SignedSquare => format!("growing as the square of {s}, with {s}'s sign"),
            Unary::Cube => format!("growing as the cube of {s}"),
            Unary::Power => format!("growing as a power of |{s}|, its exponent free"),
            Unary::Reciprocal => format!("inversely proportional to {s}"),
            Unary::Exp => format!("exponential in {s}"),
            Unary::Log => format!("logarithmic in {s}"),
            Unary::Sin => format!("the sine of {s}"),
            Unary::Cos => format!("the cosine of {s}"),
            Unary::Sin2 => format!("the squared sine of {s}"),
            Unary::Cos2 => format!("the squared cosine of {s}"),
            Unary::Saturating => format!("saturating in {s} above a scale K"),
            Unary::Hill => format!("switching on as {s} passes a scale K (a Hill function of order 2)"),
            Unary::Logistic => format!("a smooth step in {s} at b"),
            Unary::XLog => format!("{s} times the log of a scale K over {s}"),
        }
    }
}

/// A number written into a formula: enough digits to be exact for the fit.
pub fn number(v: f64) -> String {
    let text = seven_digits(v);
    if v < 0.0 {
        format!("({text})")
    } else {
        text
    }
}

/// A fitted value as the verdict's words give it: to four decimals, in
/// exponent form only when it is very small or very large (a scale that
/// fell to 3.2e-5 is not "0.000").
pub fn fitted_value(v: f64) -> String {
    if v != 0.0 && !(1e-2..1e4).contains(&v.abs()) {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}").trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// `v` to seven significant digits, the decimal `{:.6e}` writes, but as a
/// physicist writes it where that is short (`25`, `0.6500487`, not
/// `2.500000e1`, `6.500487e-1`): the same decimal, so the same f64 parsed,
/// and a formula compiles to the same model either way.
pub fn seven_digits(v: f64) -> String {
    let sci = format!("{v:.6e}");
    let Some((mantissa, exponent)) = sci.split_once('e') else { return sci };
    let Ok(exponent) = exponent.parse::<i32>() else { return sci };
    if !(-4..=6).contains(&exponent) {
        return sci;
    }
    let digits: String = mantissa.chars().filter(char::is_ascii_digit).collect();
    let point = exponent + 1;
    let text = if point <= 0 {
        format!("0.{}{digits}", "0".repeat(point.unsigned_abs() as usize))
    } else {
        let (whole, fraction) = digits.split_at((point as usize).min(digits.len()));
        let whole = format!("{whole}{}", "0".repeat((point as usize).saturating_sub(digits.len())));
        format!("{whole}.{fraction}")
    };
    let text = if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.') } else { &text };
    let sign = if mantissa.starts_with('-') { "-" } else { "" };
    format!("{sign}{text}")
}

/// One factor of a term: a primitive of the symbol at `symbol`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Factor {
    pub unary: Unary,
    pub symbol: usize,
}

impl Factor {
    /// What the prior charges for this factor's bare uses of its symbol,
    /// when the model makes that symbol an angle (`s` in `s^2`, not in `sin(s)`).
    fn angle_nats(&self, symbols: &[Symbol]) -> f64 {
        if !symbols[self.symbol].angle {
            return 0.0;
        }
        let angle = std::collections::BTreeSet::from(["s".to_string()]);
        notation::parse(self.unary.canonical()).map_or(0.0, |e| prior::bare_angle_nats(&e, &angle))
    }
}

/// A term of the library: its coefficient times a product of factors (none: a constant).
#[derive(Clone, Debug)]
pub struct Term {
    pub factors: Vec<Factor>,
    pub nonlinear: Vec<Nonlinear>,
    /// Its prior cost in nats (`prior::nats` of its canonical form).
    pub nats: f64,
}

impl Term {
    fn new(factors: Vec<Factor>, symbols: &[Symbol]) -> Term {
        let mut nonlinear = Vec::new();
        for (k, f) in factors.iter().enumerate() {
            let tag = if factors.len() > 1 { (k + 1).to_string() } else { String::new() };
            nonlinear.extend(f.unary.nonlinear(&symbols[f.symbol].scale, &tag));
        }
        let canonical: Vec<&str> = factors.iter().map(|f| f.unary.canonical()).collect();
        let operations = if canonical.is_empty() { 0.0 } else { prior::nats(&format!("c*{}", canonical.join("*"))) };
        let nats = operations + factors.iter().map(|f| f.angle_nats(symbols)).sum::<f64>();
        Term { factors, nonlinear, nats }
    }

    /// `square_x_0`, `linear_x_0_cos_x_1`, `constant`.
    pub fn name(&self, symbols: &[Symbol]) -> String {
        if self.factors.is_empty() {
            return "constant".into();
        }
        let parts: Vec<String> =
            self.factors.iter().map(|f| format!("{}_{}", f.unary.key(), symbols[f.symbol].name)).collect();
        parts.join("_")
    }

    /// The term as a formula, each of its parameters (`c` and the
    /// nonlinear ones) written as `name` gives it.
    pub fn render(&self, symbols: &[Symbol], name: &dyn Fn(&str) -> String) -> String {
        let mut at = 0;
        let mut parts = vec![name("c")];
        for f in &self.factors {
            let n = f.unary.nonlinear(&symbols[f.symbol].scale, "").len();
            let names: Vec<String> = self.nonlinear[at..at + n].iter().map(|p| name(&p.name)).collect();
            at += n;
            let s = &symbols[f.symbol];
            let text = f.unary.render(&s.name, &s.scale, &names);
            let simple = text.chars().all(|c| c.is_alphanumeric() || c == '_' || c == '^');
            parts.push(if simple { text } else { format!("({text})") });
        }
        parts.join("*")
    }

    /// The term's value without its coefficient at every point, its
    /// nonlinear parameters at `p`.
    pub fn column(&self, symbols: &[Symbol], p: &[f64], out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 1.0);
        let mut at = 0;
        for f in &self.factors {
            let s = &symbols[f.symbol];
            let n = f.unary.nonlinear(&s.scale, "").len();
            for (o, v) in out.iter_mut().zip(&s.values) {
                *o *= f.unary.eval(*v, &s.scale, &p[at..at + n]);
            }
            at += n;
        }
    }

    /// What the term means, in words built from the symbols' own names.
    pub fn meaning(&self, symbols: &[Symbol]) -> String {
        match self.factors.as_slice() {
            [] => "a constant".into(),
            [f] => format!("a term {}", f.unary.phrase(&symbols[f.symbol].name)),
            fs => {
                let parts: Vec<String> = fs.iter().map(|f| f.unary.phrase(&symbols[f.symbol].name)).collect();
                format!("a product of terms {}", parts.join(" and "))
            }
        }
    }

    /// Every grid point of the nonlinear parameters (one empty point when it has none).
    pub fn grid(&self) -> Vec<Vec<f64>> {
        let mut out = vec![Vec::new()];
        for p in &self.nonlinear {
            out = out.into_iter().flat_map(|s| p.grid.iter().map(move |v| [s.clone(), vec![*v]].concat())).collect();
        }
        out
    }
}

/// Every term over `symbols`: a constant; each primitive of each symbol;
/// each product of two primitives of different symbols (at most one with
/// a nonlinear parameter), and sin·cos of one; each product of three
/// different symbols.
pub fn terms(symbols: &[Symbol]) -> Vec<Term> {
    let mut out = vec![Term::new(Vec::new(), symbols)];
    let applies = |u: Unary, s: usize| u.applies(&symbols[s].scale);
    for s in 0..symbols.len() {
        for u in Unary::ALL.into_iter().filter(|u| applies(*u, s)) {
            out.push(Term::new(vec![Factor { unary: u, symbol: s }], symbols));
        }
        out.push(Term::new(
            vec![Factor { unary: Unary::Sin, symbol: s }, Factor { unary: Unary::Cos, symbol: s }],
            symbols,
        ));
    }
    let nonlinear = |u: Unary| !u.nonlinear(&symbols[0].scale, "").is_empty();
    for a in 0..symbols.len() {
        for b in a + 1..symbols.len() {
            for ua in Unary::IN_PRODUCTS.into_iter().filter(|u| applies(*u, a)) {
                for ub in Unary::IN_PRODUCTS.into_iter().filter(|u| applies(*u, b)) {
                    if nonlinear(ua) && nonlinear(ub) {
                        continue;
                    }
                    let factors = vec![Factor { unary: ua, symbol: a }, Factor { unary: ub, symbol: b }];
                    out.push(Term::new(factors, symbols));
                }
            }
            for c in b + 1..symbols.len() {
                let factors = [a, b, c].map(|s| Factor { unary: Unary::Id, symbol: s }).to_vec();
                out.push(Term::new(factors, symbols));
            }
        }
    }
    out
}

#[cfg(test)]
mod number_tests {
    use super::{fitted_value, number, seven_digits};

    #[test]
    fn a_number_in_a_formula_reads_plainly_and_parses_to_the_value_it_always_did() {
        assert_eq!(seven_digits(25.0), "25");
        assert_eq!(seven_digits(0.6500487123), "0.6500487");
        assert_eq!(seven_digits(14.5), "14.5");
        assert_eq!(seven_digits(0.0), "0");
        assert_eq!(seven_digits(-0.00012345678), "-0.0001234568");
        assert_eq!(seven_digits(9.9999996), "10");
        assert_eq!(seven_digits(1234567.8), "1234568");
        assert_eq!(seven_digits(12345678.0), "1.234568e7");
        assert_eq!(seven_digits(3.2e-7), "3.200000e-7");
        assert_eq!(number(-2.5), "(-2.5)");
        assert_eq!(
            (fitted_value(3.2e-5), fitted_value(0.3712), fitted_value(6.0)),
            ("3.200e-5".into(), "0.3712".into(), "6".into())
        );
        // Whatever the value, the decimal is the one `{:.6e}` wrote, so the
        // same f64 is parsed and a formula compiles to the same model.
        let mut v = 1.234_567_89e-6_f64;
        while v < 1e8 {
            for x in [v, -v, v * 0.999_999_97, v * 1.000_000_03] {
                let before: f64 = format!("{x:.6e}").parse().unwrap();
                assert_eq!(seven_digits(x).parse::<f64>().unwrap(), before, "{x}: {}", seven_digits(x));
            }
            v *= 1.37;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::formula::{Formula, Scope};

    fn symbol(name: &str, values: Vec<f64>) -> Symbol {
        let scale = Scale::of(&values).unwrap();
        Symbol { name: name.into(), values, scale, angle: false }
    }

    /// Each term's column is its formula's value, the formula compiled
    /// by the engine's own parser with the coefficient at 1.
    #[test]
    fn every_term_evaluates_as_its_formula_reads() {
        let x: Vec<f64> = (0..7).map(|i| 0.3 + 0.4 * i as f64).collect();
        let y: Vec<f64> = (0..7).map(|i| -1.0 + 0.5 * i as f64).collect();
        let symbols = [symbol("x", x), symbol("y", y)];
        let all = terms(&symbols);
        assert!(all.len() > 80, "{}", all.len());
        for term in &all {
            let text = term.render(&symbols, &|p| p.to_string());
            let mut names: Vec<String> = vec!["c".into(), "x".into(), "y".into()];
            names.extend(term.nonlinear.iter().map(|p| p.name.clone()));
            let f = Formula::parse(&text, &Scope::new(names), "test").unwrap();
            let p: Vec<f64> = term.nonlinear.iter().map(|n| n.grid[n.grid.len() / 2]).collect();
            let mut column = vec![0.0; 7];
            term.column(&symbols, &p, &mut column);
            for i in 0..7 {
                let mut at = vec![1.0, symbols[0].values[i], symbols[1].values[i]];
                at.extend(&p);
                let want = f.eval(&at);
                assert!((column[i] - want).abs() <= 1e-9 * want.abs().max(1.0), "{text}: {} vs {want}", column[i]);
            }
        }
    }

    #[test]
    fn functions_undefined_on_the_data_are_left_out_and_simpler_forms_cost_less() {
        let through_zero = symbol("v", vec![-2.0, -1.0, 0.0, 1.0, 2.0]);
        let positive = symbol("T", vec![300.0, 305.0, 310.0]);
        assert!(!Unary::Reciprocal.applies(&through_zero.scale) && !Unary::Log.applies(&through_zero.scale));
        assert!(Unary::SignedSquare.applies(&through_zero.scale) && !Unary::SignedSquare.applies(&positive.scale));
        assert!(Unary::Reciprocal.applies(&positive.scale));
        let symbols = [positive];
        let cost = |u: Unary| Term::new(vec![Factor { unary: u, symbol: 0 }], &symbols).nats;
        assert!(cost(Unary::Id) < cost(Unary::Square) && cost(Unary::Square) < cost(Unary::Cube));
        assert!(cost(Unary::Square) < cost(Unary::Hill) && cost(Unary::Sin) < cost(Unary::Log));
        assert_eq!(Term::new(Vec::new(), &symbols).nats, 0.0);
    }

    /// A symbol the model uses as an angle pays the prior's price for each
    /// bare use in a form (one in θ, two in θ|θ|), and nothing inside a sine.
    #[test]
    fn an_angle_pays_for_each_bare_use_and_nothing_inside_a_sine() {
        let values = vec![-1.2, -0.4, 0.3, 1.1];
        let plain = [symbol("theta", values.clone())];
        let angle = [Symbol { angle: true, ..symbol("theta", values) }];
        let bare = prior::nats_given("c*x", &["x".to_string()].into()) - prior::nats("c*x");
        assert!(bare > 2.0, "{bare}");
        let cost = |symbols: &[Symbol], u: Unary| Term::new(vec![Factor { unary: u, symbol: 0 }], symbols).nats;
        for (u, uses) in [(Unary::Sin, 0.0), (Unary::Cos2, 0.0), (Unary::Id, 1.0), (Unary::SignedSquare, 2.0)] {
            let extra = cost(&angle, u) - cost(&plain, u);
            assert!((extra - uses * bare).abs() < 1e-12, "{u:?}: {extra}");
        }
    }

    /// A temperature near 300 K varies an exponential over its own span,
    /// not over its size: exp(a (T − T̄)/span) reaches a factor e^a across the data.
    #[test]
    fn a_symbol_far_from_zero_is_centred_and_scaled_by_its_span() {
        let symbols = [symbol("T", vec![300.0, 310.0, 320.0])];
        let term = Term::new(vec![Factor { unary: Unary::Exp, symbol: 0 }], &symbols);
        let mut column = vec![0.0; 3];
        term.column(&symbols, &[1.0], &mut column);
        assert!((column[2] / column[0] - 1f64.exp()).abs() < 1e-12, "{column:?}");
    }
}
