"""The ODEBench protocol "a term left out" as test cases (../shared/odebench/README.md).

Reads the odd-id ODEBench systems (d'Ascoli et al., ICLR 2024) and writes
tests/fixtures/odebench/cases.json: for every rate with two or more additive
terms (multiplied out as sympy.expand does, functions left whole), one case
per term removed, and one null per system (nothing removed). Each case holds
the user's model (the system without the term; the constants that remain
are parameters with priors [c/2, 2c], sign kept; the initial values known),
the data (the full system from its first initial condition, integrated here
by SciPy's DOP853 at rtol 1e-11, observed at t = 0.25, 0.5, ..., 10, every
state with Gaussian noise of 1% of its range plus 1e-3, a seed of its own),
and the second initial condition's trajectory with the true rates along it,
where a repaired model is judged. The data come from SciPy, never from
mdpipe.

Run from the repository's root:
    python3 bench/odebench/make_cases.py ../shared/odebench/systems.json
or, for other systems in the same format, into another fixture (run.py --fixture):
    python3 bench/odebench/make_cases.py bench/odebench/textbook_systems.json /tmp/textbook_cases.json
(needs numpy, scipy and sympy; only the fixture it writes is used by the tests).
"""
import json
import sys
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

TIMES = np.arange(1, 41) * 0.25
JUDGE_TIMES = np.linspace(0.0, 10.0, 101)
DIVERGED = 1e6
MAX_EVALUATIONS = 400_000


def symbols(system):
    dim = system["dim"]
    xs = [sp.Symbol(f"x_{i}") for i in range(dim)]
    cs = [sp.Symbol(f"c_{i}") for i in range(len(system["constants"]))]
    names = {str(s): s for s in xs + cs}
    names["cot"] = sp.cot
    return xs, cs, names


def mdpipe_text(expr):
    """A sympy expression in mdpipe's (and exmex's) notation."""
    return sp.sstr(expr, order="none").replace("**", "^").replace("pi", "PI").replace("Abs(", "abs(")


def rounded(values):
    """Numbers to 12 significant digits, far below the noise, for a smaller file."""
    return np.vectorize(lambda v: float(f"{v:.12g}"))(np.asarray(values, dtype=float)).tolist()


def term_class(term, xs):
    """The protocol's classes: polynomial, rational or saturating, transcendental, products across states."""
    if term.atoms(sp.Function):
        return "transcendental"
    _, den = sp.fraction(sp.together(term))
    if den.free_symbols & set(xs):
        return "rational or saturating"
    if len(term.free_symbols & set(xs)) >= 2:
        return "products across states"
    return "polynomial"


class TooLong(Exception):
    pass


def integrate(rates_fn, y0, t_eval):
    """The trajectory at t_eval, or None where it diverges, fails or needs more
    than MAX_EVALUATIONS rate evaluations (a blow-up the steps chase)."""
    count = [0]

    def counted(t, y):
        count[0] += 1
        if count[0] > MAX_EVALUATIONS:
            raise TooLong()
        return rates_fn(t, y)

    def blown(t, y):
        return DIVERGED - np.abs(y).max()

    blown.terminal = True
    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(counted, (0.0, float(t_eval[-1])), y0, t_eval=t_eval, method="DOP853", rtol=1e-11, atol=1e-12, events=blown)
    except (TooLong, OverflowError, ZeroDivisionError, ValueError):
        return None
    if not sol.success or sol.y.shape[1] != len(t_eval) or not np.all(np.isfinite(sol.y)) or np.abs(sol.y).max() > DIVERGED:
        return None
    return sol.y


def lambdas(rates, xs):
    fs = [sp.lambdify(xs, r, "numpy") for r in rates]

    def rhs(t, y):
        return [float(f(*y)) for f in fs]

    return fs, rhs


def prior(value):
    lo, hi = sorted([0.5 * value, 2.0 * value])
    return {"min": lo, "max": hi}


def case(system, k, removed, rates, xs, cs, values, rng, data_full, judge_full):
    """One case: rate k without `removed` (None: the null)."""
    model_rates = list(rates)
    if removed is not None:
        model_rates[k] = sp.expand(rates[k]) - removed
    used = sorted({str(c) for r in model_rates for c in r.free_symbols if c in cs}, key=lambda n: int(n[2:]))
    sigma = 0.01 * (data_full.max(axis=1) - data_full.min(axis=1)) + 1e-3
    noisy = data_full + sigma[:, None] * rng.standard_normal(data_full.shape)
    true_at = {str(c): v for c, v in zip(cs, values)}
    true_rates = [r.subs(true_at) for r in rates]
    fs, _ = lambdas(true_rates, xs)
    judge_rates = [np.broadcast_to(np.asarray(f(*judge_full), dtype=float), JUDGE_TIMES.shape).tolist() for f in fs]
    size = None
    if removed is not None:
        without = [r.subs(true_at) for r in model_rates]
        _, rhs = lambdas(without, xs)
        y = integrate(rhs, system["initial"][0], TIMES)
        # A model that cannot be integrated to t = 10 (None) misses the data by more than any 5σ.
        size = None if y is None else float(np.max(np.abs(y - data_full) / sigma[:, None]))
    return {
        "id": system["id"],
        "system": system["name"],
        "rate": k,
        "removed": None if removed is None else mdpipe_text(removed),
        "class": None if removed is None else term_class(removed, xs),
        "states": [str(x) for x in xs],
        "initial": system["initial"][0],
        "model_rates": [mdpipe_text(r) for r in model_rates],
        "parameters": {n: dict(prior(true_at[n]), truth=true_at[n]) for n in used},
        "true_rates": [mdpipe_text(r) for r in true_rates],
        "size_sigma": size,
        "data": {
            "t": TIMES.tolist(),
            "values": rounded(noisy),
            "errors": rounded(sigma),
        },
        "judge": {"t": JUDGE_TIMES.tolist(), "states": rounded(judge_full), "rates": rounded(judge_rates)},
    }


def main(path, out):
    systems = json.loads(Path(path).read_text())
    cases, nulls, left_out = [], [], []
    for s in systems:
        xs, cs, names = symbols(s)
        rates = [sp.sympify(r.replace("^", "**"), locals=names) for r in s["rates"]]
        # mdpipe has no cot: cos/sin, as a user would write it.
        rates = [r.replace(sp.cot, lambda a: sp.cos(a) / sp.sin(a)) for r in rates]
        values = s["constants"]
        true = [r.subs({c: v for c, v in zip(cs, values)}) for r in rates]
        _, rhs = lambdas(true, xs)
        data_full = integrate(rhs, s["initial"][0], TIMES)
        judge_full = integrate(rhs, s["initial"][1], JUDGE_TIMES)
        if data_full is None or judge_full is None:
            left_out.append({"id": s["id"], "why": "diverges or fails on [0, 10]"})
            continue
        seed = 1000 * s["id"]
        nulls.append(case(s, 0, None, rates, xs, cs, values, np.random.default_rng(seed), data_full, judge_full))
        for k, r in enumerate(rates):
            terms = sp.Add.make_args(sp.expand(r))
            if len(terms) < 2:
                continue
            for j, t in enumerate(terms):
                c = case(s, k, t, rates, xs, cs, values, np.random.default_rng(seed + 10 * k + j + 1), data_full, judge_full)
                if c["size_sigma"] is not None and c["size_sigma"] < 5.0:
                    left_out.append({"id": s["id"], "removed": c["removed"], "why": f"changes no observable by 5 sigma ({c['size_sigma']:.1f})"})
                    continue
                cases.append(c)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(allow_nan=False, obj={"source": "ODEBench odd ids (../shared/odebench/systems.json)" if str(path).endswith("odebench/systems.json") else str(path), "cases": cases, "nulls": nulls, "left_out": left_out}, indent=None))
    by_class = {}
    for c in cases:
        by_class[c["class"]] = by_class.get(c["class"], 0) + 1
    print(f"{len(cases)} cases {by_class}, {len(nulls)} nulls, {len(left_out)} left out -> {out}")
    for l in left_out:
        print("  left out:", l)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "../shared/odebench/systems.json",
         sys.argv[2] if len(sys.argv) > 2 else "tests/fixtures/odebench/cases.json")
