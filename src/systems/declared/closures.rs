//! A compiled tape turned into a tree of closures, one per operation, with
//! names and numbers folded into the operation that reads them: `bb*v` is
//! one closure reading two slots, not three stack operations.
//!
//! Why: a stack interpreter's one indirect jump per operation is where an
//! ODE's right-hand side spent its time (the jump mispredicts; measured with
//! perf on the ball drop with quadratic drag, 46% of a likelihood
//! evaluation). A closure per node calls its children directly by type and
//! leaves the branch predictor one call per node. The arithmetic, and its
//! order, are the tape's; `tests` checks the two agree to the bit.

use super::ops::Op;
use std::sync::Arc;

/// A compiled node: the value of a subexpression at the value vector.
pub type Node = Arc<dyn Fn(&[f64]) -> f64 + Send + Sync>;

/// A subexpression while the tree is built: leaves stay leaves so that the
/// node reading them can read them in place.
#[derive(Clone)]
pub enum Built {
    Var(usize),
    Const(f64),
    Node(Node),
}

impl Built {
    /// The value at `values`.
    #[inline]
    pub fn eval(&self, values: &[f64]) -> f64 {
        match self {
            Built::Var(i) => values[*i],
            Built::Const(c) => *c,
            Built::Node(f) => f(values),
        }
    }

    fn into_node(self) -> Node {
        match self {
            Built::Var(i) => Arc::new(move |v: &[f64]| v[i]),
            Built::Const(c) => Arc::new(move |_: &[f64]| c),
            Built::Node(f) => f,
        }
    }
}

fn node(f: impl Fn(&[f64]) -> f64 + Send + Sync + 'static) -> Built {
    Built::Node(Arc::new(f))
}

/// One arithmetic operation, known by type so that it inlines.
trait Arith: Send + Sync + 'static {
    fn apply(a: f64, b: f64) -> f64;
}

macro_rules! arith {
    ($name:ident, $a:ident, $b:ident, $e:expr) => {
        struct $name;
        impl Arith for $name {
            #[inline(always)]
            fn apply($a: f64, $b: f64) -> f64 {
                $e
            }
        }
    };
}
arith!(Plus, a, b, a + b);
arith!(Minus, a, b, a - b);
arith!(Times, a, b, a * b);
arith!(Over, a, b, a / b);

/// `a op b` with each operand read in place when it is a leaf.
fn binary<A: Arith>(a: Built, b: Built) -> Built {
    use Built::{Const, Node, Var};
    match (a, b) {
        (Var(i), Var(j)) => node(move |v| A::apply(v[i], v[j])),
        (Var(i), Const(c)) => node(move |v| A::apply(v[i], c)),
        (Const(c), Var(j)) => node(move |v| A::apply(c, v[j])),
        (Const(c), Const(d)) => node(move |_| A::apply(c, d)),
        (Node(f), Var(j)) => node(move |v| A::apply(f(v), v[j])),
        (Node(f), Const(c)) => node(move |v| A::apply(f(v), c)),
        (Var(i), Node(g)) => node(move |v| A::apply(v[i], g(v))),
        (Const(c), Node(g)) => node(move |v| A::apply(c, g(v))),
        (Node(f), Node(g)) => node(move |v| A::apply(f(v), g(v))),
    }
}

/// `op(a)`, reading a leaf in place.
fn unary(a: Built, op: impl Fn(f64) -> f64 + Send + Sync + Copy + 'static) -> Built {
    match a {
        Built::Var(i) => node(move |v| op(v[i])),
        Built::Const(c) => node(move |_| op(c)),
        Built::Node(f) => node(move |v| op(f(v))),
    }
}

/// The tree of a tape (postfix, as `Tape::compile` leaves it).
pub fn build(code: &[Op]) -> Built {
    let mut stack: Vec<Built> = Vec::new();
    let pop = |stack: &mut Vec<Built>| stack.pop().expect("a well-formed tape");
    for op in code {
        let built = match *op {
            Op::Const(c) => Built::Const(c),
            Op::Var(i) => Built::Var(i as usize),
            Op::Neg => unary(pop(&mut stack), |x| -x),
            Op::Abs => unary(pop(&mut stack), f64::abs),
            Op::Sqrt => unary(pop(&mut stack), f64::sqrt),
            Op::Square => unary(pop(&mut stack), |x| x * x),
            Op::Cube => unary(pop(&mut stack), |x| x * x * x),
            Op::PowI(n) => unary(pop(&mut stack), move |x| x.powi(n)),
            Op::F1(f) => unary(pop(&mut stack), f),
            Op::AddV(i) => binary::<Plus>(pop(&mut stack), Built::Var(i as usize)),
            Op::SubV(i) => binary::<Minus>(pop(&mut stack), Built::Var(i as usize)),
            Op::MulV(i) => binary::<Times>(pop(&mut stack), Built::Var(i as usize)),
            Op::DivV(i) => binary::<Over>(pop(&mut stack), Built::Var(i as usize)),
            Op::AddC(c) => binary::<Plus>(pop(&mut stack), Built::Const(c)),
            Op::SubC(c) => binary::<Minus>(pop(&mut stack), Built::Const(c)),
            Op::MulC(c) => binary::<Times>(pop(&mut stack), Built::Const(c)),
            Op::DivC(c) => binary::<Over>(pop(&mut stack), Built::Const(c)),
            Op::Add | Op::Sub | Op::Mul | Op::Div | Op::Pow | Op::F2(_) => {
                let b = pop(&mut stack);
                let a = pop(&mut stack);
                match *op {
                    Op::Add => binary::<Plus>(a, b),
                    Op::Sub => binary::<Minus>(a, b),
                    Op::Mul => binary::<Times>(a, b),
                    Op::Div => binary::<Over>(a, b),
                    Op::Pow => {
                        let (f, g) = (a.into_node(), b.into_node());
                        node(move |v| f(v).powf(g(v)))
                    }
                    Op::F2(h) => {
                        let (f, g) = (a.into_node(), b.into_node());
                        node(move |v| h(f(v), g(v)))
                    }
                    _ => unreachable!("only two-operand operations reach here"),
                }
            }
        };
        stack.push(built);
    }
    pop(&mut stack)
}
