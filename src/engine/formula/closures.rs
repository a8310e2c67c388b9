//! A compiled tape turned into a tree of closures, one per operation, with
//! names, numbers and cheap functions of a name (`-v`, `abs(v)`, `v^2`)
//! folded into the operation that reads them: `bb*v` is one closure reading
//! two slots, not three stack operations, and `-k*v*abs(v)` is two closures,
//! not four.
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

/// A subexpression while the tree is built: leaves (a name, a number, or
/// the sign, magnitude or square of a name) stay leaves, so that the node
/// reading them reads them in place instead of calling a closure.
#[derive(Clone)]
pub enum Built {
    Var(usize),
    Const(f64),
    OfVar(Cheap, usize),
    Node(Node),
}

/// A one-operand operation cheap enough to redo in every node that reads
/// it: `-v`, `abs(v)` and `v^2` of a name are leaves, not nodes.
#[derive(Clone, Copy)]
pub enum Cheap {
    Neg,
    Abs,
    Square,
}

impl Cheap {
    #[inline(always)]
    fn apply(self, x: f64) -> f64 {
        match self {
            Cheap::Neg => -x,
            Cheap::Abs => x.abs(),
            Cheap::Square => x * x,
        }
    }
}

impl Built {
    /// The value at `values`.
    #[inline]
    pub fn eval(&self, values: &[f64]) -> f64 {
        match self {
            Built::Var(i) => values[*i],
            Built::Const(c) => *c,
            Built::OfVar(op, i) => op.apply(values[*i]),
            Built::Node(f) => f(values),
        }
    }

    fn into_node(self) -> Node {
        match self {
            Built::Node(f) => f,
            leaf => Arc::new(move |v: &[f64]| leaf.eval(v)),
        }
    }
}

fn node(f: impl Fn(&[f64]) -> f64 + Send + Sync + 'static) -> Built {
    Built::Node(Arc::new(f))
}

/// How a node reads one operand, known by type so that reading a leaf
/// inlines and only a node operand costs a call.
trait Read: Send + Sync + 'static {
    fn read(&self, v: &[f64]) -> f64;
}

macro_rules! reader {
    ($name:ident, $field:ty, |$s:ident, $v:ident| $e:expr) => {
        struct $name($field);
        impl Read for $name {
            #[inline(always)]
            fn read(&self, $v: &[f64]) -> f64 {
                let $s = self;
                $e
            }
        }
    };
}
reader!(ReadVar, usize, |s, v| v[s.0]);
reader!(ReadConst, f64, |s, _v| s.0);
reader!(ReadNeg, usize, |s, v| -v[s.0]);
reader!(ReadAbs, usize, |s, v| v[s.0].abs());
reader!(ReadSquare, usize, |s, v| v[s.0] * v[s.0]);
reader!(ReadNode, Node, |s, v| (s.0)(v));

/// Runs `$body` with `$r` bound to the reader of `$built`, one
/// monomorphized copy per kind of operand.
macro_rules! with_reader {
    ($built:expr, |$r:ident| $body:expr) => {
        match $built {
            Built::Var(i) => {
                let $r = ReadVar(i);
                $body
            }
            Built::Const(c) => {
                let $r = ReadConst(c);
                $body
            }
            Built::OfVar(Cheap::Neg, i) => {
                let $r = ReadNeg(i);
                $body
            }
            Built::OfVar(Cheap::Abs, i) => {
                let $r = ReadAbs(i);
                $body
            }
            Built::OfVar(Cheap::Square, i) => {
                let $r = ReadSquare(i);
                $body
            }
            Built::Node(f) => {
                let $r = ReadNode(f);
                $body
            }
        }
    };
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
    with_reader!(a, |ra| with_reader!(b, |rb| node(move |v| A::apply(ra.read(v), rb.read(v)))))
}

/// A cheap operation of a name is a leaf; of anything else, a node.
fn cheap(a: Built, op: Cheap) -> Built {
    match a {
        Built::Var(i) => Built::OfVar(op, i),
        other => unary(other, move |x| op.apply(x)),
    }
}

/// `op(a)`, reading a leaf in place.
fn unary(a: Built, op: impl Fn(f64) -> f64 + Send + Sync + Copy + 'static) -> Built {
    with_reader!(a, |ra| node(move |v| op(ra.read(v))))
}

/// The tree of a tape (postfix, as `Tape::compile` leaves it).
pub fn build(code: &[Op]) -> Built {
    let mut stack: Vec<Built> = Vec::new();
    let pop = |stack: &mut Vec<Built>| stack.pop().expect("a well-formed tape");
    for op in code {
        let built = match *op {
            Op::Const(c) => Built::Const(c),
            Op::Var(i) => Built::Var(i as usize),
            Op::Neg => cheap(pop(&mut stack), Cheap::Neg),
            Op::Abs => cheap(pop(&mut stack), Cheap::Abs),
            Op::Sqrt => unary(pop(&mut stack), f64::sqrt),
            Op::Square => cheap(pop(&mut stack), Cheap::Square),
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
