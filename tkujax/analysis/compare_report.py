"""What `tkujax compare` writes: the difference maps and the by-sector figure, table.csv and
table.md, and summary.md for a person. The numbers come from `tkujax.analysis.compare`
(cell_table, verdict, difference_cells); files are written whole or not at all."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from tkujax.analysis.map_cells import polar_mesh


def write_text_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` whole or not at all (a temporary file, then a rename)."""
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
    A, J = polar_mesh(cells["azimuths"], cells["impulses"])
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
    fig.suptitle(f"radius: {cells['size_label']}; angle: push azimuth (0° = pushed from "
                 f"behind, at the bottom; 90° = from the right); cells with < {min_count} "
                 "pushes blank",
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
        ax.set_xlabel(table["size_label"].replace(" ", " band centre ", 1), fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("fall rate (%)")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    fig.tight_layout()
    _save_fig(fig, path)
    plt.close(fig)


def table_csv(table: dict, labels: list[str]) -> str:
    key = table["size_key"]                          # impulse_lo_ns, or kick_lo_mps
    head = ["sector", key.replace("_", "_lo_", 1), key.replace("_", "_hi_", 1), "phase_lo",
            "phase_hi"]
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


def markdown_table(table: dict, labels: list[str], phase: str | None) -> list[str]:
    """Rows of one phase band ('all' = pooled; None = every phase band)."""
    head = f"| sector | {table['size_label']} | phase | " + " | ".join(
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


def summary_markdown(runs: list, table: dict, verdict_: dict, files: list[str]) -> str:
    """summary.md: the runs (`tkujax.analysis.compare.Run`), the verdict, the worst cells."""
    labels = [r.label for r in runs]
    ref = verdict_["reference"]
    lines = [f"# tkujax compare: {len(runs) - 1} run(s) against `{ref['label']}`", "",
             "Runs (same pushes, checked column by column): " + "; ".join(
                 f"`{r.label}` = {r.path} control {r.control}, {int((~r.diverged).sum())} "
                 "pushes" + (f", {int(r.diverged.sum())} diverged (left out)"
                             if r.diverged.any() else "")
                 + ("" if r.complete else f" (**{r.mark or 'incomplete'}**)")
                 for r in runs) + ".", "",
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
                      f"| sector | {table['size_label']} | phase | pushes | reference | run "
                      "| diff (pp ± s.e.) | beyond 2 s.e. |", "|---|---|---|---|---|---|---|---|"]
            for h in sorted(v["harmed_cells"], key=lambda h: -h["diff_pp"]):
                se = "" if h["se_pp"] is None else f" ± {h['se_pp']:.1f}"
                lo, hi = h[table["size_key"]]
                lines.append(f"| {h['sector']} | {lo:.2f}-{hi:.2f}"
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
    lines += markdown_table(table, labels, "all")
    lines += ["", "Files: " + ", ".join(Path(f).name for f in files) + "."]
    return _kick_words(table, "\n".join(lines) + "\n")


def _kick_words(table: dict, text: str) -> str:
    """A kick sweep's text (`tkujax.analysis.map_cells.push_size`): its bands are kicks'."""
    if table["size_key"] == "impulse_ns":
        return text
    return text.replace("impulse band", "kick band").replace("impulses and", "kicks and")


def table_markdown(table: dict, labels: list[str]) -> str:
    """table.md: the cells per phase band, then with the phases pooled."""
    return _kick_words(table, "# Fall rate by sector × impulse band × phase band\n\nCells: "
                       "fall rate (pushes); after the reference: difference to it, pp ± paired "
                       "s.e.\n\n" + "\n".join(markdown_table(table, labels, None))
                       + "\n\n## Phases pooled\n\n"
                       + "\n".join(markdown_table(table, labels, "all")) + "\n")
