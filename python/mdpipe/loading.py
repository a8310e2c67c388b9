"""mdpipe's artifacts (Parquet and JSON) as ArviZ and pandas objects.

The layout follows ArviZ's InferenceData schema: every group of draws has
the dimensions `chain` (an SMC replicate, or an ensemble walker) and
`draw`; observed quantities have one dimension per observable, named
`<observable>_x`, whose coordinate is the measured x.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import xarray as xr

from ._binary import StrPath

if TYPE_CHECKING:  # ArviZ is imported where it is used: it is slow to import
    from arviz import InferenceData

_STAT_COLUMNS = ("chain", "log_likelihood", "log_prior")
_TERM_PREFIX = "log_likelihood."


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: not found (is {path.parent} an mdpipe output folder?)") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON at line {err.lineno}, column {err.colno}: {err.msg}") from None


def _chain_draw(frame: pd.DataFrame, column: str) -> np.ndarray:
    """One column of a draws table as a chain x draw array (chains of equal
    length: SMC replicates and ensemble walkers always are)."""
    chains = frame["chain"].to_numpy().astype(int)
    ids = np.unique(chains)
    lengths = {int(c): int((chains == c).sum()) for c in ids}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"chains of unequal length {lengths}: not a chain x draw array")
    values = frame[column].to_numpy()
    return np.stack([values[chains == c] for c in ids])


def _attrs(summary: dict) -> dict:
    """Provenance and the run's identity, as flat attributes (NetCDF and
    Zarr keep strings and numbers only)."""
    attrs: dict[str, str | int | float] = {"created_by": "mdpipe", "inference_library": "mdpipe"}
    for key, value in summary.get("provenance", {}).items():
        attrs[key] = value
    for key in ("name", "kernel", "log_evidence", "log_evidence_err"):
        value = summary.get(key)
        if value is not None:
            attrs[key] = value
    attrs["observables"] = ",".join(summary.get("observables", []))
    attrs["converged"] = int(bool(summary.get("diagnostics", {}).get("converged", False)))
    warnings = summary.get("diagnostics", {}).get("warnings", [])
    attrs["warnings"] = "; ".join(warnings)
    return attrs


def _parameter_attrs(name: str, summary: dict) -> dict:
    units = summary.get("units", {}).get("parameters", {})
    bounds = summary.get("prior_bounds", {}).get(name)
    attrs: dict[str, str | float] = {}
    if "." in name:
        observable, hyper = name.split(".", 1)
        attrs.update(role="discrepancy hyperparameter", observable=observable, hyperparameter=hyper)
    else:
        attrs["role"] = "model parameter"
        if name in units:
            attrs["units"] = units[name]
    if bounds is not None:
        attrs["prior"] = f"uniform on [{bounds[0]}, {bounds[1]}]"
    return attrs


def _posterior(frame: pd.DataFrame, summary: dict) -> xr.Dataset:
    names = summary.get("parameter_order") or [
        c for c in frame.columns if c not in _STAT_COLUMNS and not c.startswith(_TERM_PREFIX)
    ]
    variables = {
        name: (("chain", "draw"), _chain_draw(frame, name), _parameter_attrs(name, summary)) for name in names
    }
    return _with_chain_draw(xr.Dataset(variables))


def _with_chain_draw(ds: xr.Dataset) -> xr.Dataset:
    return ds.assign_coords(chain=np.arange(ds.sizes["chain"]), draw=np.arange(ds.sizes["draw"]))


def _sample_stats(frame: pd.DataFrame, summary: dict) -> xr.Dataset | None:
    if "log_likelihood" not in frame:
        return None
    loglik = _chain_draw(frame, "log_likelihood")
    variables: dict[str, tuple[tuple[str, ...], np.ndarray]] = {
        "log_likelihood": (("chain", "draw"), loglik),
        "lp": (("chain", "draw"), loglik + _chain_draw(frame, "log_prior")),
    }
    sampler = summary.get("diagnostics", {}).get("sampler", {})
    n_chains = loglik.shape[0]
    evidence = sampler.get("replicate_log_evidence")
    if evidence is not None and len(evidence) == n_chains:
        variables["log_evidence"] = (("chain",), np.asarray(evidence, float))
    steps = sampler.get("tempering_steps")
    if steps is not None and len(steps) == n_chains:
        variables["tempering_steps"] = (("chain",), np.asarray(steps, int))
    ds = _with_chain_draw(xr.Dataset(variables))
    schedule = sampler.get("schedule")
    if schedule:
        ds.attrs["tempering_beta"] = [float(s["beta"]) for s in schedule]
        ds.attrs["tempering_acceptance"] = [float(s["acceptance"]) for s in schedule]
    if "acceptance" in sampler:
        ds.attrs["acceptance"] = float(np.mean(sampler["acceptance"]))
    ds.attrs["sampler"] = sampler.get("kind", "")
    ds.attrs["converged"] = int(bool(summary.get("diagnostics", {}).get("converged", False)))
    return ds


def _log_likelihood(frame: pd.DataFrame) -> xr.Dataset | None:
    terms = [c for c in frame.columns if c.startswith(_TERM_PREFIX)]
    if not terms:
        return None
    variables = {c[len(_TERM_PREFIX):]: (("chain", "draw"), _chain_draw(frame, c)) for c in terms}
    return _with_chain_draw(xr.Dataset(variables))


def _observed(measurements: pd.DataFrame) -> tuple[xr.Dataset, xr.Dataset]:
    observed, constant = {}, {}
    for name, rows in measurements.groupby("observable", sort=False):
        rows = rows.sort_values("x")
        dim = f"{name}_x"
        coords = {dim: rows["x"].to_numpy()}
        observed[name] = xr.DataArray(rows["value"].to_numpy(), dims=(dim,), coords=coords)
        constant[f"{name}_error"] = xr.DataArray(rows["error"].to_numpy(), dims=(dim,), coords=coords)
    return xr.Dataset(observed), xr.Dataset(constant)


def _posterior_predictive(path: Path) -> xr.Dataset | None:
    if not path.is_file():
        return None
    table = pd.read_parquet(path)
    variables = {}
    for name, rows in table.groupby("observable", sort=False):
        cube = rows.set_index(["chain", "draw", "x"])["y"].to_xarray()
        variables[name] = cube.rename({"x": f"{name}_x"})
    ds = xr.Dataset(variables).transpose("chain", "draw", ...)
    # `draw` keeps the posterior's draw index of each replicate.
    return ds.assign_coords(chain=np.arange(ds.sizes["chain"]), draw=ds["draw"].values.astype(np.int64))


def _inference_data(groups: dict[str, xr.Dataset | None]) -> InferenceData:
    import arviz as az

    present: dict[str, xr.Dataset] = {k: v for k, v in groups.items() if v is not None}
    if hasattr(az, "InferenceData"):
        return az.InferenceData(**present)  # type: ignore[arg-type]  # its stubs know its keywords only
    # ArviZ 1.x, beyond the pinned range, works on DataTree.
    return xr.DataTree.from_dict(present)  # type: ignore[return-value]


def load(run_dir: StrPath) -> InferenceData:
    """One calibration's folder (`mdpipe calibrate --out DIR`, or a case of a
    study or a fit of a diagnosis) as ArviZ InferenceData: `posterior` (θ and
    the discrepancy's hyperparameters, with units and priors as attributes),
    `sample_stats` (log-likelihood, lp, per-replicate evidence and tempering
    where the sampler is SMC), `log_likelihood` (per observable, when the
    observables are independent), `observed_data` and `constant_data` (the
    measurements and their errors), `posterior_predictive` (replicated data),
    and the provenance as attributes of every group."""
    run_dir = Path(run_dir)
    summary = _read_json(run_dir / "summary.json")
    frame = pd.read_parquet(run_dir / "posterior.parquet")
    observed, constant = _observed(pd.read_parquet(run_dir / "measurements.parquet"))
    groups = {
        "posterior": _posterior(frame, summary),
        "sample_stats": _sample_stats(frame, summary),
        "log_likelihood": _log_likelihood(frame),
        "posterior_predictive": _posterior_predictive(run_dir / "posterior_predictive.parquet"),
        "observed_data": observed,
        "constant_data": constant,
    }
    attrs = _attrs(summary)
    for ds in groups.values():
        if ds is not None:
            ds.attrs.update(attrs)
    return _inference_data(groups)


def load_bands(run_dir: StrPath) -> pd.DataFrame:
    """The posterior-predictive bands of `predictions.parquet` (η, η + δ and
    δ at the 2.5, 16, 50, 84 and 97.5 percentiles, on a grid and at the data)."""
    return pd.read_parquet(Path(run_dir) / "predictions.parquet")


@dataclass
class Study:
    """What `mdpipe run` wrote: its cases as a table (`case`, `observables`,
    `kernel`, `converged`, `log_evidence`, then `<parameter>.<statistic>`),
    each case's calibration by `calibration(case)`, the diagnosis when it
    ran; `consistency` and `emulator_vs_data` are empty unless the system
    assesses its cases (the heavy-ion stand-in)."""

    out: Path
    cases: pd.DataFrame
    consistency: pd.DataFrame
    emulator_vs_data: pd.DataFrame
    truth: dict = field(default_factory=dict)

    def calibration(self, case: str) -> InferenceData:
        """The InferenceData of one case (a row of `cases`, by its `case`)."""
        return load(self.out / "calibrate" / case)

    @property
    def diagnosis(self) -> Diagnosis | None:
        folder = self.out / "diagnose"
        return load_diagnosis(folder) if (folder / "diagnosis.json").is_file() else None


def _case_rows(cases: list[dict]) -> pd.DataFrame:
    rows = []
    for case in cases:
        row = {k: case[k] for k in ("case", "kernel", "log_evidence", "converged", "seconds") if k in case}
        row["observables"] = ",".join(case.get("observables", []))
        for name, stats in case.get("parameters", {}).items():
            for key, value in stats.items():
                row[f"{name}.{key}"] = value
        rows.append(row)
    return pd.DataFrame(rows)


def load_study(out_dir: StrPath) -> Study:
    """`mdpipe run`'s output folder: its cases (`calibrate/cases.json`) as a
    table, one row per case, and, for a system that assesses its own cases
    (the heavy-ion stand-in's `study.json`), those checks as tables."""
    out = Path(out_dir).resolve()
    cases = _read_json(out / "calibrate" / "cases.json")
    assessed = out / "study.json"
    study = json.loads(assessed.read_text()) if assessed.is_file() else {}
    return Study(
        out=out,
        cases=_case_rows(study.get("cases") or cases.get("cases", [])),
        consistency=pd.DataFrame(study.get("consistency", [])),
        emulator_vs_data=pd.DataFrame(study.get("emulator_vs_data", [])),
        truth=study.get("truth") or {},
    )


@dataclass
class Diagnosis:
    """`diagnosis.json` as tables: the verdict, the candidates ranked by
    evidence, where the mismatch is, how the repaired fit improved; each
    fit's calibration (`base_md`, `base_no_md`, `candidate_<name>`,
    `repaired_md`) by `fit(name)`."""

    folder: Path
    verdict: dict
    candidates: pd.DataFrame
    mismatch: pd.DataFrame
    improvement: dict
    raw: dict

    @property
    def best(self) -> str:
        return self.verdict.get("best", "")

    @property
    def fits(self) -> list[str]:
        return sorted(p.name for p in self.folder.iterdir() if (p / "summary.json").is_file())

    def fit(self, name: str) -> InferenceData:
        return load(self.folder / name)


def load_diagnosis(folder: StrPath) -> Diagnosis:
    """`mdpipe diagnose --out DIR` (or a study's `diagnose/` folder)."""
    folder = Path(folder)
    raw = _read_json(folder / "diagnosis.json")
    candidates = pd.DataFrame(
        [{k: v for k, v in c.items() if not isinstance(v, (dict, list))} for c in raw.get("candidates", [])]
    )
    mismatch = pd.DataFrame(
        [
            {k: v for k, v in m.items() if k in ("observable", "max_sigma", "x_at_max", "sign", "grows_with_x", "no_md_chi2")}
            for m in raw.get("mismatch", [])
        ]
    )
    return Diagnosis(
        folder=folder,
        verdict=raw.get("verdict", {}),
        candidates=candidates,
        mismatch=mismatch,
        improvement=raw.get("improvement") or {},
        raw=raw,
    )
