"""`tkujax compare RUN_A RUN_B [RUN_C ...] --out DIR`: where controllers help or hurt.

Inputs are output folders of `tkujax sweep` runs of ONE spec (the same pushes), e.g. control
off, the paper's parameters, a tuned set. The first run is the reference. A run is a folder,
optionally with the control setting to take from it: `DIR:off` or `DIR:on` (default: the
records with control on when the folder has any, else those with control off), so one sweep
with `control = ["off", "on"]` gives both the reference (`DIR:off`) and a controller (`DIR:on`).
The selected records of every run must be the same pushes in the same order: every input
column (impulse, azimuth, height, onset, duration, phase, randomisation, controller-grid and
step columns) is checked, and a mismatch is refused with the column and the first record that
differs named.

Conventions (tkujax.sim.push): azimuth 0 deg = pushed from behind (the force points forward,
+x), 90 deg = pushed from the right (force toward +y, the robot's left), 180 = from the front,
270 = from the left. Sectors are centred on those directions (4 sectors of 90 deg, or 8 of
45 deg: behind-right is centred on 45 deg). The phase is the push onset's phase in the 30 ms
control period (`onset_phase`, 0 = on a controller tick).

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
import math
import os
from pathlib import Path

import numpy as np

from tkujax.sim.push import onset_phase
from tkujax.studies.chunks import read_manifest
from tkujax.studies.maps import MAX_AZIMUTH_BINS, _axis, _polar_mesh
from tkujax.studies.spec import PHASE_KEY, RANDOMIZE_FIELDS, SpecError
from tkujax.studies.sweep import load, outcome_keys

SECTOR_NAMES = {4: ("behind", "right", "front", "left"),
                8: ("behind", "behind-right", "right", "front-right", "front", "front-left",
                    "left", "behind-left")}
# Columns that are not inputs of a push: outcomes, the control setting (selected on), the
# record number (differs between the control blocks of one spec), a replay's state.
NOT_INPUTS = set(outcome_keys(True)) | {"control", "push_id", "qpos"}
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
    complete: bool                     # the folder's manifest says the sweep is complete


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
    """'DIR', 'DIR:on' or 'DIR:off' -> (DIR, control or None)."""
    for suffix in (":on", ":off"):
        if arg.endswith(suffix):
            return arg[:-len(suffix)], suffix[1:]
    return arg, None


def load_run(arg: str, label: str | None = None, subset: str = "all") -> Run:
    """The records of one run argument ('DIR[:on|:off]'), see the module doc."""
    if subset not in SUBSETS:
        raise SpecError(f"subset must be one of {SUBSETS}, got {subset!r}")
    path, control = parse_run(arg)
    if not Path(path).is_dir():
        raise FileNotFoundError(f"run {arg!r}: {path} is not a folder (a tkujax sweep --out)")
    rec = load(path)
    for key in ("fell", "control", "impulse_ns", "azimuth_deg"):
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
    complete = bool(read_manifest(Path(path)).get("complete", True))
    return Run(label=label or f"{Path(path).name} ({control})", path=str(path), control=control,
               inputs=inputs, fell=rec["fell"][sel].astype(bool), diverged=diverged,
               complete=complete)


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
        incomplete = [r.label for r in (ref, run) if not r.complete]
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


def _paired(cell: np.ndarray, n_cells: int, ref: Run, run: Run, unpaired: bool = False):
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
    edges = impulse_edges(ref.inputs["impulse_ns"], bands)
    n_j, n_p, n_s = len(edges) - 1, bands.phase_bands, bands.sectors
    s = sector_index(ref.inputs["azimuth_deg"], n_s)
    j = band_index(ref.inputs["impulse_ns"], edges)
    p = phase_index(ref.inputs[PHASE_KEY], n_p)
    phase_edges = np.linspace(0.0, 1.0, n_p + 1)
    levels = [("phase", (s * n_j + j) * n_p + p, n_s * n_j * n_p),
              ("pooled", s * n_j + j, n_s * n_j)]
    rows = []
    for level, cell, n_cells in levels:
        stats = {r.label: _rates(cell, n_cells, r.fell, ~r.diverged) for r in runs}
        paired = {r.label: _paired(cell, n_cells, ref, r, unpaired) for r in runs[1:]}
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
                phase_edges=phase_edges.tolist(), rows=rows)


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
                harmed.append(dict(sector=row["sector"], impulse_ns=[row["impulse_lo"],
                                                                      row["impulse_hi"]],
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
    return _axis(values, max_bins, period, keep_empty=True)


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
    js, ij = map_axis(ref.inputs["impulse_ns"], impulse_bins)
    p = phase_index(ref.inputs[PHASE_KEY], phase_bands)
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
    return dict(azimuths=azs, impulses=js, bands=out)


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _save_fig(fig, path: Path) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.png")
    fig.savefig(tmp, dpi=90)
    os.replace(tmp, path)


def plot_difference_maps(cells: dict, labels: list[str], path: Path, min_count: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = labels[0]
    A, J = _polar_mesh(cells["azimuths"], cells["impulses"])
    diffs = []
    for _, per in cells["bands"]:
        for lab in labels[1:]:
            ok = np.minimum(per[lab][1], per[ref][1]) >= min_count
            diffs.append(np.where(ok, per[lab][0] - per[ref][0], np.nan))
    finite = np.concatenate([np.abs(d[np.isfinite(d)]) for d in diffs]) if diffs else np.zeros(0)
    vmax = max(0.1, math.ceil(10 * float(np.percentile(finite, 98))) / 10) if finite.size else 1
    rows, cols = len(cells["bands"]), len(labels)
    fig, axes = plt.subplots(rows, cols, subplot_kw=dict(projection="polar"),
                             figsize=(3.4 * cols + 1.0, 3.3 * rows + 0.8), squeeze=False,
                             layout="constrained")
    k = 0
    for i, (title, per) in enumerate(cells["bands"]):
        rate, count = per[ref]
        ax = axes[i, 0]
        m0 = ax.pcolormesh(A, J, np.where(count >= min_count, rate, np.nan), cmap="RdYlGn_r",
                           vmin=0, vmax=1, shading="flat")
        ax.set_title(f"{ref}: fall rate\n{title}", fontsize=8)
        for c, lab in enumerate(labels[1:], start=1):
            ax = axes[i, c]
            m1 = ax.pcolormesh(A, J, diffs[k], cmap="RdBu_r", vmin=-vmax, vmax=vmax,
                               shading="flat")
            k += 1
            ax.set_title(f"{lab} − {ref}\n{title}", fontsize=8)
        for ax in axes[i]:
            ax.set_theta_zero_location("S")   # pushed from behind (0 deg) drawn at the bottom
            ax.set_rlabel_position(135)
            ax.tick_params(labelsize=6)
    fig.colorbar(m0, ax=axes[-1, 0], location="bottom", shrink=0.8, label="fall rate")
    if cols > 1:
        fig.colorbar(m1, ax=axes[-1, 1:].tolist(), location="bottom", shrink=0.6,
                     label="fall-rate difference (red: falls more often than the reference)")
    fig.suptitle("radius: impulse (N·s); angle: push azimuth (0° = pushed from behind, at the "
                 f"bottom; 90° = from the right); cells with < {min_count} pushes blank",
                 fontsize=9)
    _save_fig(fig, path)
    plt.close(fig)


def plot_by_sector(table: dict, labels: list[str], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = table["sector_names"]
    pooled = [r for r in table["rows"] if r["phase"] == "all"]
    cols = min(len(names), 4)
    nrows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.4 * cols, 3.0 * nrows), squeeze=False,
                             sharey=True)
    for k, name in enumerate(names):
        ax = axes.ravel()[k]
        rows = [r for r in pooled if r["sector"] == name]
        x = [(r["impulse_lo"] + r["impulse_hi"]) / 2 for r in rows]
        for lab in labels:
            y = [100 * r["runs"][lab]["rate"] if r["runs"][lab]["rate"] is not None
                 else np.nan for r in rows]
            ax.plot(x, y, "o-", ms=3, label=lab)
        ax.set_title(f"pushed from {name}" if name != "behind" else "pushed from behind",
                     fontsize=9)
        ax.set_xlabel("impulse band centre (N·s)", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("fall rate (%)")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    fig.tight_layout()
    _save_fig(fig, path)
    plt.close(fig)


def _csv(table: dict, labels: list[str]) -> str:
    head = ["sector", "impulse_lo_ns", "impulse_hi_ns", "phase_lo", "phase_hi"]
    for i, lab in enumerate(labels):
        head += [f"n[{lab}]", f"falls[{lab}]", f"fall_rate[{lab}]"]
        if i:
            head += [f"diff_pp[{lab}]", f"se_pp[{lab}]"]
    fmt = lambda v: "" if v is None else (f"{v:.6g}" if isinstance(v, float) else str(v))  # noqa
    lines = [",".join('"' + h + '"' if "," in h else h for h in head)]
    for r in table["rows"]:
        vals = [r["sector"], r["impulse_lo"], r["impulse_hi"], r["phase_lo"], r["phase_hi"]]
        for i, lab in enumerate(labels):
            e = r["runs"][lab]
            vals += [e["n"], e["falls"], e["rate"]]
            if i:
                vals += [e["diff_pp"], e["se_pp"]]
        lines.append(",".join(fmt(v) for v in vals))
    return "\n".join(lines) + "\n"


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _markdown_table(table: dict, labels: list[str], phase: str | None) -> list[str]:
    """Rows of one phase band ('all' = pooled; None = every phase band)."""
    head = "| sector | impulse (N·s) | phase | " + " | ".join(
        f"{lab}" + ("" if i == 0 else " (diff, pp ± s.e.)") for i, lab in enumerate(labels)) + " |"
    lines = [head, "|---" * (3 + len(labels)) + "|"]
    for r in table["rows"]:
        if (phase == "all") != (r["phase"] == "all"):
            continue
        cells = []
        for i, lab in enumerate(labels):
            e = r["runs"][lab]
            text = f"{_pct(e['rate'])} ({e['n']})"
            if i and e["diff_pp"] is not None:
                se = "" if e["se_pp"] is None else f" ± {e['se_pp']:.1f}"
                text += f" {e['diff_pp']:+.1f}{se}"
            cells.append(text)
        lines.append(f"| {r['sector']} | {r['impulse_lo']:.2f}-{r['impulse_hi']:.2f} | "
                     f"{r['phase']} | " + " | ".join(cells) + " |")
    return lines


def summary_markdown(runs: list[Run], table: dict, verdict_: dict, files: list[str]) -> str:
    labels = [r.label for r in runs]
    ref = verdict_["reference"]
    lines = [f"# tkujax compare: {len(runs) - 1} run(s) against `{ref['label']}`", "",
             "Runs (same pushes, checked column by column): " + "; ".join(
                 f"`{r.label}` = {r.path} control {r.control}, {int((~r.diverged).sum())} "
                 "pushes" + (f", {int(r.diverged.sum())} diverged (left out)"
                             if r.diverged.any() else "")
                 + ("" if r.complete else " (INCOMPLETE sweep)") for r in runs) + ".", "",
             "Azimuth 0° = pushed from behind, 90° = from the right, 180° = from the front, "
             "270° = from the left; phase = the onset's phase in the 30 ms control period.", "",
             "## Verdict", "",
             f"No harm = no cell (sector × impulse band × phase band, and the same with the "
             f"phases pooled) with ≥ {verdict_['min_pushes']} pushes where the run falls more "
             f"often than `{ref['label']}` by more than {verdict_['harm_pp']:g} pp. Of those, "
             f"'beyond 2 s.e.' are the ones whose excess over {verdict_['harm_pp']:g} pp is more "
             "than twice its paired standard error (the rest may be noise).", "",
             "| run | fall rate | reference | ratio | cells checked | harmed cells (beyond 2 s.e.) "
             "| no harm |", "|---|---|---|---|---|---|---|"]
    for lab, v in verdict_["runs"].items():
        ratio = "-" if v["ratio_to_reference"] is None else f"{v['ratio_to_reference']:.3f}"
        lines.append(f"| {lab} | {_pct(v['fall_rate'])} | {_pct(v['reference_fall_rate'])} | "
                     f"{ratio} | {v['cells_checked']} | {len(v['harmed_cells'])} "
                     f"({v['n_harmed_beyond_2se']}) | "
                     f"{'yes' if v['no_harm'] else '**no**'} |")
    for lab, v in verdict_["runs"].items():
        if v["harmed_cells"]:
            lines += ["", f"Harmed cells, `{lab}` (worst first):", "",
                      "| sector | impulse (N·s) | phase | pushes | reference | run "
                      "| diff (pp ± s.e.) | beyond 2 s.e. |", "|---|---|---|---|---|---|---|---|"]
            for h in sorted(v["harmed_cells"], key=lambda h: -h["diff_pp"]):
                se = "" if h["se_pp"] is None else f" ± {h['se_pp']:.1f}"
                lines.append(f"| {h['sector']} | {h['impulse_ns'][0]:.2f}-{h['impulse_ns'][1]:.2f}"
                             f" | {h['phase']} | {h['n']} | {_pct(h['reference_rate'])} | "
                             f"{_pct(h['rate'])} | {h['diff_pp']:+.1f}{se} | "
                             f"{'yes' if h['beyond_2se'] else 'no'} |")
    # Per sector, everything pooled.
    sec = {}
    for r in table["rows"]:
        if r["phase"] == "all":
            for lab in labels:
                e = r["runs"][lab]
                a = sec.setdefault((r["sector"], lab), [0, 0])
                a[0] += e["falls"]
                a[1] += e["n"]
    lines += ["", "## Fall rate by direction (impulses and phases pooled)", "",
              "| run | " + " | ".join(table["sector_names"]) + " |",
              "|---" * (1 + len(table["sector_names"])) + "|"]
    for lab in labels:
        lines.append(f"| {lab} | " + " | ".join(
            (lambda f, n: f"{100 * f / n:.1f} % ({n})" if n else "-")(*sec.get((s, lab), (0, 0)))
            for s in table["sector_names"]) + " |")
    lines += ["", "## Sector × impulse band (phases pooled)", "",
              "Cells: fall rate (pushes); runs after the reference also give the difference to "
              "it in percentage points ± its paired standard error. Every phase band: "
              "table.md and table.csv.", ""]
    lines += _markdown_table(table, labels, "all")
    lines += ["", "Files: " + ", ".join(Path(f).name for f in files) + "."]
    return "\n".join(lines) + "\n"


def compare_runs(run_args: list[str], out: str | Path, labels: list[str] | None = None,
                 bands: Bands = Bands(), min_pushes: int = 100, harm_pp: float = 2.0,
                 subset: str = "all", azimuth_bins: int = 24, impulse_bins: int = 12,
                 min_map_count: int = 10, unpaired_robots: bool = False) -> dict:
    """Compare sweep runs against the first (see the module doc); write the outputs into out.

    unpaired_robots: accept runs whose model randomisation columns differ (independent robot
    draws from one distribution, e.g. the control-off and control-on blocks of sweeps made
    before the draws were shared); the standard errors are then unpaired.

    run_args: 'DIR', 'DIR:on' or 'DIR:off' each. labels: one per run (default: the folder's
    name and the control setting). Returns dict(verdict, table, files, summary)."""
    if len(run_args) < 2:
        raise SpecError(f"compare needs 2 or more runs (the first is the reference), got "
                        f"{len(run_args)}")
    if labels is not None and len(labels) != len(run_args):
        raise SpecError(f"labels: {len(labels)} given for {len(run_args)} runs; give one per run")
    if not isinstance(min_map_count, int) or min_map_count < 1:
        raise SpecError(f"min_map_count must be an integer >= 1, got {min_map_count!r}")
    bands = bands.validate()
    runs = [load_run(a, None if labels is None else labels[i], subset)
            for i, a in enumerate(run_args)]
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
    _atomic_text(files[2], _csv(table, lab))
    _atomic_text(files[3], "# Fall rate by sector × impulse band × phase band\n\nCells: fall "
                 "rate (pushes); after the reference: difference to it, pp ± paired s.e.\n\n"
                 + "\n".join(_markdown_table(table, lab, None)) + "\n\n## Phases pooled\n\n"
                 + "\n".join(_markdown_table(table, lab, "all")) + "\n")
    _atomic_text(files[4], json.dumps(dict(v, unpaired_robots=unpaired_robots, bands=dict(
        sectors=table["sector_names"], impulse_edges_ns=table["impulse_edges"],
        phase_edges=table["phase_edges"])), indent=1))
    text = summary_markdown(runs, table, v, [str(f) for f in files])
    if unpaired_robots:
        text = text.replace("\n", "\n\n**Unpaired robots:** the runs' model randomisation draws "
                            "differ, so every standard error here is that of two independent "
                            "rates, not a paired one.\n", 1)
    _atomic_text(files[5], text)
    return dict(verdict=v, table=table, files=[str(f) for f in files], summary=str(files[5]))
