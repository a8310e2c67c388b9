#!/usr/bin/env python3
"""Ball-drop MD calibration in Python (numpy + emcee, and pocoMC if installed),
timed against `mdpipe calibrate` on the same data and likelihood.

    pip install numpy scipy emcee pocomc
    cargo build --release
    python3 bench/ball_drop_python.py [--mdpipe target/release/mdpipe] [--kernel II]

Prints likelihood evaluations per second, ESS per second, and the ratios
(mdpipe / Python). One run: machines are noisy, so treat ratios as rough.
"""
import argparse, csv, json, os, subprocess, sys, tempfile, time
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def load(path):
    rows = [r for r in csv.DictReader(l for l in open(path) if not l.startswith("#"))]
    out = {}
    for name in ["height", "velocity", "acceleration"]:
        sel = sorted([(float(r["x"]), float(r["value"]), float(r["error"])) for r in rows if r["observable"] == name])
        x, y, e = map(np.array, zip(*sel))
        out[name] = (x, y, e, y.mean(), y.std())  # population std, as the paper
    return out


def model(name, t, g, v0, h0=60.0):
    if name == "height":
        return h0 - v0 * t - 0.5 * g * t * t
    if name == "velocity":
        return v0 + g * t
    return np.full_like(t, g)


def make_loglike(data, kernel):
    names = list(data)
    nh = 4 if kernel == "I" else 3
    lo = np.array([0.0, -2.0] + [0.0] * nh * len(names))
    hi = np.array([20.0, 2.0] + [10.0] * nh * len(names))

    def loglike(p):
        if np.any(p <= lo) or np.any(p >= hi):
            return -np.inf
        g, v0 = p[0], p[1]
        total = 0.0
        for b, name in enumerate(names):
            x, y, e, mu, sd = data[name]
            cbar, ell, r = p[2 + b * nh: 5 + b * nh]
            s2 = p[5 + b * nh] ** 2 if kernel == "I" else 0.0
            res = (y - model(name, x, g, v0)) / sd
            xr = x ** r
            K = s2 + cbar ** 2 * np.outer(xr, xr) * np.exp(-np.subtract.outer(x, x) ** 2 / (2 * ell ** 2))
            K[np.diag_indices_from(K)] += (e / sd) ** 2
            try:
                L = np.linalg.cholesky(K)
            except np.linalg.LinAlgError:
                return -np.inf
            z = np.linalg.solve(L, res)  # triangular in effect
            total += -0.5 * (z @ z) - np.log(np.diag(L)).sum() - 0.5 * len(x) * np.log(2 * np.pi) - len(x) * np.log(sd)
        return total

    return loglike, lo, hi


def ess_min(chain):
    import emcee
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    n = chain.shape[0] * chain.shape[1]
    return float(np.min(n / tau))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mdpipe", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target")), "release", "mdpipe"))
    ap.add_argument("--kernel", default="II", choices=["I", "II"])
    ap.add_argument("--steps", type=int, default=20000)
    args = ap.parse_args()
    data = load(os.path.join(ROOT, "pipeline", "ball_drop_data.csv"))
    loglike, lo, hi = make_loglike(data, args.kernel)
    dim = len(lo)
    rng = np.random.default_rng(1)

    pts = lo + (hi - lo) * rng.uniform(size=(2000, dim))
    t0 = time.perf_counter()
    for p in pts:
        loglike(p)
    py_evals = len(pts) / (time.perf_counter() - t0)
    print(f"python likelihood (kernel {args.kernel}, dim {dim}): {py_evals:,.0f} evaluations/s")

    results = {}
    import emcee
    nw = max(32, 4 * dim)
    p0 = lo + (hi - lo) * rng.uniform(size=(nw, dim))
    sampler = emcee.EnsembleSampler(nw, dim, loglike)
    t0 = time.perf_counter()
    sampler.run_mcmc(p0, args.steps, progress=False)
    wall = time.perf_counter() - t0
    chain = sampler.get_chain(discard=args.steps // 4)
    results["emcee"] = (wall, ess_min(chain))
    print(f"emcee: {wall:.1f} s, min ESS {results['emcee'][1]:.0f}, min ESS/s {results['emcee'][1] / wall:.1f}, "
          f"g = {np.median(chain[..., 0]):.3f}")

    try:
        import pocomc
        prior = pocomc.Prior([__import__("scipy").stats.uniform(l, h - l) for l, h in zip(lo, hi)])
        t0 = time.perf_counter()
        s = pocomc.Sampler(prior, loglike, n_dim=dim, random_state=1)
        s.run(progress=False)
        wall = time.perf_counter() - t0
        samples, _, _ = s.posterior(resample=True)[:3]
        results["pocomc"] = (wall, float(len(samples)))
        print(f"pocomc: {wall:.1f} s for {len(samples)} posterior samples")
    except Exception as e:  # pocomc is optional
        print(f"pocomc: skipped ({e.__class__.__name__}: {e})")

    bench = subprocess.run([args.mdpipe, "bench", os.path.join(ROOT, "pipeline", "ball_drop.toml"), "--likelihood-only",
                            "--evaluations", "500000"], capture_output=True, text=True, check=True).stdout
    print(bench.strip())
    rust_evals = float([l for l in bench.splitlines() if f"kernel={args.kernel} " in l][0].split(":")[1].split()[0])
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        subprocess.run([args.mdpipe, "calibrate", os.path.join(ROOT, "pipeline", "ball_drop.toml"), "--kernel", args.kernel,
                        "--out", d, "--seed", "1"], check=True, capture_output=True)
        wall_total = time.perf_counter() - t0
        summ = json.load(open(os.path.join(d, "summary.json")))
    rust_ess_s = summ["diagnostics"]["min_ess_per_second"]
    print(f"mdpipe SMC: {summ['diagnostics']['wall_seconds']:.2f} s sampling ({wall_total:.2f} s with I/O and diagnostics), "
          f"min ESS/s {rust_ess_s:.0f}, g = {summ['parameters']['g']['median']:.3f}")
    print(f"ratio, likelihood evaluations/s (mdpipe one core / numpy): {rust_evals / py_evals:.0f}x")
    w, e = results["emcee"]
    print(f"ratio, min ESS/s (mdpipe SMC / emcee): {rust_ess_s / (e / w):.0f}x")


if __name__ == "__main__":
    sys.exit(main())
