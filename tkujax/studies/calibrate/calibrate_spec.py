"""Calibration specs: the TOML schema of `tkujax calibrate` and its validation.

[fit]
params = [...]            subset of params.NAMES to fit (default: all but params.NEUTRAL's, the
                          front hit relative to the back one); the others are held at the
                          default model's values (params.base_vector())
readings = [...]          subset of params.READINGS (default: all): one fit per reading
rows = "all"              "all" (8 rows) or "table4" (pushes from behind only)
heldout = true            with rows = "all": also fit on Table 4 alone and predict Table 5
hit_phases_ms = [0]       hit phases after the 30 ms controller tick
criterion_weight = 0      > 0: add this x the shortfall below 80 % of each row's paper outcome
                          and the probability of a step against the paper's way (run.py)
contact_times_ms = [20]   ball contact times (the push's half-sine duration); the loss is the
                          mean over every (hit phase, contact time): an expected loss
[fit.bounds]              name = [lo, hi]: narrower bounds (never wider than params.py's)
[fit.start]               name = value: the search's starting point (default: the base model)
[search]
budget_s, max_evals       wall seconds of this invocation and/or total candidates (at least one)
popsize, restarts         CMA-ES population and the number of IPOP restarts (doubling it)
workers, seed, sigma0     parallel processes (0: this one), CMA seed, initial step (unit cube)
backend = "mujoco"        "mujoco": MuJoCo C on the CPU, one candidate per process; "mjx": a
                          whole generation per compiled MJX call (a GPU)
robots_per_call = 32      mjx: candidate robots per call (the batch is padded to it)
[report]
sensitivity = true        finite-difference sensitivities at the best fit (2 runs per parameter)
ensemble_tolerance = 1.0  write ensemble.json: the candidates within this loss of the best
                          (absent: no ensemble); ensemble_max caps its members (default 64)
island_points = 40        island widths: slices of this many points per fitted parameter through
                          the ensemble's default member (0: none; needs ensemble_tolerance)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from tkujax.studies.calibrate import fit_vector as P
from tkujax.dialects.validation import (SpecError, boolean, choice, distinct_list, integer,
                                        names, number, read_toml, string, table)

ROWS_CHOICES = ("all", "table4")
MAX_PHASE_MS = 30.0                  # the controller's sampling period
DEFAULT_CONTACT_MS = 20.0            # tkujax.sim.push.DEFAULT_DURATION_S
CONTACT_RANGE_MS = (5.0, 60.0)       # a ball on a robot: a few ms (hard) to tens of ms (soft)
BACKENDS = ("mujoco", "mjx")


@dataclasses.dataclass(frozen=True)
class CalibrateSpec:
    name: str
    params: tuple[str, ...]                         # fitted (searched) names, params.NAMES order
    bounds: dict[str, tuple[float, float]]          # every name -> (lo, hi), params.py units
    start: dict[str, float]                         # every name -> start / held value
    readings: tuple[str, ...]
    rows: str                                       # "all" | "table4"
    heldout: bool
    hit_phases_ms: tuple[float, ...]
    contact_times_ms: tuple[float, ...]
    criterion_weight: float
    budget_s: float | None
    max_evals: int | None
    popsize: int
    restarts: int
    workers: int
    seed: int
    sigma0: float
    sensitivity: bool
    backend: str = "mujoco"
    robots_per_call: int = 32
    ensemble_tolerance: float | None = None
    ensemble_max: int = 64
    island_points: int = 0

    @property
    def samples(self) -> tuple:
        """Every (hit phase, contact time) the loss averages over, phase-major."""
        from tkujax.studies.calibrate.paper_rows import Sample
        return tuple(Sample(p, c) for p in self.hit_phases_ms for c in self.contact_times_ms)

    @property
    def objectives(self) -> tuple[str, ...]:
        """Fitted objectives: "ALL" (8 rows) and/or "T4" (Table 4; Table 5 held out)."""
        if self.rows == "table4":
            return ("T4",)
        return ("ALL", "T4") if self.heldout else ("ALL",)

    def fit_digest(self) -> str:
        """What an archived candidate's meaning depends on: a rerun into the same folder with a
        different digest would mix incomparable losses, so run_calibrate refuses it."""
        # Held names at their neutral value (params.NEUTRAL) leave the digest as it was before
        # they existed, so archives of older fits still resume.
        held = {k for k, v in P.NEUTRAL.items()
                if k not in self.params and self.start.get(k) == v}
        start = {k: v for k, v in self.start.items() if k not in held}
        bounds = {k: v for k, v in self.bounds.items() if k not in held}
        key = dict(params=self.params, bounds=bounds, start=start,
                   readings=self.readings, hit_phases_ms=self.hit_phases_ms)
        if self.contact_times_ms != (DEFAULT_CONTACT_MS,):   # fits of one contact time: as before
            key["contact_times_ms"] = self.contact_times_ms
        if self.criterion_weight:
            key["criterion_weight"] = self.criterion_weight
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def parse_calibrate_spec(data: dict) -> CalibrateSpec:
    """Validate a parsed calibrate TOML document (SpecError names the key and allowed range)."""
    table("top level", data, {"fit", "search", "report"})
    fit = _parse_fit(data)
    return CalibrateSpec(**fit, **_parse_search(data), **_parse_report(data))


def _parse_fit(data: dict) -> dict:
    """The [fit] table: CalibrateSpec fields by name."""
    fit = table("fit", data.get("fit", {}), {"name", "description", "params", "readings",
                                             "rows", "heldout", "hit_phases_ms",
                                             "contact_times_ms", "criterion_weight",
                                             "bounds", "start"})
    for k in ("name", "description"):
        if k in fit:
            string(f"fit.{k}", fit[k])
    # Default: every parameter but the NEUTRAL ones (added later; a fit names them to move them).
    fitted = names("fit.params", fit.get("params", list(P.DEFAULT_FIT)), P.NAMES)
    out = dict(
        name=fit.get("name", "calibrate"), params=fitted,
        readings=names("fit.readings", fit.get("readings", list(P.READINGS)), P.READINGS),
        rows=choice("fit.rows", fit.get("rows", "all"), ROWS_CHOICES),
        heldout=boolean("fit.heldout", fit.get("heldout", True)))
    phases = distinct_list("fit.hit_phases_ms", fit.get("hit_phases_ms", [0.0]),
                           f"numbers in [0, {MAX_PHASE_MS:g}) ms")
    phases = tuple(number(f"fit.hit_phases_ms[{i}]", v, 0.0, MAX_PHASE_MS, "ms")
                   for i, v in enumerate(phases))
    if MAX_PHASE_MS in phases:              # 30 ms is the next tick: phase 0 again
        raise SpecError(f"fit.hit_phases_ms: expected numbers in [0, {MAX_PHASE_MS:g}) ms "
                        f"(30 ms is the next tick, i.e. phase 0), got {list(phases)}")
    lo, hi = CONTACT_RANGE_MS
    contacts = distinct_list("fit.contact_times_ms",
                             fit.get("contact_times_ms", [DEFAULT_CONTACT_MS]),
                             f"numbers in [{lo:g}, {hi:g}] ms")
    contacts = tuple(number(f"fit.contact_times_ms[{i}]", v, lo, hi, "ms")
                     for i, v in enumerate(contacts))
    out.update(hit_phases_ms=phases, contact_times_ms=contacts,
               criterion_weight=number("fit.criterion_weight", fit.get("criterion_weight", 0.0),
                                       0.0, 1e4))
    bounds = _parse_bounds(fit, fitted)
    return dict(out, bounds=bounds, start=_parse_start(fit, fitted, bounds))


def _parse_bounds(fit: dict, fitted: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    """fit.bounds: {name: (lo, hi)}, each within (never wider than) params.py's bound."""
    bounds = {p.name: (p.lo, p.hi) for p in P.PARAMS}
    for key, value in table("fit.bounds", fit.get("bounds", {}), P.NAMES).items():
        p = P.PARAMS[P.NAMES.index(key)]
        unit = " (log10)" if p.log else ""
        if key not in fitted:
            raise SpecError(f"fit.bounds.{key}: {key} is not fitted (fit.params); its value is "
                            "held, a bound would have no effect")
        if not (isinstance(value, list) and len(value) == 2):
            raise SpecError(f"fit.bounds.{key}: expected [lo, hi] within the physically "
                            f"plausible [{p.lo:g}, {p.hi:g}]{unit}, got {value!r}")
        lo, hi = value
        for v, side in ((lo, "lo"), (hi, "hi")):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise SpecError(f"fit.bounds.{key}: {side} must be a number, got {v!r}")
        if lo < p.lo or hi > p.hi:
            raise SpecError(f"fit.bounds.{key}: [{lo:g}, {hi:g}]{unit} widens the physically "
                            f"plausible bound [{p.lo:g}, {p.hi:g}] of params.py ({p.why}); "
                            "a spec may only narrow it")
        if not lo < hi:
            raise SpecError(f"fit.bounds.{key}: lower bound {lo:g} must be below upper "
                            f"bound {hi:g}")
        bounds[key] = (float(lo), float(hi))
    return bounds


def _parse_start(fit: dict, fitted: tuple[str, ...], bounds: dict) -> dict[str, float]:
    """fit.start over the base model's values; every fitted start inside its bounds."""
    start = dict(P.as_dict(P.base_vector()))
    for key, value in table("fit.start", fit.get("start", {}), P.NAMES).items():
        lo, hi = bounds[key]
        start[key] = number(f"fit.start.{key}", value, lo, hi)
    for key in fitted:
        lo, hi = bounds[key]
        if not lo <= start[key] <= hi:
            raise SpecError(f"fit.start.{key}: the base model's value {start[key]:g} lies outside "
                            f"fit.bounds.{key} [{lo:g}, {hi:g}]; give a start inside them")
    return start


def _parse_search(data: dict) -> dict:
    """The [search] table: the CMA-ES budget, population, restarts and backend."""
    search = table("search", data.get("search", {}), {"budget_s", "max_evals", "popsize",
                                                      "restarts", "workers", "seed", "sigma0",
                                                      "backend", "robots_per_call"})
    budget = search.get("budget_s")
    budget = None if budget is None else number("search.budget_s", budget, 1.0, 30 * 86400.0, "s")
    max_evals = search.get("max_evals")
    max_evals = None if max_evals is None else integer("search.max_evals", max_evals, 1,
                                                       10_000_000)
    if budget is None and max_evals is None:
        raise SpecError("search: give budget_s (wall seconds) and/or max_evals (candidates)")
    return dict(
        budget_s=budget, max_evals=max_evals,
        popsize=integer("search.popsize", search.get("popsize", 8), 2, 4096),
        restarts=integer("search.restarts", search.get("restarts", 4), 0, 64),
        workers=integer("search.workers", search.get("workers", 0), 0, 1024),
        seed=integer("search.seed", search.get("seed", 0), 0, 2**31 - 1),
        sigma0=number("search.sigma0", search.get("sigma0", 0.25), 1e-3, 1.0, "(unit cube)"),
        backend=choice("search.backend", search.get("backend", "mujoco"), BACKENDS),
        robots_per_call=integer("search.robots_per_call", search.get("robots_per_call", 32), 1,
                                4096))


def _parse_report(data: dict) -> dict:
    """The [report] table: sensitivity, the ensemble's tolerance and size, island points."""
    report = table("report", data.get("report", {}), {"sensitivity", "ensemble_tolerance",
                                                      "ensemble_max", "island_points"})
    sens = boolean("report.sensitivity", report.get("sensitivity", True))
    tol = report.get("ensemble_tolerance")
    tol = None if tol is None else number("report.ensemble_tolerance", tol, 1e-6, 1e3, "(loss)")
    ens_max = integer("report.ensemble_max", report.get("ensemble_max", 64), 2, 4096)
    points = integer("report.island_points", report.get("island_points", 0), 0, 400)
    if points and (points < 5 or tol is None):
        raise SpecError(f"report.island_points: expected 0, or 5-400 together with "
                        f"report.ensemble_tolerance, got {points!r}"
                        f"{'' if tol is not None else ' without ensemble_tolerance'}")
    return dict(sensitivity=sens, ensemble_tolerance=tol, ensemble_max=ens_max,
                island_points=points)


def load_calibrate_spec(path: str | Path) -> CalibrateSpec:
    return parse_calibrate_spec(read_toml(path))
