"""Writes the example measurements from the published true processes, in
closed form and independently of mdpipe (Python's own Gaussian generator,
fixed seeds). Run from anywhere: python3 pipeline/examples/make_data.py

- simple_machine: Brynjarsdottir & O'Hagan (2014), Inverse Problems 30,
  114007: reality zeta(x) = theta x / (1 + x/a), theta = 0.65, a = 20; the
  simulator eta(x, theta) = theta x leaves out the saturation.
- kinetics: Bayarri et al. (2007), Technometrics 49, 138: reality
  y(t) = 3.5 exp(-1.7 t) + 1.5; the simulator y = 5 exp(-u t) (dy/dt = -u y)
  leaves out the equilibrium the reaction approaches.
- kinetics_null: the simulator itself at u = 1.7, nothing left out.

The x grids and noise levels are ours (the papers' own data are not
reproduced); they are written beside each table.
"""
import math
import os
import random

HERE = os.path.dirname(os.path.abspath(__file__))


def write(name, rows, note):
    with open(os.path.join(HERE, name), "w") as f:
        f.write(f"# {note}\n")
        f.write("observable,x,value,error\n")
        for obs, x, value, error in rows:
            f.write(f"{obs},{x:.6g},{value:.10g},{error}\n")


def noisy(rng, truth, xs, sigma, observable):
    return [(observable, x, truth(x) + rng.gauss(0.0, sigma), sigma) for x in xs]


rng = random.Random(14)
xs = [0.4 * i for i in range(1, 11)]
write("simple_machine_data.csv", noisy(rng, lambda x: 0.65 * x / (1.0 + x / 20.0), xs, 0.01, "work"),
      "zeta(x) = 0.65 x / (1 + x/20) + N(0, 0.01^2), x = 0.4..4.0 (make_data.py, seed 14)")

ts = [0.1 + 0.3 * i for i in range(10)]
rng = random.Random(2007)
write("kinetics_data.csv", noisy(rng, lambda t: 3.5 * math.exp(-1.7 * t) + 1.5, ts, 0.05, "concentration"),
      "y(t) = 3.5 exp(-1.7 t) + 1.5 + N(0, 0.05^2), t = 0.1..2.8 (make_data.py, seed 2007)")
rng = random.Random(2008)
write("kinetics_null_data.csv", noisy(rng, lambda t: 5.0 * math.exp(-1.7 * t), ts, 0.05, "concentration"),
      "y(t) = 5 exp(-1.7 t) + N(0, 0.05^2), nothing missing, t = 0.1..2.8 (make_data.py, seed 2008)")
