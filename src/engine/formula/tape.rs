//! A parsed formula compiled to a short postfix program ("tape") over a
//! fixed stack, so that evaluating it reads the caller's value vector in
//! place, never allocates, and pays no interpretation overhead beyond one
//! `match` per operation.
//!
//! Why not evaluate with exmex: declared models evaluate formulas hundreds
//! of times per likelihood evaluation (every ODE right-hand side, every
//! observable at every point), and exmex copies its operand list and
//! gathers the variables on each call; that was 40% of the declared ball
//! drop's likelihood. exmex remains the tests' independent evaluator.
//!
//! Compilation folds constant subexpressions, and writes `x^2` and `x^3`
//! as products and other small integer powers as `powi`; these agree with
//! `powf` to a few ulps.

use super::closures::{self, Built};
use super::notation::Expr;
use super::ops::Op;
use anyhow::{bail, Result};

/// The deepest stack a formula may need.
pub const MAX_DEPTH: usize = 24;

/// A compiled formula: evaluate with [`Tape::eval`].
#[derive(Clone)]
pub struct Tape {
    code: Vec<Op>,
    /// The same operations as a tree of closures (`closures`), which is
    /// what `eval` runs.
    root: Built,
}

impl std::fmt::Debug for Tape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tape").field("code", &self.code).finish()
    }
}

fn function1(name: &str) -> Option<fn(f64) -> f64> {
    Some(match name {
        "abs" => f64::abs,
        "signum" => f64::signum,
        "sin" => f64::sin,
        "cos" => f64::cos,
        "tan" => f64::tan,
        "asin" => f64::asin,
        "acos" => f64::acos,
        "atan" => f64::atan,
        "sinh" => f64::sinh,
        "cosh" => f64::cosh,
        "tanh" => f64::tanh,
        "asinh" => f64::asinh,
        "acosh" => f64::acosh,
        "atanh" => f64::atanh,
        "floor" => f64::floor,
        "round" => f64::round,
        "ceil" => f64::ceil,
        "trunc" => f64::trunc,
        "fract" => f64::fract,
        "exp" => f64::exp,
        "sqrt" => f64::sqrt,
        "cbrt" => f64::cbrt,
        "ln" | "log" => f64::ln,
        "log2" => f64::log2,
        "log10" => f64::log10,
        _ => return None,
    })
}

fn function2(name: &str) -> Option<fn(f64, f64) -> f64> {
    Some(match name {
        "atan2" => f64::atan2,
        "min" => f64::min,
        "max" => f64::max,
        _ => return None,
    })
}

/// The functions a formula may call, for error messages.
pub const FUNCTIONS: &str = "abs, signum, sqrt, cbrt, exp, ln, log, log2, log10, sin, cos, tan, asin, acos, atan, sinh, cosh, tanh, asinh, acosh, atanh, floor, round, ceil, trunc, fract (one argument); min, max, atan2 (two)";

impl Tape {
    /// The named constants, as exmex spells them; they take precedence over
    /// a scope's names (so no variable may be called `e`).
    pub fn constant(name: &str) -> Option<f64> {
        use std::f64::consts::{E, PI, TAU};
        match name {
            "PI" | "π" => Some(PI),
            "E" | "e" => Some(E),
            "TAU" | "τ" => Some(TAU),
            _ => None,
        }
    }

    /// Compiles `expr`, finding each name's index in the value vector with
    /// `slot` (None: not a name of this formula's scope).
    pub fn compile(expr: &Expr, slot: &dyn Fn(&str) -> Option<usize>) -> Result<Tape> {
        let mut code = Vec::new();
        emit(&fold(expr), slot, &mut code)?;
        let depth = max_depth(&code);
        if depth > MAX_DEPTH {
            bail!("the formula nests {depth} deep; at most {MAX_DEPTH} levels are supported");
        }
        let code = fuse(&code);
        let root = closures::build(&code);
        Ok(Tape { code, root })
    }

    /// The value with the variables at `values`; NaN where it is undefined.
    #[inline]
    pub fn eval(&self, values: &[f64]) -> f64 {
        self.root.eval(values)
    }
}

/// Runs postfix `code` on a stack: the reference the closures are tested
/// against, and what folds constants while compiling.
fn run(code: &[Op], values: &[f64]) -> f64 {
    let mut stack = [0.0f64; MAX_DEPTH];
    let mut top = 0usize;
    for op in code {
        let x = &mut stack[top.max(1) - 1];
        match *op {
            Op::Const(c) => {
                stack[top] = c;
                top += 1;
            }
            Op::Var(i) => {
                stack[top] = values[i as usize];
                top += 1;
            }
            Op::Neg => *x = -*x,
            Op::Abs => *x = x.abs(),
            Op::Sqrt => *x = x.sqrt(),
            Op::Square => *x *= *x,
            Op::Cube => *x = *x * *x * *x,
            Op::PowI(n) => *x = x.powi(n),
            Op::F1(f) => *x = f(*x),
            Op::AddV(i) => *x += values[i as usize],
            Op::SubV(i) => *x -= values[i as usize],
            Op::MulV(i) => *x *= values[i as usize],
            Op::DivV(i) => *x /= values[i as usize],
            Op::AddC(c) => *x += c,
            Op::SubC(c) => *x -= c,
            Op::MulC(c) => *x *= c,
            Op::DivC(c) => *x /= c,
            Op::Add | Op::Sub | Op::Mul | Op::Div | Op::Pow | Op::F2(_) => {
                top -= 1;
                let (a, b) = (stack[top - 1], stack[top]);
                stack[top - 1] = match *op {
                    Op::Add => a + b,
                    Op::Sub => a - b,
                    Op::Mul => a * b,
                    Op::Div => a / b,
                    Op::Pow => a.powf(b),
                    Op::F2(f) => f(a, b),
                    _ => unreachable!("only two-operand operations reach here"),
                };
            }
        }
    }
    stack[0]
}

/// `expr` with every subexpression free of names replaced by its value.
fn fold(expr: &Expr) -> Expr {
    let folded = match expr {
        Expr::Number(_) | Expr::Name(_) => return expr.clone(),
        Expr::Neg(a) => Expr::Neg(Box::new(fold(a))),
        Expr::Binary(op, a, b) => Expr::Binary(*op, Box::new(fold(a)), Box::new(fold(b))),
        Expr::Call(f, args) => Expr::Call(f.clone(), args.iter().map(fold).collect()),
    };
    let constant_only = match &folded {
        Expr::Neg(a) => matches!(**a, Expr::Number(_)),
        Expr::Binary(_, a, b) => matches!((&**a, &**b), (Expr::Number(_), Expr::Number(_))),
        Expr::Call(_, args) => args.iter().all(|a| matches!(a, Expr::Number(_))),
        _ => false,
    };
    if constant_only {
        let mut code = Vec::new();
        if emit(&folded, &|_| None, &mut code).is_ok() {
            return Expr::Number(run(&code, &[]));
        }
    }
    folded
}

fn emit(expr: &Expr, slot: &dyn Fn(&str) -> Option<usize>, code: &mut Vec<Op>) -> Result<()> {
    match expr {
        Expr::Number(v) => code.push(Op::Const(*v)),
        Expr::Name(n) => match (Tape::constant(n), slot(n)) {
            (Some(c), _) => code.push(Op::Const(c)),
            (None, Some(i)) => code.push(Op::Var(i as u32)),
            (None, None) => bail!("unknown name '{n}'"),
        },
        Expr::Neg(a) => {
            emit(a, slot, code)?;
            code.push(Op::Neg);
        }
        Expr::Binary('^', a, b) => {
            emit(a, slot, code)?;
            match **b {
                Expr::Number(2.0) => code.push(Op::Square),
                Expr::Number(3.0) => code.push(Op::Cube),
                Expr::Number(n) if n.fract() == 0.0 && n.abs() <= 16.0 => code.push(Op::PowI(n as i32)),
                _ => {
                    emit(b, slot, code)?;
                    code.push(Op::Pow);
                }
            }
        }
        Expr::Binary(op, a, b) => {
            emit(a, slot, code)?;
            emit(b, slot, code)?;
            code.push(match op {
                '+' => Op::Add,
                '-' => Op::Sub,
                '*' => Op::Mul,
                _ => Op::Div,
            });
        }
        Expr::Call(f, args) => {
            for a in args {
                emit(a, slot, code)?;
            }
            match (args.len(), function1(f), function2(f)) {
                (1, Some(_), _) if f == "abs" => code.push(Op::Abs),
                (1, Some(_), _) if f == "sqrt" => code.push(Op::Sqrt),
                (1, Some(g), _) => code.push(Op::F1(g)),
                (2, _, Some(g)) => code.push(Op::F2(g)),
                (n, Some(_), _) => bail!("{f} takes one argument, not {n}"),
                (n, _, Some(_)) => bail!("{f} takes two arguments, not {n}"),
                _ => bail!("unknown function '{f}' (known: {FUNCTIONS})"),
            }
        }
    }
    Ok(())
}

/// `code` with each name or number that is at once the right operand of
/// `+ - * /` merged into that operation.
fn fuse(code: &[Op]) -> Vec<Op> {
    let mut out: Vec<Op> = Vec::with_capacity(code.len());
    for op in code {
        let merged = match (out.last(), op) {
            (Some(Op::Var(i)), Op::Add) => Some(Op::AddV(*i)),
            (Some(Op::Var(i)), Op::Sub) => Some(Op::SubV(*i)),
            (Some(Op::Var(i)), Op::Mul) => Some(Op::MulV(*i)),
            (Some(Op::Var(i)), Op::Div) => Some(Op::DivV(*i)),
            (Some(Op::Const(c)), Op::Add) => Some(Op::AddC(*c)),
            (Some(Op::Const(c)), Op::Sub) => Some(Op::SubC(*c)),
            (Some(Op::Const(c)), Op::Mul) => Some(Op::MulC(*c)),
            (Some(Op::Const(c)), Op::Div) => Some(Op::DivC(*c)),
            _ => None,
        };
        match merged {
            Some(m) => *out.last_mut().expect("merged with it") = m,
            None => out.push(*op),
        }
    }
    out
}

/// The deepest the stack gets while running `code` (before `fuse`).
fn max_depth(code: &[Op]) -> usize {
    let (mut depth, mut deepest) = (0usize, 0usize);
    for op in code {
        match op {
            Op::Const(_) | Op::Var(_) => depth += 1,
            Op::Add | Op::Sub | Op::Mul | Op::Div | Op::Pow | Op::F2(_) => depth -= 1,
            _ => {}
        }
        deepest = deepest.max(depth);
    }
    deepest
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The closures against the stack interpreter, to the bit, on formulas
    /// that use every kind of operation and leaf pairing, at random values
    /// (NaN taken equal to NaN).
    #[test]
    fn the_closures_compute_what_the_stack_computes() {
        let names = ["a", "b", "c", "x", "y"];
        let slot = |n: &str| names.iter().position(|m| *m == n);
        let formulas = [
            "b",
            "-x",
            "2.5",
            "a*x",
            "x*a + 3",
            "3 - x/a",
            "a/(b + c) - x*y*abs(y)",
            "-a^2*x",
            "sqrt(abs(x))*exp(-b*y) + sin(a*x + c)",
            "x^3 - 2*x^2 + x^-1",
            "a^b + max(x, y) - atan2(y, x)",
            "(a + b)*(c - x)/(y*y + 1)",
            "c*y - c*y/(1 + b*y)",
            "-(x)",
            "2/x",
            "x - 2",
            "PI*x",
            "(-x)*abs(y) + y^2/x - abs(a)",
            "x^2 - abs(y)*(-b) + (-c)/y^2",
            "exp(-x^2) + sqrt(-x) + abs(x - y)",
            "c + -a*x*abs(x)",
        ];
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
        for text in formulas {
            let tape = Tape::compile(&notation_parse(text), &slot).unwrap();
            for _ in 0..200 {
                let values: Vec<f64> = (0..names.len()).map(|_| rng.random_range(-3.0..3.0)).collect();
                let (got, want) = (tape.eval(&values), run(&tape.code, &values));
                assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{text}: {got} vs {want}");
            }
        }
    }

    fn notation_parse(text: &str) -> Expr {
        super::super::notation::parse(text).unwrap()
    }
}
