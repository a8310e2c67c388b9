"""The ODEBench protocol "a term left out", mdpipe and PySINDy side by side.

For each case of tests/fixtures/odebench/cases.json (made by make_cases.py
from the odd-id systems of ../shared/odebench/): writes the user's model
(a declared ODE with no candidates) and data into a folder, runs
`mdpipe diagnose model.toml --seed 1 --out diag` there as a user would
(first verdicts: the data as given; `--no-repair`, the verdict only), and gives PySINDy the same data
(polynomials to degree 3, smoothed finite differences, thresholds chosen by
AICc). Both are judged by the protocol (../shared/odebench/README.md): a
law whose repaired rates, at the posterior medians (PySINDy: its
coefficients), are within 10% relative RMS of the true rates along the
trajectory from the second initial condition, which no fit saw, on every
rate. Prints each case and the counts with 95% Clopper-Pearson intervals,
by class; writes results.json.

    python3 bench/odebench/run.py --mdpipe target/release/mdpipe --out /tmp/odebench [--cases 0,5,7] [--nulls] [--sindy]
    python3 bench/odebench/run.py --out /tmp/odebench --rejudge   # the verdicts left there, judged again

A decisive verdict is right or wrong; `ambiguous` is never counted wrong (it
is not decisive): it is honest when a form it leaves standing has the right
rates. A run that timed out or failed is counted apart.

Needs numpy, scipy and sympy (and pysindy for --sindy), from the package
index, never in the build.
"""
import argparse
import json
import math
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.stats import beta

HERE = Path(__file__).resolve().parent
FIXTURE = HERE.parent.parent / "tests" / "fixtures" / "odebench" / "cases.json"
TOLERANCE = 0.10
# "wrong" is decisive and wrong only; an `ambiguous` verdict is not decisive,
# so it is never counted there, whatever form leads it.
LABELS = ["right", "ambiguous, right form standing", "ambiguous, no standing form right", "unexplained", "none",
          "timed out or failed", "wrong"]


def clopper_pearson(k, n):
    lo = 0.0 if k == 0 else beta.ppf(0.025, k, n - k + 1)
    hi = 1.0 if k == n else beta.ppf(0.975, k + 1, n - k)
    return lo, hi


SAMPLER = ""


def write_case(case, folder):
    folder.mkdir(parents=True, exist_ok=True)
    states = case["states"]
    lines = [f'name = "odebench_{case["id"]}"', "[model]", 'kind = "ode"', "t0 = 0.0"]
    lines.append("initial = { " + ", ".join(f'{s} = "{v!r}"' for s, v in zip(states, case["initial"])) + " }")
    lines.append("rates = { " + ", ".join(f'{s} = "{r}"' for s, r in zip(states, case["model_rates"])) + " }")
    lines.append("observables = { " + ", ".join(f'{s} = "{s}"' for s in states) + " }")
    lines += ["[data]", 'measurements = "data.csv"']
    for name, p in case["parameters"].items():
        lines += [f"[parameters.{name}]", f"min = {p['min']!r}", f"max = {p['max']!r}"]
    lines += ["[discrepancy]", 'kernel = "II"']
    if SAMPLER:
        lines += ["[sampler.smc]", SAMPLER]
    (folder / "model.toml").write_text("\n".join(lines) + "\n")
    rows = ["observable,x,value,error"]
    for k, s in enumerate(states):
        for t, v in zip(case["data"]["t"], case["data"]["values"][k]):
            rows.append(f"{s},{t!r},{v!r},{case['data']['errors'][k]!r}")
    (folder / "data.csv").write_text("\n".join(rows) + "\n")


def symbols_of(case):
    return {s: sp.Symbol(s) for s in case["states"]}


def rates_close(case, rates):
    """Whether sympy rates (states free, every constant in) are within the tolerance on every rate."""
    xs = [sp.Symbol(s) for s in case["states"]]
    judge = np.asarray(case["judge"]["states"], dtype=float)
    if any(sp.sympify(r).free_symbols - set(xs) for r in rates):
        return False, math.inf  # a constant the verdict did not estimate: no law to judge
    worst = 0.0
    for k, r in enumerate(rates):
        f = sp.lambdify(xs, r, "numpy")
        with np.errstate(all="ignore"):
            got = np.broadcast_to(np.asarray(f(*judge), dtype=float), judge.shape[1:])
        want = np.asarray(case["judge"]["rates"][k], dtype=float)
        rms = math.sqrt(np.mean((got - want) ** 2)) / max(math.sqrt(np.mean(want ** 2)), 1e-12)
        worst = max(worst, rms if np.isfinite(rms) else math.inf)
    return worst <= TOLERANCE, worst


def parse(text, names):
    return sp.sympify(text.replace("^", "**"), locals=names)


def repaired_rates(case, diagnosis, name):
    """The model's rates with the candidate `name` in, at its posterior medians; None if not a rate law."""
    candidate = next((c for c in diagnosis["candidates"] if c["name"] == name), None)
    screened = next((s for s in (diagnosis.get("discovery") or {}).get("screened", []) if s["name"] == name), None)
    if candidate is None or screened is None:
        return None
    table = tomllib.loads(screened["toml"])["candidates"][0]
    medians = {n: p["median"] for n, p in candidate["parameters"].items()}
    names = symbols_of(case) | {n: sp.Symbol(n) for n in medians} | {"PI": sp.pi, "abs": sp.Abs}
    rates = [parse(r, names) for r in case["model_rates"]]
    for k, s in enumerate(case["states"]):
        if s in table.get("rates", {}):
            rates[k] = rates[k] + parse(table["rates"][s], names)
    for p, text in table.get("vary", {}).items():
        rates = [r.subs(sp.Symbol(p), parse(text, names)) for r in rates]
    return [r.subs({sp.Symbol(n): v for n, v in medians.items()}) for r in rates]


def judge_mdpipe(case, diagnosis):
    best = diagnosis["verdict"]["best"]
    if best in ("unexplained", "none", "emulator_limited"):
        return best if best != "emulator_limited" else "unexplained", None
    if best == "ambiguous":
        standing = diagnosis["verdict"].get("standing") or []
        right = [s for s in standing if (rates := repaired_rates(case, diagnosis, s)) is not None and rates_close(case, rates)[0]]
        if right:
            return "ambiguous, right form standing", f"{right[0]} (of {', '.join(standing)})"
        return "ambiguous, no standing form right", ", ".join(standing)
    rates = repaired_rates(case, diagnosis, best)
    if rates is None:
        return "wrong", best
    ok, worst = rates_close(case, rates)
    return ("right" if ok else "wrong"), f"{best} (worst rms {worst:.3f})"


def judge_folder(case, folder):
    """The verdict in `folder`'s diag/diagnosis.json, judged; a folder without one timed out or failed."""
    path = folder / "diag" / "diagnosis.json"
    if not path.exists():
        return "timed out or failed", None
    return judge_mdpipe(case, json.loads(path.read_text()))


def run_mdpipe(case, folder, binary, timeout):
    write_case(case, folder)
    start = time.time()
    try:
        done = subprocess.run([binary, "diagnose", "model.toml", "--seed", "1", "--no-repair", "--out", "diag"], cwd=folder,
                              capture_output=True, text=True, timeout=timeout)
        ok = done.returncode == 0
    except subprocess.TimeoutExpired:
        ok = False
    seconds = time.time() - start
    if not ok:
        return "timed out or failed", "failed or timed out", seconds
    verdict, what = judge_folder(case, folder)
    return verdict, what, seconds


def run_sindy(case):
    """PySINDy on the same data: polynomials to degree 3, smoothed finite differences, AICc over thresholds."""
    import pysindy as ps

    t = np.asarray(case["data"]["t"], dtype=float)
    x = np.asarray(case["data"]["values"], dtype=float).T
    best = None
    xdot = ps.SmoothedFiniteDifference()(x, t=t)
    for threshold in [0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0]:
        model = ps.SINDy(optimizer=ps.STLSQ(threshold=threshold), feature_library=ps.PolynomialLibrary(degree=3))
        try:
            model.fit(x, t=t, x_dot=xdot)
        except Exception:
            continue
        residual = xdot - model.predict(x)
        n = residual.size
        k = int(np.count_nonzero(model.coefficients()))
        rss = float(np.sum(residual ** 2))
        aicc = n * math.log(max(rss / n, 1e-300)) + 2 * k + (2 * k * (k + 1)) / max(n - k - 1, 1)
        if best is None or aicc < best[0]:
            best = (aicc, model)
    if best is None:
        return "wrong", "no fit"
    model = best[1]
    names = [sp.Symbol(s) for s in case["states"]]
    features = [parse(f.replace(" ", "*"), {f"x{i}": names[i] for i in range(len(names))})
                for f in model.get_feature_names()]
    rates = [sum(c * f for c, f in zip(row, features)) for row in model.coefficients()]
    ok, worst = rates_close(case, rates)
    if ok:
        return "right", f"worst rms {worst:.3f}"
    # Approximate: every rate within 50%.
    return ("approximate" if worst <= 0.5 else "wrong"), f"worst rms {worst:.3f}"


def summary(label, results, key):
    n = len(results)
    print(f"\n{label}: {n} cases")
    kinds = sorted({r[key] for r in results}, key=lambda k: (LABELS + ["approximate"]).index(k) if k in LABELS + ["approximate"] else 99)
    for kind in kinds:
        k = sum(1 for r in results if r[key] == kind)
        lo, hi = clopper_pearson(k, n)
        print(f"  {kind:34s} {k:3d} of {n}  95% [{100 * lo:.0f}%, {100 * hi:.0f}%]")
    for cls in sorted({r["class"] for r in results if r["class"]}):
        sub = [r for r in results if r["class"] == cls]
        k = sum(1 for r in sub if r[key] == "right")
        lo, hi = clopper_pearson(k, len(sub))
        print(f"    {cls:30s} right {k} of {len(sub)}  95% [{100 * lo:.0f}%, {100 * hi:.0f}%]")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mdpipe", default="target/release/mdpipe")
    ap.add_argument("--out", default="/tmp/odebench")
    ap.add_argument("--cases", default="")
    ap.add_argument("--nulls", action="store_true", help="the nulls: each system as it is, the search forced on")
    ap.add_argument("--sindy", action="store_true")
    ap.add_argument("--no-mdpipe", action="store_true")
    ap.add_argument("--rejudge", action="store_true",
                    help="judge the verdicts an earlier run left in --out again, without running mdpipe (its seconds kept)")
    ap.add_argument("--timeout", type=float, default=900)
    ap.add_argument("--fixture", default=str(FIXTURE),
                    help="cases made by make_cases.py from other systems (default: the ODEBench odd ids)")
    ap.add_argument("--sampler", default="", help="e.g. 'particles = 500' for a quicker look, not the protocol's measure")
    args = ap.parse_args()
    global SAMPLER
    SAMPLER = args.sampler
    fixture = json.loads(Path(args.fixture).read_text())
    cases = fixture["nulls"] if args.nulls else fixture["cases"]
    earlier = Path(args.out) / "results.json"
    seconds_before = {r["index"]: r.get("seconds") for r in json.loads(earlier.read_text())} if earlier.exists() else {}
    # Judged again, the cases are those the earlier run held unless named.
    every = sorted(seconds_before) if args.rejudge else range(len(cases))
    chosen = [int(i) for i in args.cases.split(",") if i] or every
    binary = str(Path(args.mdpipe).resolve())
    results = []
    for i in chosen:
        case = cases[i]
        row = {"index": i, "id": case["id"], "removed": case["removed"], "class": case["class"]}
        if not args.no_mdpipe:
            folder = Path(args.out) / ("null_%d" % i if args.nulls else "case_%d" % i)
            if args.nulls:
                write_case(case, folder)
                start = time.time()
                try:
                    subprocess.run([binary, "diagnose", "model.toml", "--seed", "1", "--discover", "--no-repair", "--out", "diag"],
                                   cwd=folder, capture_output=True, text=True, timeout=args.timeout)
                    d = json.loads((folder / "diag" / "diagnosis.json").read_text())
                    found = any(c["name"] == d["verdict"]["best"] and c["prior_log_odds"] < 0 for c in d["candidates"])
                    row.update(mdpipe="discovered" if found else "clean", what=d["verdict"]["best"])
                except (subprocess.TimeoutExpired, FileNotFoundError) as e:
                    # A null that times out or fails discovered nothing, but is no clean answer either.
                    row.update(mdpipe="failed or timed out", what=type(e).__name__)
                row["seconds"] = time.time() - start
            elif args.rejudge:
                verdict, what = judge_folder(case, folder)
                row.update(mdpipe=verdict, what=what, seconds=seconds_before.get(i))
            else:
                verdict, what, seconds = run_mdpipe(case, folder, binary, args.timeout)
                row.update(mdpipe=verdict, what=what, seconds=seconds)
        if args.sindy and not args.nulls:
            row["sindy"], row["sindy_what"] = run_sindy(case)
        results.append(row)
        print(json.dumps(row), flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / ("nulls.json" if args.nulls else "results.json")).write_text(json.dumps(results, indent=1))
    if not args.no_mdpipe:
        summary("mdpipe", results, "mdpipe")
        times = sorted(r["seconds"] for r in results if r.get("seconds") is not None)
        if times:
            print(f"  diagnose wall time: median {times[len(times) // 2]:.1f} s, max {times[-1]:.1f} s")
    if args.sindy and not args.nulls:
        summary("PySINDy", results, "sindy")


if __name__ == "__main__":
    sys.exit(main())
