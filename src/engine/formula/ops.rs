//! The operations a compiled formula is made of, in postfix order: what
//! `tape` compiles a formula to, runs on a stack, and `closures` turns into
//! a tree.

/// One operation on the stack. `AddV(i)` is `Var(i), Add` in one step and
/// `AddC(c)` is `Const(c), Add` (likewise for the other three operators):
/// the same arithmetic in the same order, in half the dispatches.
#[derive(Clone, Copy, Debug)]
pub enum Op {
    Const(f64),
    Var(u32),
    Neg,
    Abs,
    Sqrt,
    Add,
    Sub,
    Mul,
    Div,
    AddV(u32),
    SubV(u32),
    MulV(u32),
    DivV(u32),
    AddC(f64),
    SubC(f64),
    MulC(f64),
    DivC(f64),
    Pow,
    Square,
    Cube,
    PowI(i32),
    F1(fn(f64) -> f64),
    F2(fn(f64, f64) -> f64),
}
