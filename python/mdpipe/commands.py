"""`mdpipe run`, `calibrate` and `diagnose` from Python, returning what they wrote."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterable, Optional, Sequence

from ._binary import call
from .loading import Diagnosis, Study, load, load_diagnosis, load_study

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib


def _options(**options) -> list:
    args = []
    for key, value in options.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            args.append(flag)
        elif isinstance(value, (list, tuple)):
            args += [flag, ",".join(map(str, value))]
        else:
            args += [flag, str(value)]
    return args


def study_out(config, cwd: Optional[Path] = None) -> Path:
    """Where `mdpipe run CONFIG` writes without `--out`: `[run] out`
    (relative to the config), else `outputs/<name>` in the working folder."""
    config = Path(config)
    table = tomllib.loads(config.read_text())
    out = table.get("run", {}).get("out")
    if out is not None:
        return (config.parent / out).resolve()
    return (Path(cwd or Path.cwd()) / "outputs" / table["name"]).resolve()


def run(
    config,
    out=None,
    *,
    seed: Optional[int] = None,
    executor: Optional[str] = None,
    stage: Optional[str] = None,
    force: bool = False,
    cwd=None,
    quiet: bool = False,
) -> Study:
    """`mdpipe run CONFIG`: the whole study; returns `load_study` of its folder."""
    out = Path(out) if out is not None else study_out(config, cwd)
    args = ["run", str(config), "--out", str(out)]
    args += _options(seed=seed, executor=executor, stage=stage, force=force)
    call(args, cwd=cwd, quiet=quiet)
    return load_study(out)


def calibrate(
    config,
    out,
    *,
    seed: Optional[int] = None,
    kernel: Optional[str] = None,
    observables: Optional[Sequence[str]] = None,
    sampler: Optional[str] = None,
    cwd=None,
    quiet: bool = False,
):
    """`mdpipe calibrate CONFIG --out OUT`; returns `load(OUT)` (InferenceData)."""
    args = ["calibrate", str(config), "--out", str(out)]
    args += _options(seed=seed, kernel=kernel, observables=observables, sampler=sampler)
    call(args, cwd=cwd, quiet=quiet)
    return load(out)


def diagnose(
    config,
    out,
    *,
    seed: Optional[int] = None,
    data=None,
    discover: Optional[bool] = None,
    cwd=None,
    quiet: bool = False,
    extra: Iterable[str] = (),
) -> Diagnosis:
    """`mdpipe diagnose CONFIG --out OUT`; returns `load_diagnosis(OUT)`.
    `discover=True` searches for undeclared terms even when a candidate
    explains the data, `False` never."""
    args = ["diagnose", str(config), "--out", str(out)]
    args += _options(seed=seed, data=data)
    if discover is not None:
        args.append("--discover" if discover else "--no-discover")
    args += list(extra)
    call(args, cwd=cwd, quiet=quiet)
    return load_diagnosis(out)
