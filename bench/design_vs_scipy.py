#!/usr/bin/env python3
"""Minimum pairwise distance and centered L2 discrepancy of mdpipe's maximin
Latin hypercube against scipy's LatinHypercube (plain and optimization="random-cd").

    pip install scipy
    cargo build --release
    python3 bench/design_vs_scipy.py [--mdpipe target/release/mdpipe]
"""
import argparse, json, os, subprocess, tempfile, time
import numpy as np
from scipy.spatial.distance import pdist
from scipy.stats import qmc

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ap = argparse.ArgumentParser()
ap.add_argument("--mdpipe", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target")), "release", "mdpipe"))
args = ap.parse_args()

SEEDS = range(1, 6)
print(f"mean over seeds {list(SEEDS)} of each design's minimum pairwise distance and centered L2 discrepancy (CD2)")
print(f"{'n':>4} {'d':>3} | {'min distance: mdpipe':>20} {'scipy random-cd':>16} {'scipy plain':>12} {'ratio':>6} | {'CD2: mdpipe':>11} {'random-cd':>10} | {'mdpipe s':>8}")
for n, d in [(50, 2), (100, 2), (100, 5), (250, 5), (500, 10)]:
    ours, cds, plains, ours_cd, cd_cd, walls = [], [], [], [], [], []
    for seed in SEEDS:
        with tempfile.TemporaryDirectory() as tmp:
            spec = os.path.join(tmp, "spec.toml")
            with open(spec, "w") as f:
                f.write('name = "bench"\n')
                for k in range(d):
                    f.write(f'[[parameter]]\nname = "p{k}"\nmin = 0.0\nmax = 1.0\nkey = "p{k}"\n')
            t0 = time.perf_counter()
            subprocess.run([args.mdpipe, "design", spec, "--points", str(n), "--out", os.path.join(tmp, "out"), "--seed", str(seed)], check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            q = json.load(open(os.path.join(tmp, "out", "quality.json")))["quality"]
        cd = qmc.LatinHypercube(d=d, optimization="random-cd", seed=seed).random(n)
        plain = qmc.LatinHypercube(d=d, seed=seed).random(n)
        ours.append(q["min_distance"]); ours_cd.append(q["centered_l2_discrepancy"])
        cds.append(pdist(cd).min()); plains.append(pdist(plain).min())
        cd_cd.append(np.sqrt(qmc.discrepancy(cd, method="CD")))
    m = np.mean
    print(f"{n:>4} {d:>3} | {m(ours):>20.4f} {m(cds):>16.4f} {m(plains):>12.4f} {m(ours) / m(cds):>5.2f}x | "
          f"{m(ours_cd):>11.5f} {m(cd_cd):>10.5f} | {m(walls):>8.2f}")
