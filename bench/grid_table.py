"""Prints the README's table for a 3x3 grid run by bench/*_grid.sh.

    python3 bench/grid_table.py OUT_DIR

reads OUT_DIR/set{0,1,2}_{none,I,II}/summary.json (one `mdpipe calibrate` per
case). Each interval is the 95% one; a cross marks an interval that excludes the
parameter's true value (eta/s = 0.1, e_sw = 0.2), with (median - truth)/sd.
"""
import json
import os
import sys

TRUTH = {"eta_s": 0.1, "e_sw": 0.2}
SETS = ["CH spectra", "+ CH v2, v3", "all 7"]


def cell(p, name):
    q = p[name]
    text = f"{q['median']:.3f} [{q['q025']:.3f}, {q['q975']:.3f}]"
    if not q["q025"] <= TRUTH[name] <= q["q975"]:
        text += f" ✗ ({(q['median'] - TRUTH[name]) / q['sd']:+.1f})"
    return text


def main(out):
    print("| observables | kernel | η/s | ε_sw | max R̂ | min bulk ESS | converged | χ²/dof (model alone) | emulator share | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for s, set_name in enumerate(SETS):
        for k in ["none", "I", "II"]:
            path = f"{out}/set{s}_{k}/summary.json"
            if not os.path.exists(path):  # a grid still running, or stopped
                print(f"| {set_name} | {k} | not run | | | | | | | |")
                continue
            d = json.load(open(path))
            diag, fit = d["diagnostics"], d["fit"]
            rhat = max(q["rhat"] for q in diag["parameters"])
            ess = min(q["ess_bulk"] for q in diag["parameters"])
            conv = "yes" if diag["converged"] else "**no**"
            share = f"{100 * fit['model_variance_share']:.1f}%" if fit.get("model_variance_share") else "—"
            p = d["parameters"]
            print(f"| {set_name} | {k} | {cell(p, 'eta_s')} | {cell(p, 'e_sw')} | {rhat:.3f} | {ess:.0f} | {conv} | {fit['chi2_per_dof']:.1f} | {share} | {diag['wall_seconds']:.0f} |")


if __name__ == "__main__":
    main(sys.argv[1])
