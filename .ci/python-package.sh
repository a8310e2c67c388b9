#!/usr/bin/env bash
# The Python package as a user gets it: `pip install .` into a fresh virtual
# environment (ArviZ and the rest from the package index), then the
# package's tests and the example notebook, executed cell by cell; any
# failing cell fails the run.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/mdpipe-target}"

venv="$(mktemp -d)/venv"
python3 -m venv "$venv"
"$venv/bin/pip" install -q --upgrade pip
"$venv/bin/pip" install -q ".[test]"
# One typing style, checked: the annotations must agree with the code.
"$venv/bin/python" -m mypy python/mdpipe

# The notebook runs the decay-counter study into outputs/decay_counter; the
# tests then find it up to date and only load it.
"$venv/bin/python" - <<'PY'
import pathlib, nbformat
from nbclient import NotebookClient
path = pathlib.Path("examples/notebooks/decay_counter.ipynb")
nb = nbformat.read(path, as_version=4)
NotebookClient(nb, timeout=1800, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
print(f"executed {path}: {sum(c.cell_type == 'code' for c in nb.cells)} code cells")
PY
"$venv/bin/python" -m pytest python/tests -q -W ignore::FutureWarning
