"""`tkujax map DIR`: stability maps, capture regions and capturability checks of a sweep.

Cells are (control, azimuth, impulse); when a sweep varies more (height, onset and its phase
in the control period, controller grid, randomisation) a cell's value is the mean over those
records (fall *fraction*), and the fall boundary is where that fraction crosses 1/2.
`fall_vs_phase.png` and the summary's phase table split the fall rate by the push's phase in
the 30 ms control period instead, per control setting and controller-grid point.
Diverged records (numerical blow-up, `tkujax.sim.metrics`) are neither fell nor survived: they
are left out of every cell and fraction, and counted on their own in the summary.

Velocity kicks ([push] kind = "velocity_kick") are mapped along kick_mps instead of the
impulse (`push_size`); the capturability overlay is then the LIP's impulse bounds over its mass.

A walking sweep ([walk]) gets the walking maps instead (`tkujax.analysis.walk_maps`: the fall
rate by impulse x direction x gait phase, per walking recovery setting).

Sweeps over an ensemble of robots ([randomize] ensemble: a robot_id column) also get each
boundary per member (`member_boundaries`: the same definition on the member's own records, at
an azimuth only where the member has at least MIN_MEMBER_PUSHES records there), drawn as the
10-90 % band of the members' boundaries with their median (where at least MIN_BAND_MEMBERS
members count), written to boundary_by_member.json / .csv and stated in summary.md.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from tkujax.control.params_files import controller_params_from_dict
from tkujax.control.controller_params import ControllerParams
from tkujax.analysis import capturability
from tkujax.sweeps import chunks
from tkujax.sim.push import peak_on_sample_phase
# The binned statistics live in tkujax.analysis.map_cells; the ones other modules read through
# this module are imported here too.
from tkujax.analysis.map_cells import (BAND_QUANTILES, MIN_BAND_MEMBERS, MIN_MEMBER_PUSHES, ROUND,
                                       cell_means, fall_by_phase, max_recoverable_impulse,
                                       member_boundaries, polar_mesh, push_size)
from tkujax.sweeps.sweep_robot import check_robot
from tkujax.dialects.sweep_spec import parse_spec
from tkujax.sweeps.sweep import load
from tkujax.analysis.walk_maps import make_walk_maps
from tkujax.sweeps.sweep_state import require_complete


def _phase_outputs(rec: dict, variant_keys, maps: Path, plt) -> tuple[Path, str]:
    """fall_vs_phase.png and the summary's markdown table."""
    by = fall_by_phase(rec, variant_keys)
    peak = peak_on_sample_phase(float(np.median(rec["duration_s"])))
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, frac, _ in by["rows"]:
        ax.plot(by["phases"], 100 * frac, "o-", ms=4, label=label)
    ax.axvline(peak, color="k", ls=":", lw=1,
               label=f"pulse peak on the IMU sample ({1000 * np.median(rec['duration_s']):.0f} ms)")
    ax.set_xlabel("push onset phase in the 30 ms control period (0 = on a controller tick)")
    ax.set_ylabel("fall rate (%)")
    ax.set_xlim(-0.02, 1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = maps / "fall_vs_phase.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    head = "| phase | " + " | ".join(r[0] for r in by["rows"]) + " |"
    lines = [head, "|---" * (1 + len(by["rows"])) + "|"]
    for i, ph in enumerate(by["phases"]):
        lines.append(f"| {ph:.2f} | " + " | ".join(
            f"{100 * r[1][i]:.1f} % ({int(r[2][i])})" for r in by["rows"]) + " |")
    spread = "; ".join(f"{label}: {100 * np.nanmin(f):.1f}-{100 * np.nanmax(f):.1f} %"
                       for label, f, _ in by["rows"])
    text = (f"## Fall rate against the push's phase in the control period\n\n"
            f"Phase 0 = onset on a controller tick; {peak:.2f} puts the pulse's peak on the "
            f"IMU sample. Range over phase: {spread}. Cells: fall rate (records).\n\n"
            + "\n".join(lines) + "\n")
    return path, text


def _polar_panel(ax, rec, key, control, title, cmap, vmin=None, vmax=None, label=""):
    azs, js, val = cell_means(rec, key, control)
    A, J = polar_mesh(azs, js)
    mesh = ax.pcolormesh(A, J, val, cmap=cmap, vmin=vmin, vmax=vmax, shading="flat")
    ax.set_theta_zero_location("S")   # pushed from behind (0 deg, toward +x) drawn at the bottom
    ax.set_title(title, fontsize=9)
    ax.set_rlabel_position(135)
    return mesh


def _name(control: bool) -> str:
    return "control on" if control else "control off"


def _spec_of(manifest: dict):
    """The sweep's SweepSpec without reading its ensemble file (the maps need the records'
    columns, not the robots; the file may have moved since the sweep ran)."""
    data = dict(manifest["spec"])
    if isinstance(data.get("randomize"), dict):
        data["randomize"] = {k: v for k, v in data["randomize"].items() if k != "ensemble"}
    return parse_spec(data)


def _records(out_dir: Path, manifest: dict) -> tuple[dict, dict, np.ndarray, int]:
    """(every non-diverged record, the records the maps use, the from_grid mask of the first,
    the number diverged). Maps and the boundary table use the grid's exact cells when the sweep
    has a grid; random samples (binned) are used only when there is no grid, and summarised
    separately."""
    everything = load(out_dir)
    if "from_grid" not in everything:   # sweeps written before the column existed
        everything["from_grid"] = _spec_of(manifest).records()["from_grid"][
            everything["push_id"]]
    diverged = everything.get("diverged", np.zeros(len(everything["fell"]), bool)).astype(bool)
    everything = {k: v[~diverged] for k, v in everything.items()}
    grid = everything["from_grid"].astype(bool)
    rec = {k: v[grid] for k, v in everything.items()} if grid.any() else everything
    return everything, rec, grid, int(diverged.sum())


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _band(ax, band: dict, colour: str, name: str) -> None:
    """The members' 10-90 % band and median boundary on a polar axis (closed around)."""
    wrap = lambda v: np.append(v, v[0])  # noqa: E731
    a = np.radians(wrap(band["azimuth_deg"]))
    a[-1] += 2 * np.pi
    lo, mid, hi = wrap(band["q10"]), wrap(band["median"]), wrap(band["q90"])
    ok = np.isfinite(mid)
    ax.fill_between(a, np.where(ok, lo, 0), np.where(ok, hi, 0), where=ok, color=colour,
                    alpha=0.3, lw=0, label=f"ensemble 10-90 %, {name}")
    for edge in (lo, hi):
        ax.plot(a, np.where(ok, edge, np.nan), color=colour, lw=0.5, alpha=0.8)
    ax.plot(a, np.where(ok, mid, np.nan), color=colour, ls=":", lw=1.2,
            label=f"ensemble median, {name}")


def _stability_figure(rec: dict, controls: list[bool], maps: Path, plt,
                      bands: dict | None = None) -> Path:
    """Polar stability map: fall fraction, with the boundary of each setting overlaid (and,
    for an ensemble sweep, the band of the members' boundaries: `bands` {control: band})."""
    fig, axes = plt.subplots(1, len(controls), subplot_kw=dict(projection="polar"),
                             figsize=(5 * len(controls), 4.6), squeeze=False)
    for ax, c in zip(axes[0], controls):
        mesh = _polar_panel(ax, rec, "fell", c, f"fall fraction, {_name(c)}", "RdYlGn_r", 0, 1)
        for c2, style, colour in zip(controls, ("k--", "b-"), ("k", "b")):
            azs, jmax = max_recoverable_impulse(rec, c2)
            a = np.radians(np.append(azs, azs[0] + 360))
            ax.plot(a, np.append(jmax, jmax[0]), style, lw=1.2, label=f"boundary, {_name(c2)}")
            if bands and c2 in bands:
                _band(ax, bands[c2], colour, _name(c2))
    axes[0, -1].legend(loc="lower left", bbox_to_anchor=(0.75, -0.12), fontsize=7)
    fig.suptitle(f"radius: {push_size(rec)[1]}; angle: push azimuth (0° = pushed from behind, "
                 "90° = from the right)", fontsize=8, y=0.02)
    fig.colorbar(mesh, ax=axes[0].tolist(), shrink=0.7)
    return _save(fig, maps / "stability_polar.png", plt)


def _recovery_figure(rec: dict, controls: list[bool], maps: Path, plt) -> Path:
    """Recovery time and step length maps (per control setting)."""
    fig, axes = plt.subplots(2, len(controls), subplot_kw=dict(projection="polar"),
                             figsize=(5 * len(controls), 8.6), squeeze=False)
    for k, c in enumerate(controls):
        m = _polar_panel(axes[0, k], rec, "recovery_time_s", c, f"recovery time (s), {_name(c)}",
                         "viridis")
        fig.colorbar(m, ax=axes[0, k], shrink=0.7)
        rec_abs = dict(rec, step_abs_cm=100 * np.hypot(rec["step_length_m"], rec["step_width_m"]))
        m = _polar_panel(axes[1, k], rec_abs, "step_abs_cm", c, f"step length (cm), {_name(c)}",
                         "magma")
        fig.colorbar(m, ax=axes[1, k], shrink=0.7)
    fig.tight_layout()
    return _save(fig, maps / "recovery_and_step.png", plt)


def _ns_per_size(rec: dict, lip) -> float:
    """N·s per unit of the push's size (`push_size`): 1 for impulses; for velocity kicks the
    LIP's mass (a kick of v m/s is the impulse m v on the LIP)."""
    return 1.0 if push_size(rec)[0] == "impulse_ns" else lip.mass_kg


def _capture_figure(rec: dict, lip, maps: Path, plt) -> Path:
    """Capture region: where the swing foot landed vs where the LIP capture point said."""
    sel = rec["control"].astype(bool) & ~rec["fell"].astype(bool) & (
        np.hypot(rec["step_length_m"], rec["step_width_m"]) > 0.005)
    az = np.radians(rec["azimuth_deg"][sel])
    shift = capturability.capture_point_shift_m(
        lip, rec[push_size(rec)[0]][sel] * _ns_per_size(rec, lip))
    fig, ax = plt.subplots(figsize=(5.5, 5))
    poly = np.vstack([lip.support_polygon, lip.support_polygon[:1]]) - lip.com_xy_m
    ax.plot(100 * poly[:, 0], 100 * poly[:, 1], "k-", lw=1, label="support polygon (stand)")
    ax.scatter(100 * shift * np.cos(az), 100 * shift * np.sin(az), s=8, c="tab:blue",
               label="LIP capture-point shift J/(mω)")
    ax.scatter(100 * rec["step_length_m"][sel], 100 * rec["step_width_m"][sel], s=8,
               c="tab:red", label="swing-foot displacement (sim)")
    ax.scatter(100 * rec["capture_point_m"][sel], np.zeros(int(sel.sum())), s=8, marker="x",
               c="tab:green", label="controller x_Sup (sagittal)")
    ax.set_xlabel("x (cm, forward)")
    ax.set_ylabel("y (cm, left)")
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    ax.set_title(f"capture region: {int(sel.sum())} recovered pushes with a step", fontsize=9)
    return _save(fig, maps / "capture_region.png", plt)


def _theory_figure(rec: dict, controls: list[bool], lip, params: ControllerParams, maps: Path,
                   plt) -> tuple[Path, list[tuple[float, bool, float]]]:
    """Max recoverable impulse per direction vs capturability theory; also returns the table
    (azimuth, control, sim max) it plots."""
    fine = np.radians(np.arange(0, 361, 2.0))
    fig, ax = plt.subplots(figsize=(7.5, 4))
    per = _ns_per_size(rec, lip)        # the theory in the push's size (a kick: J / m)
    theory = {n: capturability.max_impulse_ns(lip, fine, n, params) / per for n in (0, 1)}
    ax.plot(np.degrees(fine), theory[0], "k:", label="J_0 = mω r_max (no step)")
    ax.plot(np.degrees(fine), theory[1], "k--", label="J_1 (one step, l_max, Δt_s)")
    table = []
    for c, mk in zip(controls, ("s", "o")):
        azs, jmax = max_recoverable_impulse(rec, c)
        ax.plot(azs, jmax, mk + "-", ms=4, label=f"sim max recoverable, {_name(c)}")
        for a, j in zip(azs, jmax):
            table.append((float(a), c, float(j)))
    ax.set_xlabel("push azimuth (deg; 0 = from behind, 90 = from the right)")
    ax.set_ylabel(push_size(rec)[1])
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, maps / "max_impulse_vs_theory.png", plt), table


def _theory_table(table, lip, params: ControllerParams,
                  per: float = 1.0) -> tuple[list[str], list[dict]]:
    """The summary's markdown rows and JSON records: theory vs sim max per azimuth (the theory
    divided by `per`: `_ns_per_size`)."""
    azs_all = sorted({a for a, _, _ in table})
    lookup = {(a, c): j for a, c, j in table}
    rows = ["| azimuth (deg) | r_max (cm) | J_0 theory | sim max, off | J_1 theory | sim max, on |",
            "|---|---|---|---|---|---|"]
    summary = []
    for a in azs_all:
        ar = math.radians(a)
        j0 = float(capturability.max_impulse_ns(lip, ar, 0, params)[0] / per)
        j1 = float(capturability.max_impulse_ns(lip, ar, 1, params)[0] / per)
        off, on = lookup.get((a, False)), lookup.get((a, True))
        fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
        rows.append(f"| {a:.0f} | {100 * float(capturability.r_max(lip, ar)[0]):.1f} | "
                    f"{j0:.2f} | {fmt(off)} | {j1:.2f} | {fmt(on)} |")
        summary.append(dict(azimuth_deg=a, J0_theory=j0, J1_theory=j1, sim_max_off=off,
                            sim_max_on=on))
    return rows, summary


def _summary_text(manifest: dict, everything: dict, rec: dict, grid: np.ndarray,
                  n_diverged: int, controls: list[bool], lip, params: ControllerParams,
                  rows: list[str], phase_md: str) -> str:
    n = len(everything["fell"])
    random_note = ""
    if grid.any() and not grid.all():
        r = {k: v[~grid] for k, v in everything.items()}
        random_note = (f" Random samples ({int((~grid).sum())} records, randomised model and "
                       "pushes): fall fraction " + ", ".join(
                           f"{_name(c)} {r['fell'][r['control'].astype(bool) == c].mean():.3f}"
                           for c in controls) + "; the maps and table below use the grid.")
    diverged_note = (f" {n_diverged} diverged (numerical blow-up; left out of every figure "
                     "and fraction, neither fell nor survived)." if n_diverged else
                     " None diverged.")
    return (f"# Sweep `{manifest['name']}`: {n + n_diverged} pushes\n\n"
            f"Devices: {', '.join(manifest.get('devices', []))}; wall {manifest.get('wall_s')} s "
            f"(compile included); fall fraction: "
            + ", ".join(f"{_name(c)} {rec['fell'][rec['control'].astype(bool) == c].mean():.3f}"
                        for c in controls)
            + f".{diverged_note}{random_note}\n\n"
            f"LIP: m = {lip.mass_kg:.2f} kg, z0 = {lip.com_height_m:.3f} m, "
            f"ω = {lip.omega:.2f} 1/s, l_max = {capturability.step_reach_m(params):.3f} m, "
            f"Δt_s = {capturability.step_time_s(params):.3f} s. Sim max = largest tested impulse "
            "below which every impulse was survived (grid resolution applies).\n\n"
            + ("" if push_size(rec)[0] == "impulse_ns" else
               f"Velocity kicks: every size in this table is a {push_size(rec)[1]}; the theory "
               "is the LIP's J / m.\n\n")
            + "\n".join(rows) + "\n\n" + phase_md)


def _ensemble_outputs(rec: dict, controls: list[bool], maps: Path) -> tuple[dict, list[Path], str]:
    """({control: member_boundaries}, [boundary_by_member.json, .csv], the summary's section)
    of an ensemble sweep (records with robot_id >= 0)."""
    bands = {c: member_boundaries(rec, c) for c in controls}
    js = lambda v: [None if not np.isfinite(x) else round(float(x), ROUND)  # noqa: E731
                    for x in np.asarray(v, float)]
    doc = dict(min_pushes=MIN_MEMBER_PUSHES, min_members=MIN_BAND_MEMBERS,
               quantiles=list(BAND_QUANTILES), definition=(
                   "per member: the largest tested impulse below which every tested impulse "
                   "was survived (fall fraction < 1/2), over the member's own records at that "
                   "azimuth; null where it has fewer than min_pushes records there"),
               controls=[dict(control=_name(c), azimuth_deg=js(b["azimuth_deg"]),
                              q10=js(b["q10"]), median=js(b["median"]), q90=js(b["q90"]),
                              n_members=[int(x) for x in b["n_members"]],
                              members=[dict(robot_id=int(m), boundary_ns=js(b["boundary"][k]),
                                            pushes=[int(x) for x in b["pushes"][k]])
                                       for k, m in enumerate(b["members"])])
                         for c, b in bands.items()])
    json_path, csv_path = maps / "boundary_by_member.json", maps / "boundary_by_member.csv"
    json_path.write_text(json.dumps(doc, indent=1) + "\n")
    lines = ["control,robot_id,azimuth_deg,pushes,boundary_ns"]
    for c, b in bands.items():
        for k, m in enumerate(b["members"]):
            for a, az in enumerate(b["azimuth_deg"]):
                v = b["boundary"][k, a]
                lines.append(f"{_name(c)},{int(m)},{az:g},{int(b['pushes'][k, a])},"
                             + ("" if not np.isfinite(v) else f"{v:g}"))
    csv_path.write_text("\n".join(lines) + "\n")

    n_members = len(np.unique(np.asarray(rec["robot_id"])[np.asarray(rec["robot_id"]) >= 0]))
    head = "| azimuth (deg) | " + " | ".join(
        f"{_name(c)}: median [10 %, 90 %] (members)" for c in bands) + " |"
    rows = [head, "|---" * (1 + len(bands)) + "|"]

    def fmt(b: dict, az: float) -> str:
        hit = np.flatnonzero(np.isclose(b["azimuth_deg"], az))
        if not len(hit) or not np.isfinite(b["median"][hit[0]]):
            return "-"
        a = hit[0]
        return (f"{b['median'][a]:.2f} [{b['q10'][a]:.2f}, {b['q90'][a]:.2f}] "
                f"({int(b['n_members'][a])})")

    for az in np.unique(np.concatenate([b["azimuth_deg"] for b in bands.values()])):
        rows.append(f"| {az:.0f} | " + " | ".join(fmt(b, az) for b in bands.values()) + " |")
    widths = []
    for c, b in bands.items():
        w = b["q90"] - b["q10"]
        if np.isfinite(w).any():
            i = int(np.nanargmax(w))
            widths.append(f"{_name(c)}: median width {np.nanmedian(w):.2f} N·s, widest "
                          f"{w[i]:.2f} N·s at {b['azimuth_deg'][i]:.0f}°")
        else:
            widths.append(f"{_name(c)}: no azimuth has {MIN_BAND_MEMBERS} members with "
                          f"{MIN_MEMBER_PUSHES} pushes each (run more pushes per member)")
    text = (f"## Fall boundary across the ensemble ({n_members} robots)\n\n"
            f"Each member's boundary is computed from its own pushes (the same definition as "
            f"above) at each azimuth where it has at least {MIN_MEMBER_PUSHES} pushes; the band "
            f"is the 10-90 % range of the members' boundaries (median in the middle), drawn on "
            f"stability_polar.png where at least {MIN_BAND_MEMBERS} members count. Band "
            f"(10-90 %): {'; '.join(widths)}. Per-member boundaries: boundary_by_member.json "
            f"and .csv. Cells: median [10 %, 90 %] in N·s (members counted).\n\n"
            + "\n".join(rows) + "\n")
    return bands, [json_path, csv_path], text


class _MarkedPyplot:
    """pyplot whose every figure carries `mark` at its top (an incomplete sweep's figures)."""

    def __init__(self, plt, mark: str):
        self._plt, self._mark = plt, mark

    def subplots(self, *args, **kwargs):
        fig, axes = self._plt.subplots(*args, **kwargs)
        fig.text(0.5, 0.995, self._mark, ha="center", va="top", color="red",
                 fontsize=9, weight="bold")
        return fig, axes

    def __getattr__(self, name):
        return getattr(self._plt, name)


def make_maps(out_dir: str | Path, params: ControllerParams | None = None, robot=None,
              lip: capturability.LipModel | None = None, allow_incomplete: bool = False) -> dict:
    """Write maps/*.png and maps/summary.md (+ .json) for the sweep in `out_dir`. A sweep on a
    robot file needs that robot (a Robot, checked against the manifest's sha256) and its
    LIP (`tkujax.studies.robot_inputs.robot_lip`), which the theory overlays use. An
    incomplete sweep is refused (`tkujax.sweeps.sweep_state.IncompleteSweep`, a ValueError
    "DIR: incomplete: k of n chunks"); with
    allow_incomplete its figures and summary are marked "incomplete: k of n chunks" (the
    result's `incomplete`)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    manifest = chunks.read_manifest(out_dir)
    if not manifest:
        raise FileNotFoundError(f"{out_dir} holds no sweep ({chunks.MANIFEST} not found)")
    state = require_complete(out_dir, allow_incomplete, "tkujax map")
    mark, done, n_chunks = state.mark, state.chunks_done, state.n_chunks
    if mark:
        plt = _MarkedPyplot(plt, mark)
    everything, rec, grid, n_diverged = _records(out_dir, manifest)
    params = params or controller_params_from_dict(
        manifest.get("controller_params", {}), f"{out_dir / 'manifest.json'}: controller_params",
        base=ControllerParams())
    maps = out_dir / "maps"
    maps.mkdir(exist_ok=True)
    if "walk_recovery" in rec:   # a walking sweep: by gait phase, per recovery setting
        check_robot(manifest, robot, str(out_dir))
        return make_walk_maps(manifest, rec, maps, plt, n_diverged, mark)
    controls = [c for c in (False, True) if (rec["control"].astype(bool) == c).any()]
    if check_robot(manifest, robot, str(out_dir)) is None:
        lip = capturability.lip_model()
    elif lip is None:
        raise ValueError("make_maps: a robot sweep's maps need the robot's LIP (lip=, "
                         "tkujax.studies.robot_inputs.robot_lip)")
    ensemble = "robot_id" in rec and (np.asarray(rec["robot_id"]) >= 0).any()
    bands, ensemble_files, ensemble_md = (_ensemble_outputs(rec, controls, maps) if ensemble
                                          else ({}, [], ""))
    files = [_stability_figure(rec, controls, maps, plt, bands),
             _recovery_figure(rec, controls, maps, plt), _capture_figure(rec, lip, maps, plt)]
    theory_png, table = _theory_figure(rec, controls, lip, params, maps, plt)
    files.append(theory_png)
    # Fall rate against the push's phase in the control period.
    variant_keys = tuple(sorted(_spec_of(manifest).controller_grid))
    phase_png, phase_md = _phase_outputs(rec, variant_keys, maps, plt)
    files.append(phase_png)
    rows, summary = _theory_table(table, lip, params, _ns_per_size(rec, lip))
    text = _summary_text(manifest, everything, rec, grid, n_diverged, controls, lip, params,
                         rows, phase_md)
    if ensemble_md:
        text += "\n" + ensemble_md
    if mark:
        text = f"**{mark}**: the figures and tables below hold {done} of {n_chunks} " \
            f"chunks' records.\n\n" + text
    files += ensemble_files
    (maps / "summary.md").write_text(text)
    (maps / "summary.json").write_text(json.dumps(
        {"incomplete": mark, "rows": summary} if mark else summary, indent=1))
    return dict(files=[str(f) for f in files], summary=str(maps / "summary.md"),
                n_diverged=n_diverged, incomplete=mark)
