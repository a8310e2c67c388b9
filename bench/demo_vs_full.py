#!/usr/bin/env python3
"""Compares the light demo's grid with the full-settings demo's, quantile by
quantile, in units of their combined Monte Carlo error.

    mdpipe demo --out LIGHT && mdpipe demo --full --out FULL
    python3 bench/demo_vs_full.py LIGHT FULL        # needs numpy and pyarrow

For each grid case, parameter and quantile (2.5%, 50%, 97.5%) it prints the
two estimates and z = difference / MC sd, where a quantile's MC sd is
sqrt(q(1-q)/ESS) / f(x_q), with ESS the smaller of the run's bulk and tail ESS
for that parameter (summary.json) and f the full run's posterior density at
x_q (a Gaussian kernel estimate). With both runs right, z is about N(0, 1).
"""
import glob
import json
import os
import sys

import numpy as np
import pyarrow.parquet as pq


def ess(summary, name):
    for p in summary["diagnostics"]["parameters"]:
        if p["name"] == name:
            return min(p["ess_bulk"], p["ess_tail"])
    raise KeyError(name)


def main(light, full):
    rows = []
    for case_dir in sorted(glob.glob(os.path.join(full, "compare", "*", ""))):
        case = os.path.basename(case_dir.rstrip("/"))
        light_dir = os.path.join(light, "compare", case)
        post_full = pq.read_table(os.path.join(case_dir, "posterior.parquet"))
        post_light = pq.read_table(os.path.join(light_dir, "posterior.parquet"))
        sum_full = json.load(open(os.path.join(case_dir, "summary.json")))
        sum_light = json.load(open(os.path.join(light_dir, "summary.json")))
        for name in sum_full["parameter_order"]:
            if "." in name:  # discrepancy hyperparameters: not compared
                continue
            xf = np.asarray(post_full.column(name))
            xl = np.asarray(post_light.column(name))
            bandwidth = 1.06 * np.std(xf) * len(xf) ** -0.2
            for q in (0.025, 0.5, 0.975):
                at = np.quantile(xf, q)
                density = np.mean(np.exp(-0.5 * ((xf - at) / bandwidth) ** 2)) / (bandwidth * np.sqrt(2 * np.pi))
                var = sum(q * (1 - q) / ess(s, name) for s in (sum_full, sum_light)) / density**2
                diff = np.quantile(xl, q) - at
                rows.append((case, name, q, np.quantile(xl, q), at, np.sqrt(var), diff / np.sqrt(var)))
    print(f"{'case':<40} {'par':<4} {'q':>6} {'light':>9} {'full':>9} {'MC sd':>7} {'z':>6}")
    for r in rows:
        print(f"{r[0]:<40} {r[1]:<4} {r[2]:>6.3f} {r[3]:>9.3f} {r[4]:>9.3f} {r[5]:>7.3f} {r[6]:>6.2f}")
    z = np.array([r[-1] for r in rows])
    print(f"{len(z)} quantiles: max |z| = {np.abs(z).max():.2f}, rms z = {np.sqrt(np.mean(z**2)):.2f}, "
          f"|z| > 2: {(np.abs(z) > 2).sum()} (expected {0.0455 * len(z):.1f}), |z| > 3: {(np.abs(z) > 3).sum()}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
