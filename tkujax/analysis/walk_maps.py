"""`tkujax map DIR` of a walking sweep ([walk]; docs/walking.md): the fall rate by impulse x
direction x gait phase, per walking recovery setting.

Cells are the grid's exact values; random samples are binned as the standing maps bin them
(`tkujax.analysis.map_cells.bin_axis`), coarser as the sweep is sparser (`cell_bins`: about
MIN_PUSHES_PER_CELL pushes a cell); diverged records are left out. Outputs in DIR/maps:

  walk_polar.png      fall fraction per (azimuth, impulse), gait phases pooled, one panel per
                      recovery setting, with each setting's fall boundary (the largest impulse
                      below which every tested impulse was survived) overlaid;
  fall_vs_gait_phase.png   fall rate against the gait phase at onset, one line per recovery
                      setting and direction;
  summary.md, summary.json  the fall rates per (recovery, azimuth, impulse, gait phase) cell,
                      the overall rates and the distance walked (survivors' mean).

Velocity kicks ([push] kind = "velocity_kick") are mapped along kick_mps instead of the
impulse.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tkujax.analysis.map_cells import (MAX_AZIMUTH_BINS, MAX_IMPULSE_BINS, ROUND, bin_axis,
                                       max_recoverable_impulse, polar_mesh, push_size)
from tkujax.dialects.walk_table import GAIT_PHASE_KEY

MAX_GAIT_PHASE_BINS = 16
# Random pushes: cells of about this many pushes on average (65,536 pushes per setting: 19
# azimuths x 13 impulses x 4 gait phases; tests/test_walk_sweep.py), never fewer bins than
# MIN_RANDOM_BINS per axis. A grid keeps its values.
MIN_PUSHES_PER_CELL = 64
MIN_RANDOM_BINS = 4


def _setting(on: bool) -> str:
    return "recovery on" if on else "recovery off"


def walk_cells(rec: dict) -> dict:
    """Falls and counts per (recovery setting, azimuth, impulse, gait phase) cell.

    Returns dict(settings [bool], azimuth_deg, impulse_ns, gait_phase (the bins' centres),
    falls, count: arrays (settings, azimuths, impulses, phases))."""
    ok = ~rec["diverged"].astype(bool) if "diverged" in rec else np.ones(len(rec["fell"]), bool)
    r = {k: np.asarray(v)[ok] for k, v in rec.items()}
    on = r["walk_recovery"] > 0.5
    settings = [s for s in (False, True) if (on == s).any()]
    axes = [np.mod(r["azimuth_deg"], 360.0), r[push_size(r)[0]], r[GAIT_PHASE_KEY]]
    bins = cell_bins(axes, (MAX_AZIMUTH_BINS, MAX_IMPULSE_BINS, MAX_GAIT_PHASE_BINS),
                     len(on) / max(len(settings), 1))
    azs, ia = bin_axis(axes[0], bins[0], 360.0)
    js, ij = bin_axis(axes[1], bins[1])
    phs, ip = bin_axis(axes[2], bins[2], 1.0)
    i_s = np.searchsorted(np.array(settings, bool), on)
    shape = (len(settings), len(azs), len(js), len(phs))
    falls, count = np.zeros(shape), np.zeros(shape)
    np.add.at(falls, (i_s, ia, ij, ip), r["fell"].astype(float))
    np.add.at(count, (i_s, ia, ij, ip), 1.0)
    return dict(settings=settings, azimuth_deg=azs, impulse_ns=js, gait_phase=phs, falls=falls,
                count=count)


def cell_bins(axes: list, max_bins: tuple, pushes_per_setting: float) -> list[int]:
    """Bins per axis: a grid's axis (no more values than its max_bins) keeps its values; the
    random axes share a coarser binning, so that a cell holds about MIN_PUSHES_PER_CELL pushes
    on average (at least MIN_RANDOM_BINS bins each, at most max_bins)."""
    random = [len(np.unique(np.round(np.asarray(a, float), ROUND))) > m
              for a, m in zip(axes, max_bins)]
    if not any(random):
        return list(max_bins)
    full = float(np.prod([m for m, rnd in zip(max_bins, random) if rnd]))
    scale = min(1.0, (pushes_per_setting / (MIN_PUSHES_PER_CELL * full)) ** (1.0 / sum(random)))
    return [max(MIN_RANDOM_BINS, int(round(m * scale))) if rnd else m
            for m, rnd in zip(max_bins, random)]


def _rate(falls, count):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, falls / np.maximum(count, 1), np.nan)


def _polar_figure(cells: dict, rec: dict, path: Path, plt) -> Path:
    n = len(cells["settings"])
    fig, axes = plt.subplots(1, n, subplot_kw=dict(projection="polar"), figsize=(4.6 * n, 4.4),
                             squeeze=False)
    A, J = polar_mesh(cells["azimuth_deg"], cells["impulse_ns"])
    for k, (ax, on) in enumerate(zip(axes[0], cells["settings"])):
        frac = _rate(cells["falls"][k].sum(-1), cells["count"][k].sum(-1))
        mesh = ax.pcolormesh(A, J, frac, cmap="RdYlGn_r", vmin=0, vmax=1, shading="flat")
        for s, style in zip(cells["settings"], ("k--", "b-")):
            azs, jmax = _boundary(rec, s)
            ax.plot(np.radians(np.append(azs, azs[0] + 360)), np.append(jmax, jmax[0]), style,
                    lw=1.2, label=f"boundary, {_setting(s)}")
        ax.set_theta_zero_location("S")
        ax.set_title(f"fall fraction while walking, {_setting(on)}", fontsize=9)
        ax.set_rlabel_position(135)
    axes[0, -1].legend(loc="lower left", bbox_to_anchor=(0.7, -0.14), fontsize=7)
    fig.suptitle(f"radius: {push_size(rec)[1]}; angle: push azimuth (0° = pushed from behind, "
                 "90° = from the right); gait phases pooled", fontsize=8, y=0.02)
    fig.colorbar(mesh, ax=axes[0].tolist(), shrink=0.7)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _boundary(rec: dict, on: bool):
    """max_recoverable_impulse over one recovery setting's records (phases pooled)."""
    sel = (rec["walk_recovery"] > 0.5) == on
    sub = {k: np.asarray(v)[sel] for k, v in rec.items()}
    return max_recoverable_impulse(dict(sub, control=np.ones(int(sel.sum()), bool)), True)


def _phase_figure(cells: dict, path: Path, plt) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, on in enumerate(cells["settings"]):
        ls = "-" if on else "--"
        ax.plot(cells["gait_phase"], 100 * _rate(cells["falls"][k].sum((0, 1)),
                                                 cells["count"][k].sum((0, 1))),
                "o" + ls, color="k", ms=4, lw=1.8, label=f"all directions, {_setting(on)}")
        for a, az in enumerate(cells["azimuth_deg"]):
            ax.plot(cells["gait_phase"], 100 * _rate(cells["falls"][k, a].sum(0),
                                                     cells["count"][k, a].sum(0)),
                    ls, color=f"C{a % 10}", lw=0.9, label=f"{az:g}°, {_setting(on)}")
    ax.set_xlabel("gait phase at the push onset (0 = left touchdown, 0.5 = right touchdown)")
    ax.set_ylabel("fall rate (%)")
    ax.set_xlim(-0.02, 1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _summary(manifest: dict, rec: dict, cells: dict, n_diverged: int) -> tuple[str, dict]:
    """(summary.md, summary.json's document)."""
    walk = manifest.get("spec", {}).get("walk", {})
    on = rec["walk_recovery"] > 0.5
    fell = rec["fell"].astype(bool)
    ok = ~rec["diverged"].astype(bool) if "diverged" in rec else np.ones(len(fell), bool)
    overall = {_setting(s): dict(
        n=int((ok & (on == s)).sum()), fall_rate=round(float(fell[ok & (on == s)].mean()), ROUND),
        mean_distance_survivors_m=round(float(np.mean(
            rec["distance_m"][ok & (on == s) & ~fell])), ROUND) if (ok & (on == s) & ~fell).any()
        else None) for s in cells["settings"]}
    phases = " | ".join(f"{p:.3g}" for p in cells["gait_phase"])
    floor = manifest.get("spec", {}).get("sweep", {})
    slope, roll = floor.get("floor_pitch_deg", 0), floor.get("floor_roll_deg", 0)
    lines = [f"# Walking sweep `{manifest.get('name')}`: {len(fell)} pushes"
             + (f" on a {slope:g}° floor (+ = uphill)" if slope else " on a floor" if roll
                else "") + (f" rolled {roll:g}° (+ = rising to the left)" if roll else ""), "",
             f"Walk: {json.dumps(walk)}; devices: {', '.join(manifest.get('devices', []))}; "
             f"wall {manifest.get('wall_s')} s. " + "; ".join(
                 f"{k}: fall rate {v['fall_rate']:.3f} of {v['n']}, survivors walked "
                 f"{v['mean_distance_survivors_m']} m on average" for k, v in overall.items())
             + (f". {n_diverged} diverged (left out)." if n_diverged else ". None diverged."),
             "", "Fall rate (pushes) per cell: rows azimuth x impulse, columns the gait phase at "
             "onset (0 = left touchdown).", ""]
    cube = []
    for k, s in enumerate(cells["settings"]):
        lines += [f"## {_setting(s)}", "", f"| azimuth (deg) | {push_size(rec)[1]} | {phases} |",
                  "|---|---|" + "---|" * len(cells["gait_phase"])]
        for a, az in enumerate(cells["azimuth_deg"]):
            for j, imp in enumerate(cells["impulse_ns"]):
                f, c = cells["falls"][k, a, j], cells["count"][k, a, j]
                if not c.any():
                    continue
                lines.append(f"| {az:g} | {imp:g} | " + " | ".join(
                    "-" if n == 0 else f"{x / n:.2f} ({int(n)})" for x, n in zip(f, c)) + " |")
                cube += [dict(recovery=_setting(s), azimuth_deg=float(az),
                              **{push_size(rec)[0]: float(imp)},
                              gait_phase=float(ph), n=int(n), falls=int(x))
                         for ph, x, n in zip(cells["gait_phase"], f, c) if n > 0]
        lines.append("")
    return "\n".join(lines), dict(walk=walk, overall=overall, cells=cube)


def make_walk_maps(manifest: dict, rec: dict, maps: Path, plt, n_diverged: int,
                   mark: str = "") -> dict:
    """The walking sweep's maps into `maps` (see the module docstring); `mark`: an incomplete
    sweep's note, put at the top of the summary."""
    cells = walk_cells(rec)
    files = [_polar_figure(cells, rec, maps / "walk_polar.png", plt),
             _phase_figure(cells, maps / "fall_vs_gait_phase.png", plt)]
    text, doc = _summary(manifest, rec, cells, n_diverged)
    if mark:
        text = f"**{mark}**\n\n" + text
        doc["incomplete"] = mark
    (maps / "summary.md").write_text(text)
    (maps / "summary.json").write_text(json.dumps(doc, indent=1) + "\n")
    return dict(files=[str(f) for f in files], summary=str(maps / "summary.md"),
                n_diverged=n_diverged, incomplete=mark)
