"""A calibration folder as one NetCDF or Zarr file that ArviZ reopens with
`from_netcdf` / `from_zarr` (what `mdpipe export` writes)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from ._binary import StrPath
from .loading import load

FORMATS = {"netcdf": ".nc", "zarr": ".zarr"}


def export(run_dir: StrPath, path: StrPath | None = None, format: str = "netcdf") -> Path:
    """Writes the InferenceData of `run_dir` to `path` (default: beside the
    folder's files, `posterior.nc` or `posterior.zarr`), through a temporary
    file renamed into place, and returns the path."""
    if format not in FORMATS:
        raise ValueError(f"format {format!r}: use netcdf or zarr")
    run_dir = Path(run_dir)
    path = Path(path) if path is not None else run_dir / f"posterior{FORMATS[format]}"
    idata = load(run_dir)
    staging = Path(tempfile.mkdtemp(prefix=".export-", dir=path.parent if path.parent.exists() else None))
    try:
        target = staging / path.name
        if format == "netcdf":
            idata.to_netcdf(str(target))
        else:
            idata.to_zarr(str(target))
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(target, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mdpipe export", description=__doc__)
    parser.add_argument("run_dir")
    parser.add_argument("--format", choices=sorted(FORMATS), default="netcdf")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    try:
        written = export(args.run_dir, args.out, args.format)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except Exception as err:  # a damaged Parquet or JSON file: say which folder, not a traceback
        print(f"error: {args.run_dir}: cannot be read as a calibration ({type(err).__name__}: {err})", file=sys.stderr)
        return 2
    print(f"wrote {written}")
    return 0
