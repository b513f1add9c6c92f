"""`tkujax compare RUN_A RUN_B [RUN_C ...] --out DIR`: where controllers help or hurt.

Inputs are output folders of `tkujax sweep` runs of ONE spec (the same pushes), e.g. control
off, the paper's parameters, a tuned set. The first run is the reference. A run is a folder,
optionally with the control setting to take from it: `DIR:off` or `DIR:on` (default: the
records with control on when the folder has any, else those with control off), so one sweep
with `control = ["off", "on"]` gives both the reference (`DIR:off`) and a controller (`DIR:on`).
The selected records of every run must be the same pushes in the same order: every input
column (impulse or kick, azimuth, height, onset, duration, phase, randomisation, controller-grid
and step columns) is checked, and a mismatch is refused with the column and the first record that
differs named.

Conventions (tkujax.sim.push): azimuth 0 deg = pushed from behind (the force points forward,
+x), 90 deg = pushed from the right (force toward +y, the robot's left), 180 = from the front,
270 = from the left. Sectors are centred on those directions (4 sectors of 90 deg, or 8 of
45 deg: behind-right is centred on 45 deg). The phase is the push onset's phase in the 30 ms
control period (`onset_phase`, 0 = on a controller tick).

Walking sweeps ([walk], a walk_recovery column) pick the walking recovery setting too:
`DIR:recovery-off` or `DIR:recovery-on` (after the control setting if both: `DIR:on:recovery-on`;
default: recovery on when the folder has it), so one sweep with `recovery = ["off", "on"]`
gives the reference and the run of the no-harm verdict. Their phase bands are of the gait
phase at onset (`gait_phase`, 0 = left touchdown) instead of the control period's.

Velocity kicks ([push] kind = "velocity_kick") are banded along kick_mps (m/s) instead of the
impulse (`tkujax.analysis.map_cells.push_size`); the harmed cells then name a kick_mps band.

Diverged records (numerical blow-up) are neither fell nor survived: each run's rates leave
its own diverged records out; paired differences use the records that diverged in neither.

Outputs (in DIR):
  difference_maps.png   per (azimuth, impulse) cell, fall rate of each run minus the
                        reference's (diverging colours: red = falls more = harm, blue = help),
                        hit phase pooled (top row) and per phase band (the rows below); the
                        first column is the reference's own fall rate.
  fall_by_sector.png    fall rate against impulse band per direction sector, one line per run.
  table.csv, table.md   fall rate by direction sector x impulse band x phase band (and phases
                        pooled), with the record counts, per run, and the difference to the
                        reference with its paired standard error.
  verdict.json          per run: overall fall rates, fall(X) / fall(reference), and the
                        "no harm" check: every cell with >= min_pushes pushes (in both runs)
                        where X falls more often than the reference by more than harm_pp
                        percentage points, listed. Cells checked: sector x impulse band x
                        phase band, and the same cells with the phases pooled.
  summary.md            the above for a person.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from tkujax.sim.push import onset_phase
from tkujax.sweeps.chunks import read_manifest
from tkujax.sweeps.early import DECIDED_COLUMN
from tkujax.sweeps.sweep_robot import same_robot
from tkujax.analysis.compare_report import (plot_by_sector, plot_difference_maps, summary_markdown,
                                            table_csv, table_markdown, write_text_atomic)
from tkujax.analysis.map_cells import MAX_AZIMUTH_BINS, bin_axis, push_size
from tkujax.dialects.sweep_spec import PHASE_KEY, RANDOMIZE_FIELDS, SpecError
from tkujax.sweeps.sweep import load, outcome_keys
from tkujax.dialects.walk_table import GAIT_PHASE_KEY
from tkujax.sweeps.sweep_state import require_complete

SECTOR_NAMES = {4: ("behind", "right", "front", "left"),
                8: ("behind", "behind-right", "right", "front-right", "front", "front-left",
                    "left", "behind-left")}
# Columns that are not inputs of a push: outcomes (an early sweep's decision time among them),
# the control setting (selected on), the record number (differs between the control blocks of
# one spec), a replay's state.
NOT_INPUTS = (set(outcome_keys(True, True))
              | {"control", "push_id", "qpos", "walk_recovery", DECIDED_COLUMN})
RECOVERY_SUFFIXES = (":recovery-on", ":recovery-off")
SUBSETS = ("all", "grid", "random")
MATCH_ATOL = 1e-9


@dataclasses.dataclass(frozen=True)
class Run:
    """The selected records of one sweep folder: label, where from, inputs and outcomes."""

    label: str
    path: str
    control: str                       # "on" | "off"
    inputs: dict                       # column -> (n,) array, the push inputs
    fell: np.ndarray                   # (n,) bool
    diverged: np.ndarray               # (n,) bool
    complete: bool                     # every chunk of the sweep is done (sweep_state)
    mark: str = ""                     # "" or "incomplete: k of n chunks"
    recovery: str | None = None        # a walking sweep's recovery setting ("on" | "off")

    @property
    def phase_key(self) -> str:
        """The phase column the bands split: the gait phase of a walking run, else the
        onset's phase in the control period."""
        return PHASE_KEY if self.recovery is None else GAIT_PHASE_KEY


@dataclasses.dataclass(frozen=True)
class Bands:
    """How records are grouped: direction sectors, impulse band edges, phase band count."""

    sectors: int = 4
    impulse_edges: tuple[float, ...] | None = None   # None: impulse_bands equal bands
    impulse_bands: int = 4
    phase_bands: int = 3

    def validate(self) -> Bands:
        if self.sectors not in SECTOR_NAMES:
            raise SpecError(f"sectors must be one of {sorted(SECTOR_NAMES)}, got {self.sectors!r}")
        if not 1 <= self.impulse_bands <= 50:
            raise SpecError(f"impulse_bands must be in [1, 50], got {self.impulse_bands!r}")
        if not 1 <= self.phase_bands <= 30:
            raise SpecError(f"phase_bands must be in [1, 30], got {self.phase_bands!r}")
        if self.impulse_edges is not None:
            e = np.asarray(self.impulse_edges, float)
            if e.size < 2 or not np.all(np.isfinite(e)) or np.any(np.diff(e) <= 0):
                raise SpecError("impulse_edges must be 2 or more increasing finite numbers "
                                f"(N·s), got {list(self.impulse_edges)}")
        return self


def parse_run(arg: str) -> tuple[str, str | None]:
    """'DIR', 'DIR:on' or 'DIR:off' (each optionally followed by ':recovery-on' or
    ':recovery-off') -> (DIR, control or None)."""
    return parse_selection(arg)[:2]


def parse_selection(arg: str) -> tuple[str, str | None, str | None]:
    """A run argument -> (DIR, control or None, walking recovery or None)."""
    recovery = None
    for suffix in RECOVERY_SUFFIXES:
        if arg.endswith(suffix):
            arg, recovery = arg[:-len(suffix)], suffix.rsplit("-", 1)[1]
    for suffix in (":on", ":off"):
        if arg.endswith(suffix):
            return arg[:-len(suffix)], suffix[1:], recovery
    return arg, None, recovery


def load_run(arg: str, label: str | None = None, subset: str = "all",
             allow_incomplete: bool = False) -> Run:
    """The records of one run argument ('DIR[:on|:off]'), see the module doc. An incomplete
    sweep is refused (`tkujax.sweeps.sweep_state.IncompleteSweep`) unless allow_incomplete."""
    if subset not in SUBSETS:
        raise SpecError(f"subset must be one of {SUBSETS}, got {subset!r}")
    path, control, recovery = parse_selection(arg)
    if not Path(path).is_dir():
        raise FileNotFoundError(f"run {arg!r}: {path} is not a folder (a tkujax sweep --out)")
    state = require_complete(path, allow_incomplete, "tkujax compare")
    rec = load(path)
    for key in ("fell", "control", push_size(rec)[0], "azimuth_deg"):
        if key not in rec:
            raise SpecError(f"run {arg!r}: records have no {key!r} column (not a push sweep?)")
    on = rec["control"].astype(bool)
    if control is None:
        control = "on" if on.any() else "off"
    sel = on if control == "on" else ~on
    if subset != "all":
        if "from_grid" not in rec:
            raise SpecError(f"run {arg!r}: subset {subset!r} needs the from_grid column, which "
                            "this sweep predates; use subset 'all'")
        grid = rec["from_grid"].astype(bool)
        sel &= grid if subset == "grid" else ~grid
    sel, recovery = _walk_selection(arg, rec, sel, recovery)
    if not sel.any():
        have = sorted({"on" if c else "off" for c in on})
        raise SpecError(f"run {arg!r}: no records with control {control}"
                        + (f" in the {subset} subset" if subset != "all" else "")
                        + f"; the folder has control {have}")
    inputs = {k: np.asarray(v[sel]) for k, v in rec.items() if k not in NOT_INPUTS}
    if PHASE_KEY not in inputs:        # sweeps written before the phase column existed
        inputs[PHASE_KEY] = onset_phase(inputs["onset_s"])
    n = int(sel.sum())
    diverged = (rec["diverged"][sel].astype(bool) if "diverged" in rec else np.zeros(n, bool))
    setting = control if recovery is None else f"{control}, recovery {recovery}"
    return Run(label=label or f"{Path(path).name} ({setting})", path=str(path), control=control,
               inputs=inputs, fell=rec["fell"][sel].astype(bool), diverged=diverged,
               complete=state.complete, mark=state.mark,
               recovery=recovery)


def _walk_selection(arg: str, rec: dict, sel: np.ndarray, recovery: str | None):
    """(the selection narrowed to one walking recovery setting, the setting) of a walking
    sweep's records (default: recovery on when selected records have it); a standing sweep's
    unchanged (asking for a recovery setting of one is refused)."""
    if "walk_recovery" not in rec:
        if recovery is not None:
            raise SpecError(f"run {arg!r}: ':recovery-{recovery}' selects a walking sweep's "
                            "recovery setting, and this folder's records stand (no [walk])")
        return sel, None
    walk_on = rec["walk_recovery"] > 0.5
    if recovery is None:
        recovery = "on" if (sel & walk_on).any() else "off"
    return sel & (walk_on if recovery == "on" else ~walk_on), recovery


def check_same_pushes(ref: Run, run: Run, ignore: frozenset = frozenset()) -> None:
    """Raise SpecError naming the first difference between two runs' push inputs (columns in
    `ignore` may differ: the robot draws of an unpaired comparison)."""
    who = f"run {run.label!r} ({run.path})"
    against = f"the reference {ref.label!r} ({ref.path})"
    only_ref = sorted(set(ref.inputs) - set(run.inputs))
    only_run = sorted(set(run.inputs) - set(ref.inputs))
    if only_ref or only_run:
        raise SpecError(f"{who} does not have the same input columns as {against}: only in the "
                        f"reference {only_ref}, only in this run {only_run}; compare needs runs "
                        "of one spec")
    n_ref, n_run = len(ref.fell), len(run.fell)
    if n_ref != n_run:
        incomplete = [f"{r.label} ({r.mark})" for r in (ref, run) if not r.complete]
        raise SpecError(f"{who} has {n_run} records with control {run.control}, {against} has "
                        f"{n_ref}" + (f"; incomplete sweep(s) {incomplete}: rerun their "
                                      "`tkujax sweep` command to finish them"
                                      if incomplete else "; compare needs runs of one spec"))
    for k in sorted(set(ref.inputs) - ignore):
        a = np.asarray(ref.inputs[k], float)
        b = np.asarray(run.inputs[k], float)
        same = np.isclose(a, b, rtol=0.0, atol=MATCH_ATOL, equal_nan=True)
        if not same.all():
            i = int(np.argmin(same))
            raise SpecError(f"{who} does not push like {against}: column {k!r} differs in "
                            f"{int((~same).sum())} of {n_ref} records (first: record {i}, "
                            f"{b[i]:.6g} vs {a[i]:.6g}); compare needs runs of one spec")


def sector_index(azimuth_deg: np.ndarray, sectors: int) -> np.ndarray:
    """Sector of each azimuth: 0 = behind (centred on 0 deg), counting toward 90 = right."""
    width = 360.0 / sectors
    return (np.floor(np.mod(np.asarray(azimuth_deg, float) + width / 2, 360.0) / width)
            .astype(int) % sectors)


def impulse_edges(impulse_ns: np.ndarray, bands: Bands) -> np.ndarray:
    """The impulse band edges (N·s): the given ones (which must cover every impulse), or
    `impulse_bands` equal bands from the smallest impulse to the largest."""
    j = np.asarray(impulse_ns, float)
    if bands.impulse_edges is not None:
        e = np.asarray(bands.impulse_edges, float)
        if j.min() < e[0] - MATCH_ATOL or j.max() > e[-1] + MATCH_ATOL:
            raise SpecError(f"impulse_edges [{e[0]:g} .. {e[-1]:g}] N·s must cover every "
                            f"impulse; the runs have {j.min():g} .. {j.max():g} N·s")
        return e
    lo, hi = float(j.min()), float(j.max())
    if hi <= lo:
        return np.array([lo, lo + 1e-9])
    return np.linspace(lo, hi, bands.impulse_bands + 1)


def band_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Band of each value: [e0, e1), [e1, e2), ..., [e_{n-1}, e_n] (the last one closed)."""
    idx = np.searchsorted(edges, np.asarray(values, float) + 1e-12, side="right") - 1
    return np.clip(idx, 0, len(edges) - 2)


def phase_index(phase: np.ndarray, n_bands: int) -> np.ndarray:
    return np.clip(np.floor(np.asarray(phase, float) * n_bands + 1e-9).astype(int), 0,
                   n_bands - 1)


def _rates(cell: np.ndarray, n_cells: int, fell: np.ndarray, ok: np.ndarray):
    """(falls, count) per cell over the records with ok."""
    falls = np.bincount(cell[ok], fell[ok].astype(float), n_cells)
    count = np.bincount(cell[ok], minlength=n_cells).astype(float)
    return falls, count


def fall_difference(cell: np.ndarray, n_cells: int, ref: Run, run: Run, unpaired: bool = False):
    """Per cell: mean paired difference fell(run) - fell(ref) and its standard error, over the
    records that diverged in neither run. unpaired: the two runs' robots are independent draws,
    so the standard error is that of a difference of two independent rates."""
    if unpaired:
        (fa, na), (fb, nb) = (_rates(cell, n_cells, r.fell, ~r.diverged) for r in (ref, run))
        with np.errstate(invalid="ignore", divide="ignore"):
            pa, pb = fa / na, fb / nb
            se = np.sqrt(pa * (1 - pa) / na + pb * (1 - pb) / nb)
        return pb - pa, np.where((na > 1) & (nb > 1), se, np.nan)
    ok = ~(ref.diverged | run.diverged)
    d = run.fell.astype(float) - ref.fell.astype(float)
    n = np.bincount(cell[ok], minlength=n_cells).astype(float)
    s1 = np.bincount(cell[ok], d[ok], n_cells)
    s2 = np.bincount(cell[ok], d[ok] ** 2, n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        var = (s2 - n * mean ** 2) / (n - 1)
        se = np.sqrt(np.maximum(var, 0.0) / n)
    return mean, np.where(n > 1, se, np.nan)


def cell_table(runs: list[Run], bands: Bands, unpaired: bool = False) -> dict:
    """Fall rates per (sector, impulse band, phase band) and per (sector, impulse band) with the
    phases pooled (phase band -1), for every run; and the differences to runs[0].

    Returns dict(sector_names, impulse_edges, phase_edges, rows) with one row per cell:
    dict(sector, impulse_lo, impulse_hi, phase_lo, phase_hi, phase ("all" or "lo-hi"), and per
    run label: n, falls, rate; per non-reference run: diff_pp, se_pp)."""
    ref = runs[0]
    names = SECTOR_NAMES[bands.sectors]
    size, label = push_size(ref.inputs)
    edges = impulse_edges(ref.inputs[size], bands)
    n_j, n_p, n_s = len(edges) - 1, bands.phase_bands, bands.sectors
    s = sector_index(ref.inputs["azimuth_deg"], n_s)
    j = band_index(ref.inputs[size], edges)
    p = phase_index(ref.inputs[ref.phase_key], n_p)
    phase_edges = np.linspace(0.0, 1.0, n_p + 1)
    levels = [("phase", (s * n_j + j) * n_p + p, n_s * n_j * n_p),
              ("pooled", s * n_j + j, n_s * n_j)]
    rows = []
    for level, cell, n_cells in levels:
        stats = {r.label: _rates(cell, n_cells, r.fell, ~r.diverged) for r in runs}
        paired = {r.label: fall_difference(cell, n_cells, ref, r, unpaired) for r in runs[1:]}
        for c in range(n_cells):
            if level == "phase":
                si, ji, pi = c // (n_j * n_p), (c // n_p) % n_j, c % n_p
            else:
                si, ji, pi = c // n_j, c % n_j, -1
            if all(stats[r.label][1][c] == 0 for r in runs):
                continue
            row = dict(sector=names[si], impulse_lo=float(edges[ji]),
                       impulse_hi=float(edges[ji + 1]),
                       phase="all" if pi < 0 else
                       f"{phase_edges[pi]:.2f}-{phase_edges[pi + 1]:.2f}",
                       phase_lo=0.0 if pi < 0 else float(phase_edges[pi]),
                       phase_hi=1.0 if pi < 0 else float(phase_edges[pi + 1]), runs={})
            for r in runs:
                falls, count = stats[r.label][0][c], stats[r.label][1][c]
                entry = dict(n=int(count), falls=int(falls),
                             rate=float(falls / count) if count else None)
                if r is not ref:
                    ref_rate = row["runs"][ref.label]["rate"]
                    entry["diff_pp"] = (None if ref_rate is None or entry["rate"] is None
                                        else 100.0 * (entry["rate"] - ref_rate))
                    se = paired[r.label][1][c]
                    entry["se_pp"] = float(100 * se) if np.isfinite(se) else None
                row["runs"][r.label] = entry
            rows.append(row)
    return dict(sector_names=list(names), impulse_edges=edges.tolist(),
                phase_edges=phase_edges.tolist(), rows=rows, size_key=size, size_label=label)


def verdict(runs: list[Run], table: dict, min_pushes: int = 100, harm_pp: float = 2.0) -> dict:
    """Per non-reference run: overall fall rates and their ratio, and the harmed cells (>=
    min_pushes pushes in both runs, fall rate above the reference's by more than harm_pp
    percentage points)."""
    if not isinstance(min_pushes, int) or isinstance(min_pushes, bool) or min_pushes < 1:
        raise SpecError(f"min_pushes must be an integer >= 1, got {min_pushes!r}")
    if not (isinstance(harm_pp, (int, float)) and 0.0 <= harm_pp <= 100.0):
        raise SpecError(f"harm_pp must be in [0, 100] percentage points, got {harm_pp!r}")
    ref = runs[0]
    ref_rate = float(ref.fell[~ref.diverged].mean()) if (~ref.diverged).any() else None
    out = {}
    for r in runs[1:]:
        rate = float(r.fell[~r.diverged].mean()) if (~r.diverged).any() else None
        checked, harmed = 0, []
        for row in table["rows"]:
            a, b = row["runs"][ref.label], row["runs"][r.label]
            if min(a["n"], b["n"]) < min_pushes:
                continue
            checked += 1
            # Rounded: 22/100 - 20/100 is 2.0000000000000018 pp in floating point.
            if round(b["diff_pp"], 9) > harm_pp:
                harmed.append(dict(sector=row["sector"], **{table["size_key"]: [
                                       row["impulse_lo"], row["impulse_hi"]]},
                                   phase=row["phase"], n=min(a["n"], b["n"]),
                                   reference_rate=a["rate"], rate=b["rate"],
                                   diff_pp=b["diff_pp"], se_pp=b["se_pp"],
                                   beyond_2se=b["se_pp"] is not None
                                   and b["diff_pp"] - harm_pp > 2 * b["se_pp"]))
        ratio = (None if rate is None or not ref_rate else rate / ref_rate)
        out[r.label] = dict(
            path=r.path, control=r.control, n=int((~r.diverged).sum()),
            n_diverged=int(r.diverged.sum()), fall_rate=rate, reference_fall_rate=ref_rate,
            ratio_to_reference=ratio, cells_checked=checked, harmed_cells=harmed,
            no_harm=not harmed, n_harmed_beyond_2se=sum(h["beyond_2se"] for h in harmed))
    return dict(reference=dict(label=ref.label, path=ref.path, control=ref.control,
                               n=int((~ref.diverged).sum()), n_diverged=int(ref.diverged.sum()),
                               fall_rate=ref_rate),
                min_pushes=min_pushes, harm_pp=harm_pp, runs=out)


def map_axis(values: np.ndarray, max_bins: int, period: float | None = None):
    """(bin centres, bin of each value): tkujax map's axes, with the empty bins kept."""
    return bin_axis(values, max_bins, period, keep_empty=True)


def difference_cells(runs: list[Run], azimuth_bins: int = 24, impulse_bins: int = 12,
                     phase_bands: int = 3) -> dict:
    """Per (azimuth, impulse) cell (`map_axis`): counts and fall rates of every run, phases
    pooled and per phase band.

    Returns dict(azimuths, impulses, bands: [(title, {label: (rate, count)})])."""
    if not 1 <= azimuth_bins <= MAX_AZIMUTH_BINS:
        raise SpecError(f"azimuth_bins must be in [1, {MAX_AZIMUTH_BINS}], got {azimuth_bins!r}")
    if not 1 <= impulse_bins <= 48:
        raise SpecError(f"impulse_bins must be in [1, 48], got {impulse_bins!r}")
    ref = runs[0]
    azs, ia = map_axis(np.mod(ref.inputs["azimuth_deg"], 360.0), azimuth_bins, 360.0)
    js, ij = map_axis(ref.inputs[push_size(ref.inputs)[0]], impulse_bins)
    p = phase_index(ref.inputs[ref.phase_key], phase_bands)
    n_cells = len(azs) * len(js)
    cell = ia * len(js) + ij
    edges = np.linspace(0, 1, phase_bands + 1)
    selections = [("all phases", np.ones(len(cell), bool))] + [
        (f"phase {edges[b]:.2f}-{edges[b + 1]:.2f}", p == b) for b in range(phase_bands)]
    out = []
    for title, sel in selections:
        per = {}
        for r in runs:
            falls, count = _rates(cell, n_cells, r.fell, sel & ~r.diverged)
            with np.errstate(invalid="ignore", divide="ignore"):
                rate = np.where(count > 0, falls / np.maximum(count, 1), np.nan)
            per[r.label] = (rate.reshape(len(azs), len(js)), count.reshape(len(azs), len(js)))
        out.append((title, per))
    return dict(azimuths=azs, impulses=js, bands=out, size_label=push_size(ref.inputs)[1])


def compare_runs(run_args: list[str], out: str | Path, labels: list[str] | None = None,
                 bands: Bands = Bands(), min_pushes: int = 100, harm_pp: float = 2.0,
                 subset: str = "all", azimuth_bins: int = 24, impulse_bins: int = 12,
                 min_map_count: int = 10, unpaired_robots: bool = False,
                 robot=None, allow_incomplete: bool = False) -> dict:
    """Compare sweep runs against the first (see the module doc); write the outputs into out.

    unpaired_robots: accept runs whose model randomisation columns differ (independent robot
    draws from one distribution, e.g. the control-off and control-on blocks of sweeps made
    before the draws were shared); the standard errors are then unpaired.

    run_args: 'DIR', 'DIR:on' or 'DIR:off' each. labels: one per run (default: the folder's
    name and the control setting). robot: the Robot the runs ran on (None: TKU-X;
    checked against their manifests; the runs must share one robot). An incomplete sweep is
    refused (`tkujax.sweeps.sweep_state.IncompleteSweep`, naming the folder and k of n
    chunks); with allow_incomplete the runs of one spec whose records still match are
    compared, the summary and verdict marked (verdict's `incomplete`). Returns dict(verdict,
    table, files, summary)."""
    if len(run_args) < 2:
        raise SpecError(f"compare needs 2 or more runs (the first is the reference), got "
                        f"{len(run_args)}")
    if labels is not None and len(labels) != len(run_args):
        raise SpecError(f"labels: {len(labels)} given for {len(run_args)} runs; give one per run")
    if not isinstance(min_map_count, int) or min_map_count < 1:
        raise SpecError(f"min_map_count must be an integer >= 1, got {min_map_count!r}")
    bands = bands.validate()
    runs = [load_run(a, None if labels is None else labels[i], subset, allow_incomplete)
            for i, a in enumerate(run_args)]
    same_robot([(a, read_manifest(Path(parse_run(a)[0]))) for a in run_args], robot)
    if len({r.phase_key for r in runs}) > 1:
        raise SpecError("compare: a walking sweep's runs compare only with walking runs (their "
                        "phase is the gait's)")
    seen = set()
    for i, r in enumerate(runs):                  # unique labels: they key every table
        if r.label in seen:
            runs[i] = dataclasses.replace(r, label=f"{r.label} #{i + 1}")
        seen.add(runs[i].label)
    ignore = frozenset(RANDOMIZE_FIELDS) | {"robot_id"} if unpaired_robots else frozenset()
    for r in runs[1:]:
        check_same_pushes(runs[0], r, ignore)
    table = cell_table(runs, bands, unpaired_robots)
    v = verdict(runs, table, min_pushes, harm_pp)
    cells = difference_cells(runs, azimuth_bins, impulse_bins, bands.phase_bands)

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lab = [r.label for r in runs]
    files = [out / "difference_maps.png", out / "fall_by_sector.png", out / "table.csv",
             out / "table.md", out / "verdict.json", out / "summary.md"]
    plot_difference_maps(cells, lab, files[0], min_map_count)
    plot_by_sector(table, lab, files[1])
    write_text_atomic(files[2], table_csv(table, lab))
    write_text_atomic(files[3], table_markdown(table, lab))
    incomplete = {r.label: r.mark for r in runs if r.mark}
    edges_key = table["size_key"].replace("_", "_edges_", 1)     # impulse_edges_ns
    write_text_atomic(files[4], json.dumps(dict(v, incomplete=incomplete,
                                                unpaired_robots=unpaired_robots, bands=dict(
        sectors=table["sector_names"], **{edges_key: table["impulse_edges"]},
        phase_edges=table["phase_edges"])), indent=1))
    text = summary_markdown(runs, table, v, [str(f) for f in files])
    if runs[0].recovery is not None:
        text = text.replace("phase = the onset's phase in the 30 ms control period",
                            "phase = the gait phase at onset (0 = left touchdown, 0.5 = right "
                            "touchdown); the robots walk")
    if unpaired_robots:
        text = text.replace("\n", "\n\n**Unpaired robots:** the runs' model randomisation draws "
                            "differ, so every standard error here is that of two independent "
                            "rates, not a paired one.\n", 1)
    write_text_atomic(files[5], text)
    return dict(verdict=v, table=table, files=[str(f) for f in files], summary=str(files[5]))
