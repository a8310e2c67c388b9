#!/usr/bin/env python3
"""mdpipe train-emulator vs scikit-learn GaussianProcessRegressor, side by side.

Same data (a smooth 70-output stand-in for heavy-ion observables: 3 log
"spectra" and 4 "flow" observables in 10 bins, plus 1% noise), the same
preprocessing (log of spectra, standardization, PCA with whitened scores,
inputs on the unit cube), the same kernel (C * Matern-5/2 ARD + C + White,
with the same bounds), the same number of optimizer starts.

    pip install numpy scikit-learn
    cargo build --release
    python3 bench/emulator_vs_sklearn.py --points 200 --dims 5

Prints both training times, their ratio, and both held-out RMSEs per observable.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

BINS = np.linspace(0.1, 1.9, 10)
SPECTRA = ["ch_spectrum", "pi_spectrum", "p_spectrum"]
FLOW = ["ch_v2", "ch_v3", "pi_v2", "p_v2"]


def simulator(theta, rng, noise=0.01):
    """Smooth in theta (unit cube), 70 outputs; multiplicative 1% noise."""
    d = len(theta)
    t = list(theta) + [0.5] * max(0, 5 - d)
    out = []
    for k, _ in enumerate(SPECTRA):
        slope = 0.2 + 0.25 * t[0] + 0.05 * k + 0.05 * t[1] * t[2]
        norm = (1.0 + 0.5 * t[3]) * (2.0 - k * 0.5)
        out.extend(norm * np.exp(-BINS / slope) * (1 + 0.1 * np.sin(3 * t[4] + BINS)))
    for k, _ in enumerate(FLOW):
        damp = np.exp(-(k + 1) * (0.5 + 1.5 * t[1]) * BINS * 0.3)
        out.extend((0.12 - 0.025 * k) * BINS * damp * (1 - 0.4 * t[0] + 0.2 * t[2] * t[3]) + 0.01 * np.cos(2 * t[4]) * BINS)
    y = np.array(out)
    return y * (1 + noise * rng.standard_normal(y.shape))


def names():
    return [(o, x) for o in SPECTRA + FLOW for x in BINS]


def write_table(path, X, Y):
    params = [f"p{k}" for k in range(X.shape[1])]
    with open(path, "w") as f:
        f.write("design_id,observable,x,value," + ",".join(params) + "\n")
        for i in range(len(X)):
            for j, (o, x) in enumerate(names()):
                f.write(f"{i},{o},{float(x)!r},{float(Y[i, j])!r}," + ",".join(repr(float(v)) for v in X[i]) + "\n")


def sklearn_emulator(X, Y, n_components, restarts, seed):
    from sklearn.decomposition import PCA
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel as C, Matern, WhiteKernel

    d = X.shape[1]
    is_log = np.array([o in SPECTRA for o, _ in names()])
    T = np.where(is_log, np.log(Y), Y)
    mean, std = T.mean(0), T.std(0)
    pca = PCA(n_components=n_components, whiten=True, svd_solver="full").fit((T - mean) / std)
    S = pca.transform((T - mean) / std)
    lo, hi = X.min(0), X.max(0)
    U = (X - lo) / (hi - lo)
    kernel = (
        C(1.0, (1e-4, 1e4)) * Matern(length_scale=[0.5] * d, length_scale_bounds=(1e-2, 1e3), nu=2.5)
        + C(0.1, (1e-6, 1e4))
        + WhiteKernel(1e-3, (1e-8, 1e1))
    )
    t0 = time.perf_counter()
    gps = [GaussianProcessRegressor(kernel, n_restarts_optimizer=restarts - 1, random_state=seed).fit(U, S[:, k]) for k in range(n_components)]
    seconds = time.perf_counter() - t0

    def predict(Xq):
        Uq = (Xq - lo) / (hi - lo)
        Sq = np.column_stack([gp.predict(Uq) for gp in gps])
        Tq = pca.inverse_transform(Sq) * std + mean
        return np.where(is_log, np.exp(Tq), Tq)

    return seconds, predict, [gp.log_marginal_likelihood_value_ for gp in gps]


def relative_rmse(Ytrue, Ypred):
    out = {}
    for o in SPECTRA + FLOW:
        cols = [j for j, (n, _) in enumerate(names()) if n == o]
        err = np.sqrt(np.mean((Ypred[:, cols] - Ytrue[:, cols]) ** 2))
        out[o] = err / np.sqrt(np.mean(Ytrue[:, cols].var(0)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=200)
    ap.add_argument("--dims", type=int, default=5)
    ap.add_argument("--validation", type=int, default=100)
    ap.add_argument("--restarts", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--show-lml", action="store_true", help="print each component's optimized log marginal likelihood")
    ap.add_argument("--mdpipe", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", "target"), "release", "mdpipe"))
    a = ap.parse_args()

    rng = np.random.default_rng(a.seed)
    X = rng.random((a.points, a.dims))
    Xv = rng.random((a.validation, a.dims))
    Y = np.array([simulator(x, rng) for x in X])
    Yv = np.array([simulator(x, rng) for x in Xv])

    with tempfile.TemporaryDirectory() as tmp:
        write_table(f"{tmp}/train.csv", X, Y)
        write_table(f"{tmp}/val.csv", Xv, Yv)
        params = ", ".join(f'"p{k}"' for k in range(a.dims))
        with open(f"{tmp}/emu.toml", "w") as f:
            f.write(f'[emulator]\nparameters = [{params}]\nkernel = "matern52"\nvariance_fraction = 0.99\nrestarts = {a.restarts}\n')
            f.write(f"log_observables = {json.dumps(SPECTRA)}\n")
        t0 = time.perf_counter()
        subprocess.run([a.mdpipe, "train-emulator", f"{tmp}/emu.toml", "--training", f"{tmp}/train.csv", "--out", f"{tmp}/emu", "--seed", str(a.seed)], check=True, stdout=subprocess.DEVNULL)
        md_wall = time.perf_counter() - t0
        meta = json.load(open(f"{tmp}/emu/emulator.json"))
        md_train = meta["report"]["training_seconds"]
        k = meta["n_components"]
        md_lml = meta["report"]["log_marginal_likelihood"]
        subprocess.run([a.mdpipe, "validate-emulator", f"{tmp}/emu", "--validation", f"{tmp}/val.csv", "--folds", "0"], check=True, stdout=subprocess.DEVNULL)
        md_rmse = {r["observable"]: r["relative_rmse"] for r in json.load(open(f"{tmp}/emu/validation.json"))["holdout"]}

    sk_seconds, sk_predict, sk_lml = sklearn_emulator(X, Y, k, a.restarts, a.seed)
    if a.show_lml:
        # sklearn whitens with the n-1 variance, mdpipe with n: shift by n ln sqrt(n/(n-1)).
        shift = a.points * 0.5 * np.log(a.points / (a.points - 1))
        for c, (m, s_) in enumerate(zip(md_lml, sk_lml)):
            print(f"component {c}: log marginal likelihood mdpipe {m:.3f}, sklearn {s_ - shift:.3f}")
    sk_rmse = relative_rmse(Yv, sk_predict(Xv))

    print(f"{a.points} design points, {a.dims} parameters, {Y.shape[1]} outputs, {k} PCA components, {a.restarts} optimizer starts per component")
    print(f"training: mdpipe {md_train:.2f} s ({md_wall:.2f} s wall incl. I/O), scikit-learn {sk_seconds:.2f} s -> ratio {sk_seconds / md_train:.1f}x")
    print(f"{'observable':<14}{'mdpipe RMSE/spread':>20}{'sklearn RMSE/spread':>22}")
    for o in SPECTRA + FLOW:
        print(f"{o:<14}{md_rmse[o]:>20.4f}{sk_rmse[o]:>22.4f}")
    print(f"{'mean':<14}{np.mean(list(md_rmse.values())):>20.4f}{np.mean(list(sk_rmse.values())):>22.4f}")


if __name__ == "__main__":
    sys.exit(main())
