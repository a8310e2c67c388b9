"""Runs `mdpipe diagnose` and `mdpipe compare` on every bundled declared
config with its own settings and counts the fits that did not converge
(and those the sampler had to run again), from each fit's summary.json.

    python3 bench/bundled_convergence.py OUT [MDPIPE]   # from the repository root

MDPIPE defaults to `mdpipe` on PATH. Prints one row per command and the totals.
"""
import glob
import json
import os
import subprocess
import sys
import time

CONFIGS = [
    "pipeline/ball_drop.toml",
    "pipeline/examples/goh_bias.toml",
    "pipeline/examples/kinetics.toml",
    "pipeline/examples/oscillator.toml",
    "pipeline/examples/simple_machine.toml",
]
out = sys.argv[1]
mdpipe = sys.argv[2] if len(sys.argv) > 2 else "mdpipe"
totals = {"fits": 0, "not_converged": 0, "adapted": 0}
print("| command | config | fits | not converged | sampled again | s |")
print("|---|---|---|---|---|---|")
for config in CONFIGS:
    name = os.path.splitext(os.path.basename(config))[0]
    for command in ("diagnose", "compare"):
        folder = os.path.join(out, f"{name}_{command}")
        start = time.time()
        run = subprocess.run([mdpipe, command, config, "--out", folder], capture_output=True, text=True)
        seconds = time.time() - start
        if run.returncode != 0:
            print(f"| {command} | {config} | failed: {run.stderr.strip()[-300:]} | | | {seconds:.0f} |")
            continue
        summaries = glob.glob(os.path.join(folder, "**", "summary.json"), recursive=True)
        fits = not_converged = adapted = 0
        for path in summaries:
            diagnostics = json.load(open(path)).get("diagnostics", {})
            fits += 1
            not_converged += not diagnostics.get("converged", False)
            adapted += bool(diagnostics.get("adaptation"))
        totals["fits"] += fits
        totals["not_converged"] += not_converged
        totals["adapted"] += adapted
        print(f"| {command} | {config} | {fits} | {not_converged} | {adapted} | {seconds:.0f} |")
print(f"\n{totals['fits']} fits, {totals['not_converged']} not converged, {totals['adapted']} sampled again")
