"""The prior over forms, learned from a corpus of physics equations (Guimera et al. 2020).

Counts each kind of operation in every formula of feynman_formulas.txt and gives
each kind o a cost in nats, alpha_o = ln((1 + m_o) / m_o), m_o its mean count
per equation: the maximum-likelihood rate of a geometric law for how many times
an equation uses o, so that a form's prior weight is prod_o exp(-alpha_o n_o).
A kind the corpus never uses gets half a count (m_o = 0.5 / N). Writes
src/engine/discover/operations.toml, which mdpipe reads; run from the
repository's root: python3 bench/prior/learn.py (needs sympy).

The kinds, counted the same way on mdpipe's formulas (engine::discover::prior):
+ (each sum of two terms; a difference too), * (each product of two factors,
a numeric factor included, a sign not), / (a quotient), pow2, pow3, sqrt,
pow (any other power), and each function by name. abs and signum are not
counted: they are conventions of sign (v*abs(v) is a square that keeps v's
sign), which the corpus, written for positive quantities, never needs.

One kind is a symbol's role, not an operation: "angle outside a trig
function", each use of a name outside sin, cos and tan in an equation that
uses it inside one (an angle or a phase written bare), its m the mean count
per such name. mdpipe charges it for each bare use, in a form, of a name its
model (or the form) uses inside a trig function.
"""
import math
import re
from collections import Counter
from pathlib import Path

import sympy as sp

FUNCTIONS = {sp.exp: "exp", sp.log: "log", sp.sin: "sin", sp.cos: "cos", sp.tan: "tan", sp.tanh: "tanh",
             sp.asin: "asin", sp.acos: "acos", sp.atan: "atan", sp.sinh: "sinh", sp.cosh: "cosh"}


FUNCTION_NAMES = {"exp", "log", "sin", "cos", "tan", "tanh", "asin", "acos", "atan", "sinh", "cosh", "sqrt"}


def power_kind(exponent):
    if exponent == 2:
        return "pow2"
    if exponent == 3:
        return "pow3"
    if exponent == sp.Rational(1, 2):
        return "sqrt"
    return "pow"


def count(e, out):
    if e.is_Atom:
        return
    if isinstance(e, sp.Add):
        out["+"] += len(e.args) - 1
    elif isinstance(e, sp.Mul):
        numeric = [a for a in e.args if a.is_Number]
        sign_only = len(numeric) == 1 and abs(numeric[0]) == 1
        factors = [a for a in e.args if not (sign_only and a.is_Number)]
        num = [a for a in factors if not (isinstance(a, sp.Pow) and a.exp.is_negative) and not (a.is_Rational and a.p == 1 and a.q != 1)]
        den = [a for a in factors if a not in num]
        out["*"] += max(len(num) - 1, 0) + max(len(den) - 1, 0)
        if den:
            out["/"] += 1
        for a in factors:
            if isinstance(a, sp.Pow) and a.exp.is_negative:
                if a.exp != -1:
                    out[power_kind(-a.exp)] += 1
                count(a.base, out)
            else:
                count(a, out)
        return
    elif isinstance(e, sp.Pow):
        if e.exp.is_negative:
            out["/"] += 1
            if e.exp != -1:
                out[power_kind(-e.exp)] += 1
        else:
            out[power_kind(e.exp)] += 1
    elif e.func in FUNCTIONS:
        out[FUNCTIONS[e.func]] += 1
    elif isinstance(e, (sp.Abs, sp.sign)):
        pass
    else:
        raise ValueError(f"an operation this prior does not know: {e.func}")
    for a in e.args:
        count(a, out)


TRIG = (sp.sin, sp.cos, sp.tan)


def angle_uses(e):
    """(names e uses inside sin, cos or tan; their uses outside any)."""
    inside = set()
    for call in e.atoms(*TRIG):
        inside |= call.free_symbols
    bare = e.replace(lambda a: isinstance(a, TRIG), lambda a: sp.Symbol("TRIG_CALL"))
    uses = sum(1 for node in sp.preorder_traversal(bare) if node in inside)
    return len(inside), uses


def parse(formula):
    """A formula with every name a symbol (gamma, beta, E_n are variables here), pi the number."""
    names = set(re.findall(r"[A-Za-z_][A-Za-z_0-9]*", formula)) - {f for f in dir(sp) if f in FUNCTION_NAMES} - {"pi"}
    return sp.sympify(formula, locals={n: sp.Symbol(n) for n in names})


def main():
    here = Path(__file__).parent
    lines = [l.strip() for l in (here / "feynman_formulas.txt").read_text().splitlines()]
    formulas = [l for l in lines if l and not l.startswith("#")]
    totals = Counter()
    for f in formulas:
        c = Counter()
        count(parse(f), c)
        totals.update(c)
    n = len(formulas)
    kinds = ["+", "*", "/", "pow2", "pow3", "sqrt", "pow"] + sorted(set(FUNCTIONS.values()))
    out = ["# The prior over forms: nats each operation of a form costs, learned from",
           f"# {n} physics equations (bench/prior/feynman_formulas.txt) by bench/prior/learn.py:",
           "# alpha = ln((1 + m) / m), m the mean count per equation (0.5 / N when never used).",
           "# Regenerate with `python3 bench/prior/learn.py`; do not edit by hand.", "[nats]"]
    for k in kinds:
        m = totals[k] / n if totals[k] else 0.5 / n
        out.append(f'"{k}" = {math.log((1 + m) / m):.3f}  # {totals[k]} in {n} equations')
    angles, bare = (sum(x) for x in zip(*(angle_uses(parse(f)) for f in formulas)))
    m = bare / angles if bare else 0.5 / angles
    out.append(f'"angle outside a trig function" = {math.log((1 + m) / m):.3f}  # {bare} uses of the {angles} names '
               "an equation uses inside sin, cos or tan")
    target = here.parent.parent / "src" / "engine" / "discover" / "operations.toml"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
