"""Empirical one-step capture regions from a [step] sweep, with the theory and controller
overlays and the controller's optimality gap.

A region is keyed by the push record it belongs to (`case_id`) and the step timing
(start_delay_s, from_detection, period_s): its targets are the step_x_m, step_y_m grid, and a
target is in the region when the rollout did not fall (tkujax.sim.metrics) by the end of the
horizon. Coordinates are target coordinates: the swing ankle relative to its stand pose (m).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from tkujax.studies.capture import theory
from tkujax.sweeps.sweep import load
from tkujax.sweeps.sweep_state import require_complete

TIMING = ("step_start_delay_s", "step_from_detection", "step_period_s")


@dataclasses.dataclass
class Region:
    """One (push, step timing) region. Arrays in target coordinates (m)."""

    case_id: int
    impulse_ns: float
    azimuth_deg: float
    timing: tuple[float, float, float]
    targets: np.ndarray          # (k, 2)
    captured: np.ndarray         # (k,) bool
    margin_deg: np.ndarray       # (k,)
    cell_area_m2: float
    icp_td: np.ndarray           # (2,) LIP capture point at touchdown (sim CoM), median; NaN none
    dt_s: float                  # push onset -> touchdown, median over the region's rollouts
    koolen: list                 # R_1 polygons (target coordinates)
    controller: np.ndarray       # (2,) the controller's own commanded step (x_Sup, y_Sup); NaN none
    controller_fell: float

    @property
    def area_m2(self) -> float:
        return float(self.captured.sum()) * self.cell_area_m2

    @property
    def centroid(self) -> np.ndarray:
        return (self.targets[self.captured].mean(0) if self.captured.any()
                else np.full(2, np.nan))

    @property
    def best_cell(self) -> np.ndarray:
        """The captured target of largest capture margin (NaN when the region is empty)."""
        if not self.captured.any():
            return np.full(2, np.nan)
        i = np.flatnonzero(self.captured)[np.argmax(self.margin_deg[self.captured])]
        return self.targets[i]

    def distance_to_region(self, point) -> float:
        """0 when the grid cell nearest to `point` is in the region, else the distance to the
        nearest captured target; NaN for an empty region or no point."""
        point = np.asarray(point, float)
        if not self.captured.any() or not np.isfinite(point).all():
            return math.nan
        d = np.linalg.norm(self.targets - point, axis=-1)
        if self.captured[np.argmin(d)]:
            return 0.0
        return float(d[self.captured].min())

    def summary(self) -> dict:
        c, icp = self.centroid, self.icp_td
        f = lambda v: None if not np.isfinite(v) else round(float(v), 5)  # noqa: E731
        return dict(
            case_id=self.case_id, impulse_ns=self.impulse_ns, azimuth_deg=self.azimuth_deg,
            start_delay_s=self.timing[0], from_detection=self.timing[1], period_s=self.timing[2],
            n_targets=len(self.captured), n_captured=int(self.captured.sum()),
            area_cm2=round(1e4 * self.area_m2, 2), centroid_x_m=f(c[0]), centroid_y_m=f(c[1]),
            icp_td_x_m=f(icp[0]), icp_td_y_m=f(icp[1]), dt_s=f(self.dt_s),
            koolen_nonempty=bool(self.koolen), controller_x_m=f(self.controller[0]),
            controller_y_m=f(self.controller[1]), controller_fell=f(self.controller_fell),
            gap_region_m=f(self.distance_to_region(self.controller)),
            gap_centroid_m=f(np.linalg.norm(self.controller - c)),
            icp_in_region=(f(self.distance_to_region(icp) == 0.0) if np.isfinite(icp).all()
                           else None),
            best_x_m=f(self.best_cell[0]), best_y_m=f(self.best_cell[1]))


def _spacing(v: np.ndarray) -> float:
    u = np.unique(np.round(v, 6))
    return float(np.min(np.diff(u))) if len(u) > 1 else 1.0


def _icp_targets(rec: dict, sel: np.ndarray, feet: theory.Feet) -> np.ndarray:
    """(n, 2) capture point at touchdown in target coordinates: relative to the stand ankle of
    the foot on its side, minus the sole-centre offset (the foot centre lands on it)."""
    icp = np.stack([rec["icp_td_x_m"][sel], rec["icp_td_y_m"][sel]], -1)
    l0 = np.stack([rec["l_ankle0_x_m"][sel], rec["l_ankle0_y_m"][sel]], -1)
    r0 = np.stack([rec["r_ankle0_x_m"][sel], rec["r_ankle0_y_m"][sel]], -1)
    left = icp[:, 1] >= 0.5 * (l0[:, 1] + r0[:, 1])
    centre = feet.sole.mean(0)
    return icp - np.where(left[:, None], l0, r0) - centre


def regions(rec: dict, feet: theory.Feet) -> list[Region]:
    """All one-step regions of a [step] sweep's records (as `tkujax.sweeps.sweep.load` returns
    them); two-step records (step_steps = 2) enter only `jn_table`."""
    active = (rec["step_active"] > 0.5) & (_steps(rec) < 1.5)
    ref = {int(c): i for i, c in enumerate(rec["case_id"]) if not active[i]}
    timing = np.stack([rec[k] for k in TIMING], -1)
    keys = np.unique(np.column_stack([rec["case_id"][active], timing[active]]), axis=0)
    cell = _spacing(rec["step_x_m"][active]) * _spacing(rec["step_y_m"][active])
    out = []
    for key in keys:
        case = int(key[0])
        sel = active & (rec["case_id"] == case) & np.all(timing == key[1:], -1)
        i0 = np.flatnonzero(sel)[0]
        td = rec["touchdown_s"][sel] - rec["onset_s"][sel]
        landed = np.isfinite(td)
        icp = _icp_targets(rec, sel, feet)
        icp_med = np.median(icp[landed], 0) if landed.any() else np.full(2, np.nan)
        dt = float(np.median(td[landed])) if landed.any() else math.nan
        j, az = float(rec["impulse_ns"][i0]), float(rec["azimuth_deg"][i0])
        koolen = (theory.region_halves(feet, j, math.radians(az), dt)
                  if np.isfinite(dt) else [])
        r = ref.get(case)
        ctrl = (np.array([rec["capture_point_m"][r], rec["capture_point_y_m"][r]])
                if r is not None else np.full(2, np.nan))
        # A controller that never triggered took no step: its choice is the stand pose.
        out.append(Region(
            case_id=case, impulse_ns=j, azimuth_deg=az, timing=tuple(float(v) for v in key[1:]),
            targets=np.stack([rec["step_x_m"][sel], rec["step_y_m"][sel]], -1),
            captured=~rec["fell"][sel].astype(bool), margin_deg=rec["margin_deg"][sel],
            cell_area_m2=cell, icp_td=icp_med, dt_s=dt, koolen=koolen, controller=ctrl,
            controller_fell=float(rec["fell"][r]) if r is not None else math.nan))
    return out


def _steps(rec: dict) -> np.ndarray:
    """step_steps, 1 for sweeps recorded before the two-step override."""
    return rec.get("step_steps", np.ones(len(rec["step_active"])))


def jn_table(rec: dict) -> list[dict]:
    """Per (azimuth, first-step timing): the empirical N-step limits J_N, N = 1, 2 = the largest
    tested impulse for which any commanded single step (N = 1) or any commanded pair (N = 2)
    did not fall, with the counts of survivors per impulse, and the controller's own largest
    survived impulse (the reference copies). 0.0 when none survived; None for N = 2 when the
    sweep has no two-step targets. A lower bound on the true limits: only the grid's targets
    are tried."""
    active, steps = rec["step_active"] > 0.5, _steps(rec)
    ok = ~rec["fell"].astype(bool)
    timing = np.stack([rec[k] for k in TIMING], -1)
    rows = []
    for az in np.unique(rec["azimuth_deg"]):
        for t in np.unique(timing[active], axis=0):
            at = (rec["azimuth_deg"] == az) & np.all(timing == t, -1)
            js = np.unique(rec["impulse_ns"][at & active])
            row = dict(azimuth_deg=float(az), start_delay_s=float(t[0]),
                       from_detection=float(t[1]), period_s=float(t[2]),
                       impulses_tested=[float(j) for j in js])
            for n in (1, 2):
                sel = at & active & (np.round(steps) == n)
                if not sel.any():
                    row[f"j{n}_empirical"], row[f"survivors_{n}"] = None, None
                    continue
                surv = [int((ok & sel & (rec["impulse_ns"] == j)).sum()) for j in js]
                tried = [int((sel & (rec["impulse_ns"] == j)).sum()) for j in js]
                row[f"j{n}_empirical"] = max([float(j) for j, s in zip(js, surv) if s] or [0.0])
                row[f"survivors_{n}"] = [f"{s}/{c}" for s, c in zip(surv, tried)]
            ref = (rec["azimuth_deg"] == az) & ~active
            row["controller_max_survived"] = max(
                [float(j) for j in rec["impulse_ns"][ref & ok]] or [0.0]) if ref.any() else None
            rows.append(row)
    return rows


def j1_table(regs: list[Region], feet: theory.Feet) -> list[dict]:
    """Per (azimuth, step timing): empirical J_1 (largest impulse with a non-empty region),
    theory's J_1 (one_step region meets the reach, with the median step time), and the
    controller's own largest survived impulse."""
    groups: dict = {}
    for r in regs:
        groups.setdefault((r.azimuth_deg, r.timing), []).append(r)
    rows = []
    for (az, timing), rs in sorted(groups.items()):
        rs = sorted(rs, key=lambda r: r.impulse_ns)
        nonempty = [r.impulse_ns for r in rs if r.captured.any()]
        dts = [r.dt_s for r in rs if np.isfinite(r.dt_s)]
        dt = float(np.median(dts)) if dts else math.nan
        ctrl = [r.impulse_ns for r in rs if r.controller_fell == 0.0]
        rows.append(dict(
            azimuth_deg=az, start_delay_s=timing[0], from_detection=timing[1],
            period_s=timing[2], impulses_tested=[r.impulse_ns for r in rs],
            j1_empirical=max(nonempty) if nonempty else 0.0,
            j1_theory=round(theory.j1_theory(feet, math.radians(az), dt), 4)
            if np.isfinite(dt) else None,
            dt_s=round(dt, 4), controller_max_survived=max(ctrl) if ctrl else 0.0))
    return rows


def analyse(out_dir: str | Path, feet: theory.Feet | None = None,
            allow_incomplete: bool = False) -> dict:
    """Regions, J_1 table and summaries of the sweep in out_dir -> out_dir/capture/*.json. An
    incomplete sweep is refused (`tkujax.sweeps.sweep_state.IncompleteSweep`) unless
    allow_incomplete; the result's `incomplete` is then "incomplete: k of n chunks" ("" when
    complete), also in regions.json's rows' place as {"incomplete", "rows"}."""
    out_dir = Path(out_dir)
    state = require_complete(out_dir, allow_incomplete, "tkujax capture")
    rec = load(out_dir)
    if "step_active" not in rec:
        raise ValueError(f"{out_dir} is not a [step] sweep (no step_* columns)")
    feet = feet or theory.stand_feet()
    regs = regions(rec, feet)
    rows = [r.summary() for r in regs]
    j1 = j1_table(regs, feet)
    jn = jn_table(rec)
    dest = out_dir / "capture"
    dest.mkdir(exist_ok=True)
    marked = (lambda x: {"incomplete": state.mark, "rows": x}) if state.mark else (lambda x: x)
    (dest / "regions.json").write_text(json.dumps(marked(rows), indent=1))
    (dest / "j1.json").write_text(json.dumps(marked(j1), indent=1))
    (dest / "jn.json").write_text(json.dumps(marked(jn), indent=1))
    return dict(regions=regs, rows=rows, j1=j1, jn=jn, dir=dest, incomplete=state.mark)
