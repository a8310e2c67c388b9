"""The installed package against the bundled decay-counter study: ArviZ's
view of every calibration agrees with mdpipe's own summary.json, follows
ArviZ's schema, plots headless, and survives export to NetCDF and Zarr.

Run from the repository root after `pip install .` (.ci/python-package.sh).
The study is run once into outputs/decay_counter; when it is already there
and up to date, mdpipe skips every stage and this only loads it.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import arviz as az
import matplotlib
import numpy as np
import pytest
import xarray as xr

import mdpipe

matplotlib.use("Agg")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def study():
    # The notebook's own command from the notebook's folder: a study it ran
    # is then up to date (the simulator's command holds the config's folder
    # as written) and is only loaded.
    here = os.getcwd()
    os.chdir(ROOT / "examples" / "notebooks")
    try:
        return mdpipe.run("../decay_counter/study.toml", out="../../outputs/decay_counter", quiet=True)
    finally:
        os.chdir(here)


def calibration_folders(study):
    folders = [study.out / "calibrate" / case for case in study.cases.case]
    folders += [study.out / "diagnose" / fit for fit in study.diagnosis.fits]
    return folders


def test_every_calibration_of_the_study_loads(study):
    assert len(calibration_folders(study)) >= 8
    for folder in calibration_folders(study):
        idata = mdpipe.load(folder)
        assert {"posterior", "sample_stats", "observed_data", "posterior_predictive"} <= set(idata.groups())


def test_arviz_summary_agrees_with_summary_json(study):
    for folder in calibration_folders(study):
        idata = mdpipe.load(folder)
        ours = json.loads((folder / "summary.json").read_text())
        by_median = az.summary(idata, stat_focus="median", hdi_prob=0.95, round_to="none")
        by_mean = az.summary(idata, round_to="none")
        diagnostics = {p["name"]: p for p in ours["diagnostics"]["parameters"]}
        for name, stats in ours["parameters"].items():
            draws = idata.posterior[name]
            # Medians and interval ends within 3 Monte Carlo standard errors.
            assert abs(by_median.loc[name, "median"] - stats["median"]) <= 3 * by_median.loc[name, "mcse_median"] + 1e-12
            for prob, key in ((0.025, "q025"), (0.975, "q975")):
                mcse = float(az.mcse(draws.values, method="quantile", prob=prob))
                assert abs(float(draws.quantile(prob)) - stats[key]) <= 3 * mcse + 1e-12, (folder, name, key)
            assert abs(by_mean.loc[name, "mean"] - stats["mean"]) <= 3 * by_mean.loc[name, "mcse_mean"] + 1e-12
            # R-hat and ESS are the same estimators on the same draws: equal
            # within a small fraction of their own sampling error.
            d = diagnostics[name]
            assert abs(by_mean.loc[name, "r_hat"] - d["rhat"]) < 0.005, (folder, name)
            for key, theirs in (("ess_bulk", d["ess_bulk"]), ("ess_tail", d["ess_tail"])):
                assert abs(by_mean.loc[name, key] - theirs) <= 0.05 * theirs, (folder, name, key)


def test_groups_follow_arviz_schema(study):
    idata = study.calibration("rate__kernel2")
    posterior = idata.posterior
    n_chain, n_draw = posterior.sizes["chain"], posterior.sizes["draw"]
    assert n_chain == 2  # the study's SMC replicates
    np.testing.assert_array_equal(posterior.chain, np.arange(n_chain))
    np.testing.assert_array_equal(posterior.draw, np.arange(n_draw))
    for group in ("posterior", "sample_stats", "log_likelihood"):
        for var in idata[group].data_vars.values():
            assert var.dims[:2] == ("chain", "draw") or var.dims == ("chain",), (group, var.name, var.dims)
        np.testing.assert_array_equal(idata[group].chain, posterior.chain)
    assert posterior["activity"].attrs["units"] == "1/s"
    assert posterior["rate.cbar"].attrs["role"] == "discrepancy hyperparameter"
    assert "lp" in idata.sample_stats and "log_likelihood" in idata.sample_stats
    observed = idata.observed_data["rate"]
    assert observed.dims == ("rate_x",)
    replicated = idata.posterior_predictive["rate"]
    assert replicated.dims == ("chain", "draw", "rate_x")
    np.testing.assert_array_equal(replicated.rate_x, observed.rate_x)
    assert set(replicated.draw.values) <= set(posterior.draw.values)
    for key in ("mdpipe_version", "config_hash", "data_hash", "seed", "command"):
        assert key in posterior.attrs


def test_plots_run_headless(study, tmp_path):
    idata = study.calibration("rate__kernel2")
    az.plot_posterior(idata, var_names=["activity", "half_life"])
    az.plot_trace(idata, var_names=["activity", "half_life"])
    az.plot_ppc(idata, num_pp_samples=20)
    matplotlib.pyplot.savefig(tmp_path / "ppc.png")
    assert (tmp_path / "ppc.png").stat().st_size > 0


@pytest.mark.parametrize("fmt,reader", [("netcdf", az.from_netcdf), ("zarr", az.from_zarr)])
def test_export_from_the_command_line_reloads_to_the_same_numbers(study, tmp_path, fmt, reader):
    folder = study.out / "calibrate" / "rate__kernel2"
    target = tmp_path / f"posterior.{fmt}"
    subprocess.run([mdpipe.binary(), "export", str(folder), "--format", fmt, "--out", str(target)], check=True)
    again, direct = reader(str(target)), mdpipe.load(folder)
    assert set(again.groups()) == set(direct.groups())
    for group in direct.groups():
        xr.testing.assert_allclose(again[group], direct[group], rtol=0, atol=0)
        assert again[group].attrs["config_hash"] == direct[group].attrs["config_hash"]


def test_diagnosis_tables(study):
    diagnosis = study.diagnosis
    assert diagnosis.best == "dead_time"
    assert {"name", "log_bayes_factor", "chi2_per_dof"} <= set(diagnosis.candidates.columns)
    assert list(diagnosis.candidates.name)[0] == "dead_time"
    assert {"base_md", "base_no_md", "repaired_md"} <= set(diagnosis.fits)
    assert diagnosis.mismatch.observable.tolist() == ["rate"]


def test_calibrate_from_python(tmp_path):
    idata = mdpipe.calibrate(
        ROOT / "pipeline" / "ball_drop.toml", tmp_path / "fit", kernel="none", observables=["height"], quiet=True
    )
    assert idata.posterior.sizes["chain"] >= 2
    assert (tmp_path / "fit" / "summary.json").is_file()


def test_calibrate_takes_the_command_lines_data_and_time_limit(tmp_path):
    # Half of the heights, given as `--data`; the limit is far beyond the
    # run's length, so the sampler ends as usual.
    rows = (ROOT / "pipeline" / "ball_drop_data.csv").read_text().splitlines()
    header = [r for r in rows if r.startswith(("#", "observable,"))]
    heights = [r for r in rows if r.startswith("height,")][::2]
    (tmp_path / "half.csv").write_text("\n".join([*header, *heights]) + "\n")
    idata = mdpipe.calibrate(
        ROOT / "pipeline" / "ball_drop.toml",
        tmp_path / "fit",
        kernel="none",
        observables=["height"],
        data=tmp_path / "half.csv",
        time_limit=3600,
        quiet=True,
    )
    assert idata.observed_data["height"].size == len(heights)


def test_errors_name_what_is_wrong(tmp_path):
    with pytest.raises(FileNotFoundError, match="summary.json"):
        mdpipe.load(tmp_path)
    (tmp_path / "summary.json").write_text("{")
    with pytest.raises(ValueError, match="summary.json: not valid JSON at line 1"):
        mdpipe.load(tmp_path)
    (tmp_path / "summary.json").unlink()
    with pytest.raises(mdpipe.MdpipeError, match="exit code"):
        mdpipe.calibrate(tmp_path / "missing.toml", tmp_path / "out", quiet=True)
    done = subprocess.run([mdpipe.binary(), "export", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode != 0 and "posterior.parquet" in done.stderr
