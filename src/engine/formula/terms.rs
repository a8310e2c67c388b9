//! A formula as the sum of its terms, the way a physicist reads a law:
//! products and quotients of sums multiplied out, functions (`sin`, `exp`)
//! and powers kept whole, as `sympy.expand` leaves them. `c_1*x_2*(c_8 +
//! x_1)` is the two terms `c_1*x_2*c_8` and `c_1*x_2*x_1`. Signs are set
//! apart: a term is what a coefficient multiplies.

use super::notation::Expr;

/// The terms of `e` with their signs (±1), or None beyond `limit` terms
/// (a product of long sums multiplies out into too many to be read).
pub fn additive(e: &Expr, limit: usize) -> Option<Vec<(f64, Expr)>> {
    let out = match e {
        Expr::Neg(a) => additive(a, limit)?.into_iter().map(|(s, t)| (-s, t)).collect(),
        Expr::Binary(op @ ('+' | '-'), a, b) => {
            let sign = if *op == '-' { -1.0 } else { 1.0 };
            let mut out = additive(a, limit)?;
            out.extend(additive(b, limit)?.into_iter().map(|(s, t)| (sign * s, t)));
            out
        }
        Expr::Binary('*', a, b) => {
            let (ta, tb) = (additive(a, limit)?, additive(b, limit)?);
            if ta.len() * tb.len() > limit {
                return None;
            }
            let mut out = Vec::new();
            for (sa, a) in &ta {
                for (sb, b) in &tb {
                    out.push((sa * sb, product(a, b)));
                }
            }
            out
        }
        // The denominator whole: x/(c + x) is one term, a saturation.
        Expr::Binary('/', a, b) => {
            additive(a, limit)?.into_iter().map(|(s, t)| (s, Expr::Binary('/', Box::new(t), b.clone()))).collect()
        }
        Expr::Number(v) if *v < 0.0 => vec![(-1.0, Expr::Number(-v))],
        _ => vec![(1.0, e.clone())],
    };
    (out.len() <= limit).then_some(out)
}

/// a·b, a factor of 1 left out.
fn product(a: &Expr, b: &Expr) -> Expr {
    match (a, b) {
        (Expr::Number(v), x) | (x, Expr::Number(v)) if *v == 1.0 => x.clone(),
        _ => Expr::Binary('*', Box::new(a.clone()), Box::new(b.clone())),
    }
}

/// The formula as text with only the parentheses its reading needs.
pub fn render(e: &Expr) -> String {
    written(e).0
}

/// Binding strength: sums 1, products 2, a sign 3, powers 4, atoms 5.
fn written(e: &Expr) -> (String, u8) {
    match e {
        Expr::Number(v) => (format!("{v}"), if *v < 0.0 { 3 } else { 5 }),
        Expr::Name(n) => (n.clone(), 5),
        Expr::Call(f, args) => (format!("{f}({})", args.iter().map(render).collect::<Vec<_>>().join(", ")), 5),
        // A sign commutes with a product or quotient: -(d*A) reads -d*A.
        Expr::Neg(a) if matches!(a.as_ref(), Expr::Binary('*' | '/', _, _)) => (format!("-{}", written(a).0), 2),
        Expr::Neg(a) => (format!("-{}", operand(a, 4)), 3),
        Expr::Binary(op, a, b) => {
            let strength = match op {
                '+' | '-' => 1,
                '*' | '/' => 2,
                _ => 4,
            };
            // Left-associative + - * /: the right operand binds tighter; `^`
            // is right-associative, its left operand binds tighter.
            let (left, right) = if *op == '^' { (strength + 1, strength) } else { (strength, strength + 1) };
            (format!("{}{}{}", operand(a, left), spaced(*op), operand(b, right)), strength)
        }
    }
}

fn spaced(op: char) -> String {
    if matches!(op, '+' | '-') {
        format!(" {op} ")
    } else {
        op.to_string()
    }
}

fn operand(e: &Expr, needed: u8) -> String {
    let (text, strength) = written(e);
    if strength < needed {
        format!("({text})")
    } else {
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::formula::notation::parse;
    use crate::engine::formula::{Formula, Scope};

    fn eval(text: &str, names: &[&str], values: &[f64]) -> f64 {
        let scope = Scope::new(names.iter().map(|n| n.to_string()));
        Formula::parse(text, &scope, "test").unwrap().eval(values)
    }

    #[test]
    fn a_law_splits_into_the_terms_sympy_expand_gives() {
        let law = "c_2*x_1/(c_6 + x_1) - c_1*x_2*(c_8 + x_1) + c_3*x_0*x_1/(c_7 + x_1)";
        let terms = additive(&parse(law).unwrap(), 16).unwrap();
        let text: Vec<(f64, String)> = terms.iter().map(|(s, t)| (*s, render(t))).collect();
        assert_eq!(
            text,
            vec![
                (1.0, "c_2*x_1/(c_6 + x_1)".to_string()),
                (-1.0, "c_1*x_2*c_8".to_string()),
                (-1.0, "c_1*x_2*x_1".to_string()),
                (1.0, "c_3*x_0*x_1/(c_7 + x_1)".to_string()),
            ]
        );
    }

    #[test]
    fn the_terms_sum_to_the_formula_and_render_as_they_read() {
        let names = ["a", "b", "x", "y"];
        let values = [0.7, -1.3, 2.1, 0.4];
        for text in [
            "-a*(x - y)^2 + b*sin(x)*(1 - y)",
            "(a + b)*(x - y)/(1 + x^2) - 3",
            "-(a - x)*(b + y*x) + x^-2",
            "a - (b - x) - -y",
            "2^x^y*(a + b)",
            "x*-(a*y) - -(b/x)*y + -(a + b)^2",
        ] {
            let terms = additive(&parse(text).unwrap(), 16).unwrap();
            let sum: f64 = terms.iter().map(|(s, t)| s * eval(&render(t), &names, &values)).sum();
            let whole = eval(text, &names, &values);
            assert!((sum - whole).abs() <= 1e-12 * whole.abs().max(1.0), "{text}: {sum} against {whole}");
            assert_eq!(eval(&render(&parse(text).unwrap()), &names, &values), whole, "{text} rendered");
        }
    }

    #[test]
    fn a_product_of_long_sums_is_refused_beyond_the_limit() {
        let e = parse("(a + b + x)*(a + b + y)*(x + y)").unwrap();
        assert!(additive(&e, 16).is_none());
        assert_eq!(additive(&e, 18).map(|t| t.len()), Some(18));
    }
}
