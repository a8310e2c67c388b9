"""Finding and running the mdpipe binary that `pip install` put on PATH."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Sequence
from pathlib import Path
from typing import Union

#: A path as a user passes one: a string or any path-like object.
StrPath = Union[str, "os.PathLike[str]"]


class MdpipeError(RuntimeError):
    """The mdpipe command failed; the message holds what it printed last."""


def binary() -> str:
    """The mdpipe executable: $MDPIPE_BIN, else the one installed with this
    package (the environment's scripts folder), else the first on PATH."""
    explicit = os.environ.get("MDPIPE_BIN")
    if explicit:
        return explicit
    name = "mdpipe.exe" if sys.platform == "win32" else "mdpipe"
    beside = Path(sysconfig.get_path("scripts")) / name
    if beside.is_file():
        return str(beside)
    found = shutil.which("mdpipe")
    if found:
        return found
    raise MdpipeError(
        "the mdpipe command was not found: install the package with `pip install .` "
        "from the repository, or set MDPIPE_BIN to the binary's path"
    )


def call(args: Sequence[str], cwd: StrPath | None = None, quiet: bool = False) -> None:
    """Runs `mdpipe ARGS`. Its output (progress bars included) goes to this
    process's terminal as it comes; with `quiet`, it is kept and shown only
    when the command fails."""
    command = [binary(), *map(str, args)]
    if quiet:
        done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
        output = done.stdout + done.stderr
    else:
        done = subprocess.run(command, cwd=cwd, text=True)
        output = ""
    if done.returncode != 0:
        tail = "\n".join(output.strip().splitlines()[-20:])
        raise MdpipeError(f"`{' '.join(command)}` failed with exit code {done.returncode}" + (f":\n{tail}" if tail else ""))
