#!/usr/bin/env python3
"""Measurements from ignition.py's own run at a truth: each delay scattered by
a seeded log-normal error of the given relative size, and that size of the
measured value written as its error (a shock tube's ignition delays carry
about 5-20%).

    python3 make_measurements.py TRUTH_PARAMS OUT_CSV [--seed S] [--error 0.06]
"""
import argparse
import csv
import math
import os
import random
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("truth")
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--error", type=float, default=0.06)
    ap.add_argument("--pressure-rise", choices=["on", "off"], default="off")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, os.path.join(HERE, "ignition.py"), a.truth, tmp, "--pressure-rise", a.pressure_rise]
        subprocess.run(cmd, check=True)
        with open(os.path.join(tmp, "outputs.csv")) as f:
            rows = list(csv.DictReader(f))
    rng = random.Random(a.seed)
    with open(a.out + ".tmp", "w") as f:
        f.write("observable,x,value,error\n")
        for r in rows:
            value = float(r["value"]) * math.exp(rng.gauss(0.0, a.error))
            f.write(f"{r['observable']},{r['x']},{value:.4g},{a.error * value:.2g}\n")
    os.replace(a.out + ".tmp", a.out)


if __name__ == "__main__":
    main()
