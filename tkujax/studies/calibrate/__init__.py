"""Calibration of the TKU-X model to the paper's Tables 4-5 (issue 11).

targets.py   the paper's measured rows and the per-row loss
params.py    the fitted parameter vector: names, physically plausible bounds, mapping to
             ModelParams / ControllerParams / the push
evaluate.py  one candidate -> the 8 rows for every reading of Algorithm 1 (MuJoCo C backend)
search.py    CMA-ES (the maintained `cmaes` package) with restarts; the CLI entry point
report.py    JSON / markdown / PNG of a fit, finite-difference sensitivities (identifiability)
"""
