"""Capture-region figures: small multiples (rows impulse, columns azimuth) and J_1 per direction.
Axes in cm, target coordinates (the swing ankle relative to its stand pose)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tkujax.studies.capture.region import Region


def _timing_name(t) -> str:
    base = f"{'detection' if t[1] > 0.5 else 'onset'} + {1000 * t[0]:.0f} ms"
    return base + (f", T = {t[2]:.2f} s" if t[2] > 0 else "")


def mark_figure(fig, mark: str) -> None:
    """`mark` ("incomplete: k of n chunks") in red at the figure's top; nothing when empty."""
    if mark:
        fig.text(0.5, 0.995, mark, ha="center", va="top", color="red", fontsize=9,
                 weight="bold")


def region_panels(regs: list[Region], out: Path, reach_m: float, mark: str = "") -> list[Path]:
    """One figure per step timing: panels of region, Koolen R_1, ICP at touchdown, controller."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    files = []
    for k, timing in enumerate(sorted({r.timing for r in regs})):
        rs = [r for r in regs if r.timing == timing]
        js = sorted({r.impulse_ns for r in rs})
        azs = sorted({r.azimuth_deg for r in rs})
        cell = {(r.impulse_ns, r.azimuth_deg): r for r in reversed(rs)}   # first case wins
        fig, axes = plt.subplots(len(js), len(azs), figsize=(2.1 * len(azs) + 0.6,
                                                              2.1 * len(js) + 0.9),
                                 sharex=True, sharey=True, squeeze=False)
        for i, j in enumerate(js):
            for c, az in enumerate(azs):
                ax, r = axes[i, c], cell.get((j, az))
                ax.set_aspect("equal")
                ax.grid(alpha=0.2)
                if r is None:
                    continue
                t = 100 * r.targets
                ax.scatter(*t[~r.captured].T, s=3, c="0.8", marker=".", lw=0)
                ax.scatter(*t[r.captured].T, s=9, c="tab:green", marker="s", lw=0)
                for poly in r.koolen:
                    ax.add_patch(Polygon(100 * poly, closed=True, fill=False, ec="tab:blue",
                                         ls="--", lw=0.9))
                ax.add_patch(plt.Circle((0, 0), 100 * reach_m, fill=False, ec="0.5", ls=":",
                                        lw=0.7))
                if r.captured.any():
                    ax.plot(*(100 * r.centroid), "k+", ms=7)
                ax.plot(*(100 * r.icp_td), "*", c="tab:orange", ms=7)
                ax.plot(*(100 * r.controller), "x", c="tab:red", ms=6, mew=1.5)
                lim = 100 * max(np.abs(r.targets).max() * 1.25, 0.05)
                ax.set_xlim(-lim, lim)
                ax.set_ylim(-lim, lim)
                ax.tick_params(labelsize=6)
                if i == 0:
                    ax.set_title(f"azimuth {az:.0f}°", fontsize=8)
                if c == 0:
                    ax.set_ylabel(f"J = {j:.2f} N·s\ny (cm)", fontsize=7)
                if i == len(js) - 1:
                    ax.set_xlabel("x (cm)", fontsize=7)
        handles = [Patch(fc="tab:green", label="recovers (one-step region)"),
                   Patch(fc="0.8", label="falls"),
                   Line2D([], [], c="tab:blue", ls="--", label="Koolen R₁ (LIP, step time)"),
                   Line2D([], [], c="0.5", ls=":", label="step reach l_max"),
                   Line2D([], [], c="tab:orange", marker="*", ls="",
                          label="LIP capture point at touchdown (sim CoM)"),
                   Line2D([], [], c="tab:red", marker="x", ls="",
                          label="controller's own step (x_Sup, y_Sup)"),
                   Line2D([], [], c="k", marker="+", ls="", label="region centroid")]
        fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=7, frameon=False)
        fig.suptitle(f"One-step capture regions, step from {_timing_name(timing)}\nswing ankle "
                     "vs its stand pose (x forward, y left; left foot for y ≥ 0)\nazimuth 0° = "
                     "pushed from behind, 90° = from the right", fontsize=8)
        fig.tight_layout(rect=(0, 0.07, 1, 0.93))
        files.append(out / f"regions_{k}.png")
        mark_figure(fig, mark)
        fig.savefig(files[-1], dpi=90)
        plt.close(fig)
    return files


def j1_figure(rows: list[dict], out: Path, mark: str = "") -> Path:
    """Empirical vs theoretical J_1 per direction (one line pair per step timing)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    timings = sorted({(r["start_delay_s"], r["from_detection"], r["period_s"]) for r in rows})
    for k, t in enumerate(timings):
        rs = sorted((r for r in rows if (r["start_delay_s"], r["from_detection"],
                                         r["period_s"]) == t), key=lambda r: r["azimuth_deg"])
        az = [r["azimuth_deg"] for r in rs]
        col = f"C{k}"
        ax.plot(az, [r["j1_empirical"] for r in rs], "o-", c=col,
                label=f"empirical J₁, step from {_timing_name(t)}")
        ax.plot(az, [math.nan if r["j1_theory"] is None else r["j1_theory"] for r in rs], "s--",
                c=col, mfc="none", label=f"theory J₁ (Δt = {rs[0]['dt_s']:.2f} s)")
        if k == 0:
            ax.plot(az, [r["controller_max_survived"] for r in rs], "x:", c="tab:red",
                    label="controller's own step: largest survived")
    ax.set_xlabel("push azimuth (deg; 0 = from behind, 90 = from the right)")
    ax.set_ylabel("impulse (N·s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("J₁: largest impulse with a non-empty one-step capture region "
                 "(grid resolution applies)", fontsize=8)
    fig.tight_layout()
    path = out / "j1.png"
    mark_figure(fig, mark)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
