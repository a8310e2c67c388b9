"""mdpipe from Python: run it, and read what it wrote as ArviZ and pandas.

    import mdpipe
    study = mdpipe.run("examples/decay_counter/study.toml")
    idata = study.calibration(study.cases.case[0])      # ArviZ InferenceData
    print(study.diagnosis.verdict["statement"])

The package is a thin layer over the `mdpipe` command installed with it:
the commands run as in the terminal (their progress shown), and their
artifacts are loaded afterwards.
"""

from __future__ import annotations

from ._binary import MdpipeError, binary
from .commands import calibrate, diagnose, run
from .export import export
from .loading import Diagnosis, Study, load, load_bands, load_diagnosis, load_study

__all__ = [
    "Diagnosis",
    "MdpipeError",
    "Study",
    "binary",
    "calibrate",
    "diagnose",
    "export",
    "load",
    "load_bands",
    "load_diagnosis",
    "load_study",
    "run",
]
