"""Calibration of the TKU-X model to the paper's Tables 4-5.

targets.py   the paper's measured rows and the per-row loss
params.py    the fitted parameter vector: names, physically plausible bounds, mapping to
             ModelParams / ControllerParams / the push
evaluate.py  one candidate -> the 8 rows for every reading of Algorithm 1 (MuJoCo C backend)
report.py    JSON / markdown / PNG of a fit, finite-difference sensitivities (identifiability)
spec.py      the TOML spec of `tkujax calibrate`: validation, errors naming key and range
scoring.py   one candidate's score: its rows against the paper, loss per objective and reading
run.py       run_calibrate(spec, out): the resumable search (`tkujax calibrate`)
summary.py   the report of a fit: best.json, calibration.md, the trace plot, the best parameters
refine.py    gradient refinement of a fit through MJX (`tkujax refine`)

The research tools around a fit (slices, sampling probes, phase robustness, one-at-a-time
sensitivities, the MJX cross-check, the many-core run) live in scripts/ at the repository root.
"""

from tkujax.studies.calibrate.calibrate_command import run_calibrate

__all__ = ["run_calibrate"]
