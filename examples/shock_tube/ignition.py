#!/usr/bin/env python3
"""ignition: hydrogen-air ignition delays behind a reflected shock, computed by Cantera.

A physicist's own driver around an open-source code that was not written for
mdpipe (Cantera, `pip install cantera`, with its bundled hydrogen mechanism
h2o2.yaml). It reads an iEBE-MUSIC-style parameter file (`key value` lines)
and writes OUT/outputs.csv (observable, x, value): the ignition delay in ms
of two mixtures at 10 bar, H2-air at equivalence ratio 1 (`tau_stoich`) and
0.5 (`tau_lean`), at initial temperatures T0 = 1000-1250 K in steps of 25 K,
written as x = 1000/T0 (1/K), the axis of an Arrhenius plot. The delay is the
time at which the gas has heated by 400 K.

    python3 ignition.py PARAM_FILE OUT [--pressure-rise on|off]

The parameter file gives `k_branching` and `k_ho2_h2`: multipliers of the
rate constants of H + O2 <=> O + OH (the chain branching that rules the hot
end) and H + H2O2 <=> H2 + HO2 (run backwards, HO2 + H2, the path of the
cool, high-pressure end). The ideal reactor is adiabatic at constant volume.
Physics that can be switched on:
  * heat loss to the tube's wall at 300 K: `wall heat_loss` and `wall_htc`
    (W/(m^2 K)) in the parameter file, for a tube 5 cm across (A/V = 80/m);
  * a facility pressure rise: `--pressure-rise on` and `dpdt_percent_per_ms`,
    an isentropic compression that raises the pressure of the unreacted gas
    by that percentage each millisecond;
  * `marker_lag_us` (parameter file): the experiment's ignition marker lags
    the 400 K rise by that many microseconds. The study does not declare it:
    it is the part of the measurements no candidate explains.
"""
import argparse
import math
import os
import sys
import warnings

PRESSURE = 10.0e5  # Pa
T_WALL = 300.0  # K
AREA_PER_VOLUME = 80.0  # 1/m: a tube of 5 cm diameter
TEMPERATURES = [1000.0 + 25.0 * k for k in range(11)]
MIXTURES = [("tau_stoich", 1.0), ("tau_lean", 0.5)]
T_MAX = 0.2  # s: no ignition by then is an error, not a number
GAMMA = 1.4  # for the compression that makes a given pressure rise


def read_parameters(path):
    values = {}
    with open(path) as f:
        for n, line in enumerate(f, 1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) != 2:
                sys.exit(f"{path}:{n}: expected `key value`, got {line.strip()!r}")
            values[parts[0]] = parts[1]
    return values


def number(values, key, default=None):
    if key not in values:
        if default is None:
            sys.exit(f"parameter file: missing `{key}`")
        return default
    try:
        return float(values[key])
    except ValueError:
        sys.exit(f"parameter file: `{key}` is not a number: {values[key]!r}")


def reactions(gas, equation):
    found = [i for i, r in enumerate(gas.reactions()) if r.equation == equation]
    if not found:
        sys.exit(f"h2o2.yaml has no reaction {equation!r}")
    return found


def delay_ms(ct, gas, t0, phi, settings):
    """Time for a 400 K rise, interpolated linearly between the integrator's steps."""
    gas.TP = T_WALL, PRESSURE
    gas.set_equivalence_ratio(phi, "H2", "O2:1, N2:3.76")
    outside = ct.Reservoir(gas, clone=True)
    gas.TP = t0, PRESSURE
    gas.set_equivalence_ratio(phi, "H2", "O2:1, N2:3.76")
    reactor = ct.IdealGasReactor(gas, clone=True)
    reactor.volume = 1.0 / AREA_PER_VOLUME
    walls = []
    if settings["htc"] > 0:
        walls.append(ct.Wall(reactor, outside, A=1.0, U=settings["htc"]))
    if settings["dpdt"] > 0:
        rate, v0 = settings["dpdt"] / 100.0 * 1e3, reactor.volume  # per second
        piston = ct.Wall(reactor, outside, A=1.0)
        # V(t) = V0 (1 + rate t)^(-1/γ): the unreacted gas's pressure rises as 1 + rate t.
        piston.velocity = lambda t: -v0 * rate / GAMMA * (1.0 + rate * t) ** (-1.0 / GAMMA - 1.0)
        walls.append(piston)
    net = ct.ReactorNet([reactor])
    target, t_prev, temp_prev = t0 + 400.0, 0.0, t0
    while net.time < T_MAX:
        t = net.step()
        temp = reactor.T
        if temp >= target:
            t_cross = t_prev + (t - t_prev) * (target - temp_prev) / (temp - temp_prev)
            return 1e3 * t_cross + settings["lag_us"] * 1e-3
        t_prev, temp_prev = t, temp
    sys.exit(f"no ignition within {T_MAX} s at T0 = {t0} K, phi = {phi}: heat loss too strong?")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("param_file")
    ap.add_argument("out")
    ap.add_argument("--pressure-rise", choices=["on", "off"], default="off")
    a = ap.parse_args()
    p = read_parameters(a.param_file)
    k_branching, k_ho2_h2 = number(p, "k_branching"), number(p, "k_ho2_h2")
    if not (k_branching > 0 and k_ho2_h2 > 0):
        sys.exit(f"k_branching = {k_branching}, k_ho2_h2 = {k_ho2_h2}: both must be positive")
    wall = p.get("wall", "adiabatic")
    if wall not in ("adiabatic", "heat_loss"):
        sys.exit(f"parameter file: `wall` is {wall!r}; expected adiabatic or heat_loss")
    settings = {
        "htc": number(p, "wall_htc") if wall == "heat_loss" else 0.0,
        "dpdt": number(p, "dpdt_percent_per_ms") if a.pressure_rise == "on" else 0.0,
        "lag_us": number(p, "marker_lag_us", 0.0),
    }
    warnings.simplefilter("ignore", DeprecationWarning)
    import cantera as ct

    gas = ct.Solution("h2o2.yaml")
    for i in reactions(gas, "H + O2 <=> O + OH"):
        gas.set_multiplier(k_branching, i)
    for i in reactions(gas, "H + H2O2 <=> H2 + HO2"):
        gas.set_multiplier(k_ho2_h2, i)
    rows = [(name, t0, delay_ms(ct, gas, t0, phi, settings)) for name, phi in MIXTURES for t0 in TEMPERATURES]
    os.makedirs(a.out, exist_ok=True)
    tmp = os.path.join(a.out, "outputs.csv.tmp")
    with open(tmp, "w") as f:
        f.write("observable,x,value\n")
        for name, t0, tau in rows:
            f.write(f"{name},{1000.0 / t0:.6f},{tau:.8g}\n")
    os.replace(tmp, os.path.join(a.out, "outputs.csv"))


if __name__ == "__main__":
    main()
