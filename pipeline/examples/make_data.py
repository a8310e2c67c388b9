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
- goh_bias: Goh et al. (2013), Technometrics 55, 501, as calibrated in
  Gramacy's laGP (J. Stat. Softw. 72(1), 2016): the simulator M(x1, x2; u)
  at the true u = (0.2, 0.1) plus the published bias
  b(x1, x2) = 2 (10 x1^2 + 4 x2^2) / (50 x1 x2 + 10); one observable per
  level of x2.

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


def goh_simulator(x1, x2, u1, u2):
    return (1.0 - math.exp(-1.0 / (2.0 * x2))) * (1000 * u1 * x1**3 + 1900 * x1**2 + 2092 * x1 + 60) / (
        100 * u2 * x1**3 + 500 * x1**2 + 4 * x1 + 20)


def goh_bias(x1, x2):
    return 2.0 * (10 * x1**2 + 4 * x2**2) / (50 * x1 * x2 + 10)


rng = random.Random(2013)
rows = []
for x2, name in [(0.25, "y_x2_025"), (0.5, "y_x2_050"), (0.75, "y_x2_075")]:
    truth = lambda x1, x2=x2: goh_simulator(x1, x2, 0.2, 0.1) + goh_bias(x1, x2)
    rows += noisy(rng, truth, [0.1 * i for i in range(1, 11)], 0.02, name)
write("goh_bias_data.csv", rows,
      "M(x1, x2; 0.2, 0.1) + b(x1, x2) + N(0, 0.02^2), x1 = 0.1..1.0, x2 = 0.25, 0.5, 0.75 (make_data.py, seed 2013)")

# oscillator: a harmonic oscillator x'' = -w^2 x from x(0) = x0 at rest,
# observed at 40 times over 10 s; the reality is lightly damped,
# x'' = -w^2 x - 2 g x', in closed form (underdamped, w = 2, g = 0.1, x0 = 1).
def damped(t, w=2.0, g=0.1, x0=1.0):
    wd = math.sqrt(w * w - g * g)
    return x0 * math.exp(-g * t) * (math.cos(wd * t) + g / wd * math.sin(wd * t))


rng = random.Random(2026)
write("oscillator_data.csv", noisy(rng, damped, [0.25 * i for i in range(1, 41)], 0.02, "position"),
      "x(t) = exp(-0.1 t)(cos(wd t) + 0.1/wd sin(wd t)), wd = sqrt(4 - 0.01), + N(0, 0.02^2), t = 0.25..10 (make_data.py, seed 2026)")
