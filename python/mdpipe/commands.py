"""`mdpipe run`, `calibrate` and `diagnose` from Python, returning what they wrote."""

from __future__ import annotations

import sys
from pathlib import Path
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from ._binary import StrPath, call
from .loading import Diagnosis, Study, load, load_diagnosis, load_study

if TYPE_CHECKING:
    from arviz import InferenceData

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib


def _options(**options: object) -> list[str]:
    args: list[str] = []
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


def study_out(config: StrPath, cwd: StrPath | None = None) -> Path:
    """Where `mdpipe run CONFIG` writes without `--out`: `[run] out`
    (relative to the config), else `outputs/<name>` in the working folder."""
    config = Path(config)
    table = tomllib.loads(config.read_text())
    out = table.get("run", {}).get("out")
    if out is not None:
        return (config.parent / out).resolve()
    return (Path(cwd or Path.cwd()) / "outputs" / table["name"]).resolve()


def run(
    config: StrPath,
    out: StrPath | None = None,
    *,
    seed: int | None = None,
    executor: str | None = None,
    stage: str | None = None,
    force: bool = False,
    cwd: StrPath | None = None,
    quiet: bool = False,
) -> Study:
    """`mdpipe run CONFIG`: the whole study; returns `load_study` of its folder."""
    out = Path(out) if out is not None else study_out(config, cwd)
    args = ["run", str(config), "--out", str(out)]
    args += _options(seed=seed, executor=executor, stage=stage, force=force)
    call(args, cwd=cwd, quiet=quiet)
    return load_study(out)


def calibrate(
    config: StrPath,
    out: StrPath,
    *,
    seed: int | None = None,
    kernel: str | None = None,
    observables: Sequence[str] | None = None,
    sampler: str | None = None,
    data: StrPath | None = None,
    time_limit: float | None = None,
    cwd: StrPath | None = None,
    quiet: bool = False,
) -> InferenceData:
    """`mdpipe calibrate CONFIG --out OUT`; returns `load(OUT)` (InferenceData).
    `data` replaces the config's measurements (`--data`); `time_limit`
    (seconds, `--time-limit`) stops the sampler cleanly with its state saved
    in OUT/.checkpoint, and the same call resumes it."""
    args = ["calibrate", str(config), "--out", str(out)]
    args += _options(
        seed=seed, kernel=kernel, observables=observables, sampler=sampler, data=data, time_limit=time_limit
    )
    call(args, cwd=cwd, quiet=quiet)
    return load(out)


def diagnose(
    config: StrPath,
    out: StrPath,
    *,
    seed: int | None = None,
    data: StrPath | None = None,
    discover: bool | None = None,
    cwd: StrPath | None = None,
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
