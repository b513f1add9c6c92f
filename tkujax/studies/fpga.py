"""`tkujax fpga SPEC --out DIR`: which word lengths, CORDIC iterations and latencies keep the
push recovery of the float controller.

Runs the spec (controller.arithmetic = "fixed", [fpga] keys gridded in [controller.grid]) into
DIR/sweep, and the float reference (the same pushes, float controller, no [fpga]) into
DIR/float; then, in DIR/fpga:

  agreement.png     per gridded key: fraction of pushes whose outcome (fell) equals the float
                    controller's, the other keys at their most generous value
  boundary.png      max survivable impulse per azimuth (`maps.max_recoverable_impulse`) per
                    value of each key, against the float boundary
  latency.png       the boundary (mean and min over azimuths) vs total latency in periods
  summary.md / summary.json   (each configuration with its EP3C120 resource estimate:
                    18x18 multipliers, register bits, latency cycles; `resources.py`)
  resources.md / resources.json   the full estimate of the spec's [fpga] config

"Most generous": the most bits and iterations, zero latency, round-to-nearest; for one key's
curve every other key sits there, so each curve isolates one design choice. A boundary "moves"
where it differs from the float one by more than one impulse grid step (one step is the
resolution of the grid itself).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from tkujax.control.fixed.qformat import ROUNDING_MODES
from tkujax.control.fixed.support import check_supported
from tkujax.control.controller_params import ControllerParams
from tkujax.analysis.map_cells import max_recoverable_impulse
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.dialects.sweep_spec import (FPGA_COLUMN, SpecError, SweepSpec, fixed_point_config,
                                        load_spec,
                                        parse_spec)
from tkujax.control.params_files import controller_params_from
from tkujax.sweeps.sweep import load, run_sweep

# Keys whose generous end is the smallest value (less latency is better); the rest: largest
# (more bits, more iterations); rounding: "nearest" (index 0).
_LOWER_IS_GENEROUS = ("latency_ticks", "latency_frac", "rounding")
_PUSH_KEYS = ("impulse_ns", "azimuth_deg", "height_m", "onset_s", "duration_s", "control")


def float_reference_spec(spec: SweepSpec) -> SweepSpec:
    """The same pushes (and controller grid) with the float controller, no [fpga]."""
    raw = copy.deepcopy(spec.raw)
    raw.pop("fpga", None)
    ctrl = raw.get("controller", {})
    ctrl.pop("arithmetic", None)
    ctrl.get("grid", {}).pop("fpga", None)
    raw.setdefault("sweep", {})["name"] = f"{spec.name}_float_reference"
    return parse_spec(raw)


def _match_float(rec: dict, ref: dict, keys: tuple[str, ...]) -> np.ndarray:
    """Row of `ref` holding the same push (and controller-grid point) as each row of `rec`."""
    def key(r, i):
        return tuple(round(float(r[k][i]), 6) for k in keys)
    index = {key(ref, i): i for i in range(len(ref["push_id"]))}
    try:
        return np.array([index[key(rec, i)] for i in range(len(rec["push_id"]))])
    except KeyError as err:
        raise ValueError(f"float reference has no record for push {err}") from None


def _configs(rec: dict, gridded: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(unique configurations (n_cfg, n_keys), configuration index of each record)."""
    if not gridded:
        return np.zeros((1, 0)), np.zeros(len(rec["push_id"]), int)
    table = np.stack([np.asarray(rec[FPGA_COLUMN + k], float) for k in gridded], 1)
    cfgs, which = np.unique(table, axis=0, return_inverse=True)
    return cfgs, which.ravel()


def _generous(cfgs: np.ndarray, gridded: list[str]) -> np.ndarray:
    return np.array([cfgs[:, j].min() if k in _LOWER_IS_GENEROUS else cfgs[:, j].max()
                     for j, k in enumerate(gridded)])


def _label(k: str, v: float) -> str:
    return f"{k}={ROUNDING_MODES[int(v)]}" if k == "rounding" else f"{k}={v:g}"


def _config_rows(fixed: dict, ref: dict, match: np.ndarray, cfgs: np.ndarray, which: np.ndarray,
                 gridded: list[str], grid_step: float, step_tol_m: float) -> list[dict]:
    """One row per fixed-point configuration: agreement of the fall outcomes with the float
    controller's, step differences, and the fall boundary's shift per azimuth."""
    fell, fell_ref = fixed["fell"].astype(bool), ref["fell"][match].astype(bool)
    div = fixed["diverged"].astype(bool) | ref["diverged"][match].astype(bool)
    same = (fell == fell_ref) & ~div
    both_up = ~fell & ~fell_ref & ~div
    dstep = np.abs(fixed["step_length_m"] - ref["step_length_m"][match])
    azs, b_ref = max_recoverable_impulse(ref, True)
    rows = []
    for c, cfg in enumerate(cfgs):
        sel = which == c
        az_c, b = max_recoverable_impulse({k: v[sel] for k, v in fixed.items()}, True)
        assert np.allclose(az_c, azs), "the configuration's azimuths differ from the reference's"
        shift = b - b_ref
        ok = sel & both_up
        rows.append(dict(
            config={k: (ROUNDING_MODES[int(v)] if k == "rounding" else float(v))
                    for k, v in zip(gridded, cfg)},
            n=int(sel.sum()), agreement=float(same[sel].mean()),
            n_differ=int((sel & ~same).sum()), n_diverged=int((sel & div).sum()),
            max_step_diff_m=float(dstep[ok].max()) if ok.any() else 0.0,
            step_within_tol=float((dstep[ok] <= step_tol_m).mean()) if ok.any() else 1.0,
            boundary_ns=[float(x) for x in b], boundary_shift_ns=[float(x) for x in shift],
            boundary_moved=bool((np.abs(shift) > grid_step + 1e-9).any()),
            moved_azimuths_deg=[float(a) for a, s in zip(azs, shift)
                                if abs(s) > grid_step + 1e-9]))
    return rows


def _one_key_at_a_time(cfgs: np.ndarray, gen: np.ndarray, gridded: list[str],
                       rows: list[dict]) -> dict:
    """Per gridded key, the others at their generous value: agreement and boundary by value,
    and the stingiest value from which on every more generous one agrees fully."""
    axes = {}
    for j, k in enumerate(gridded):
        others = np.all(np.delete(cfgs, j, 1) == np.delete(gen, j), 1)
        idx = [int(i) for i in np.flatnonzero(others)]
        idx.sort(key=lambda i: cfgs[i, j])
        vals = [float(cfgs[i, j]) for i in idx]
        agree = [rows[i]["agreement"] for i in idx]
        # Walk from the generous end while agreement stays 100 %: the last value reached is
        # the stingiest one from which on every more generous value agrees too.
        good = None
        for pos in (range(len(idx)) if k in _LOWER_IS_GENEROUS
                    else range(len(idx) - 1, -1, -1)):
            if agree[pos] < 1.0:
                break
            good = vals[pos]
        axes[k] = dict(values=vals, configs=idx, agreement=agree, threshold=good,
                       boundary_mean_ns=[float(np.mean(rows[i]["boundary_ns"])) for i in idx],
                       boundary_min_ns=[float(np.min(rows[i]["boundary_ns"])) for i in idx],
                       moved=[rows[i]["boundary_moved"] for i in idx])
    return axes


def _latency(cfgs: np.ndarray, gen: np.ndarray, gridded: list[str],
             rows: list[dict]) -> dict | None:
    """The boundary and agreement by total latency (ticks + fraction, in control periods),
    the other keys at their generous value; None when the spec grids no latency."""
    lat_keys = [k for k in ("latency_ticks", "latency_frac") if k in gridded]
    if not lat_keys:
        return None
    lat_j = [gridded.index(k) for k in lat_keys]
    rest = [j for j in range(len(gridded)) if j not in lat_j]
    sel_cfg = [c for c in range(len(cfgs)) if np.all(cfgs[c, rest] == gen[rest])]
    per = {}
    for c in sel_cfg:
        total = sum(float(cfgs[c, j]) for j in lat_j)   # ticks + fraction, in periods
        per[total] = c
    lats = sorted(per)
    latency = dict(periods=lats, configs=[per[t] for t in lats],
                   boundary_mean_ns=[float(np.mean(rows[per[t]]["boundary_ns"])) for t in lats],
                   boundary_min_ns=[float(np.min(rows[per[t]]["boundary_ns"])) for t in lats],
                   agreement=[rows[per[t]]["agreement"] for t in lats],
                   moved=[rows[per[t]]["boundary_moved"] for t in lats])
    ok = None   # largest latency up to which no boundary moved more than one step
    for t in lats:
        if rows[per[t]]["boundary_moved"]:
            break
        ok = t
    latency["tolerated_periods"] = ok
    return latency


def analyse(fixed: dict, ref: dict, spec: SweepSpec, step_tol_m: float = 0.005) -> dict:
    """The hardware designer's numbers (see the module doc) from the two record sets."""
    gridded = list(spec.fpga_grid)
    keys = _PUSH_KEYS + tuple(sorted(spec.controller_grid))
    match = _match_float(fixed, ref, keys)
    cfgs, which = _configs(fixed, gridded)
    gen = _generous(cfgs, gridded)
    impulses = np.unique(np.round(fixed["impulse_ns"], 6))
    grid_step = float(np.median(np.diff(impulses))) if len(impulses) > 1 else 0.0
    azs, b_ref = max_recoverable_impulse(ref, True)
    rows = _config_rows(fixed, ref, match, cfgs, which, gridded, grid_step, step_tol_m)
    full = [r for r in rows if r["agreement"] == 1.0]
    return dict(gridded=gridded, generous={k: float(v) for k, v in zip(gridded, gen)},
                azimuths_deg=[float(a) for a in azs], impulse_step_ns=grid_step,
                float_boundary_ns=[float(x) for x in b_ref], step_tol_m=step_tol_m,
                float_fell_fraction=float(ref["fell"].astype(bool).mean()),
                configs=rows, axes=_one_key_at_a_time(cfgs, gen, gridded, rows),
                latency=_latency(cfgs, gen, gridded, rows),
                n_configs=len(rows), n_full_agreement=len(full),
                n_boundary_moved=sum(r["boundary_moved"] for r in rows))


def _plots(res: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    axes = res["axes"]
    keys = list(axes)
    if keys:
        fig, axs = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3.4), squeeze=False)
        for ax, k in zip(axs[0], keys):
            a = axes[k]
            ax.plot(a["values"], [100 * x for x in a["agreement"]], "o-")
            if a["threshold"] is not None:
                ax.axvline(a["threshold"], color="g", ls="--",
                           label=f"100 % from {a['threshold']:g}")
                ax.legend(fontsize=8)
            ax.set_xlabel(k)
            ax.set_ylabel("outcome = float (%)")
            ax.set_ylim(-5, 105)
            ax.grid(alpha=0.3)
        fig.suptitle("Agreement with the float controller (other keys at their generous value)",
                     fontsize=10)
        fig.tight_layout()
        files.append(out / "agreement.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)

        fig, axs = plt.subplots(1, len(keys), figsize=(4.3 * len(keys), 3.6), squeeze=False)
        azs = res["azimuths_deg"]
        for ax, k in zip(axs[0], keys):
            a = axes[k]
            ax.plot(azs, res["float_boundary_ns"], "k-", lw=2.5, label="float")
            for v, c in zip(a["values"], a["configs"]):
                cfg = res["configs"][c]
                ax.plot(azs, cfg["boundary_ns"], "o--" if cfg["boundary_moved"] else ".-",
                        label=_label(k, v) + (" (moved)" if cfg["boundary_moved"] else ""))
            ax.set_xlabel("push azimuth (deg)")
            ax.set_ylabel("max survivable impulse (N s)")
            ax.set_title(k, fontsize=9)
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
        fig.tight_layout()
        files.append(out / "boundary.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)

    lat = res["latency"]
    if lat:
        fig, ax = plt.subplots(figsize=(5, 3.6))
        ax.plot(lat["periods"], lat["boundary_mean_ns"], "o-", label="mean over azimuths")
        ax.plot(lat["periods"], lat["boundary_min_ns"], "s-", label="min over azimuths")
        ax.axhline(np.mean(res["float_boundary_ns"]), color="k", ls=":", label="float, mean")
        ax.axhline(np.min(res["float_boundary_ns"]), color="k", ls="--", label="float, min")
        ax.set_xlabel("sensor-to-servo latency (control periods of 30 ms)")
        ax.set_ylabel("max survivable impulse (N s)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        files.append(out / "latency.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    return files


def _markdown(res: dict, spec: SweepSpec, manifests: dict) -> str:
    L = [f"# FPGA fixed-point study: {spec.name}", ""]
    L.append(f"{res['n_configs']} fixed-point configurations x "
             f"{res['configs'][0]['n']} pushes, against the float controller on the same pushes "
             f"(backend {manifests['fixed'].get('backend')}; "
             f"wall {manifests['fixed'].get('wall_s')}"
             f" s fixed + {manifests['float'].get('wall_s')} s float). Outcome = fell; "
             f"configurations vary {res['gridded'] or 'nothing'} (others at the spec's [fpga] "
             f"values or FixedPointConfig defaults).")
    L.append("")
    L.append(f"- configurations with 100 % agreement: {res['n_full_agreement']} of "
             f"{res['n_configs']}")
    L.append(f"- configurations whose boundary moves by more than one impulse step "
             f"({res['impulse_step_ns']:.3g} N s) at some azimuth: {res['n_boundary_moved']}")
    L.append(f"- float boundary (max survivable impulse, N s) per azimuth "
             f"{res['azimuths_deg']}: {res['float_boundary_ns']}")
    for k, a in res["axes"].items():
        thr = "no value" if a["threshold"] is None else f"{a['threshold']:g}"
        where = "up to" if k in _LOWER_IS_GENEROUS else "from"
        gen = {kk: v for kk, v in res["generous"].items() if kk != k}
        L.append(f"- {k}: 100 % agreement {where} {thr} (tested {a['values']}, agreement "
                 f"{[round(100 * x, 1) for x in a['agreement']]} %; others at {gen})")
    lat = res["latency"]
    if lat:
        L.append(f"- latency tolerated without the boundary moving more than one step: "
                 f"{lat['tolerated_periods']} periods (tested {lat['periods']}; boundary mean "
                 f"{[round(x, 3) for x in lat['boundary_mean_ns']]} N s, min "
                 f"{[round(x, 3) for x in lat['boundary_min_ns']]})")
    rcols = "resources" in res["configs"][0]
    L += ["", "| " + " | ".join(res["gridded"]) + " | agreement | differ | max step diff (mm) | "
          "boundary moved at (deg) |" + (" 18x18 shared / parallel | register bits | latency "
                                          "(cycles) |" if rcols else ""),
          "|" + "---|" * (len(res["gridded"]) + 4 + 3 * rcols)]
    for r in res["configs"]:
        vals = [str(v) if isinstance(v, str) else f"{v:g}" for v in r["config"].values()]
        row = ("| " + " | ".join(vals) + f" | {100 * r['agreement']:.1f} % | {r['n_differ']} | "
               f"{1000 * r['max_step_diff_m']:.2f} | "
               f"{', '.join(f'{a:g}' for a in r['moved_azimuths_deg']) or '-'} |")
        if rcols:
            q = r["resources"]
            row += (f" {q['multipliers_18x18']} / {q['multipliers_18x18_parallel']} | "
                    f"{q['register_bits']:,} | {q['latency_cycles']:,} |")
        L.append(row)
    if rcols:
        L += ["", "Resources: EP3C120 estimate per configuration (`tkujax fpga --resources`, "
              "architecture and rules in tkujax/control/fixed/resources.py; resources.md holds "
              "the spec's base configuration)."]
    L.append("")
    return "\n".join(L)


def resource_summary(config) -> dict:
    """The few resource numbers shown beside agreement (resources.py for the full estimate)."""
    from tkujax.control.fixed.resources import resources
    t = resources(config)["total"]
    return {k: t[k] for k in ("multipliers_18x18", "multipliers_18x18_parallel", "register_bits",
                              "logic_elements", "latency_cycles", "cordic_stages_unrolled")}


def write_resources(spec: SweepSpec | str | Path | None, out: str | Path | None):
    """The EP3C120 estimate (markdown, and json) of the spec's [fpga] values over the
    FixedPointConfig defaults (no spec: the defaults); written to out/resources.md and .json
    when out is given. Returns (markdown, files)."""
    from tkujax.control.fixed.resources import resources, resources_markdown
    if spec is None:
        config = FixedPointConfig()
    else:
        spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
        if spec.arithmetic != "fixed":
            raise SpecError('tkujax fpga: the spec needs controller.arithmetic = "fixed"')
        config = fixed_point_config(spec.fpga)
    res = resources(config)
    md = resources_markdown(res)
    files = []
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        files = [out / "resources.md", out / "resources.json"]
        files[0].write_text(md)
        files[1].write_text(json.dumps(res, indent=1))
    return md, files


def run_fpga(spec: SweepSpec | str | Path, out: str | Path,
             params: ControllerParams | None = None, backend: str = "auto",
             quiet: bool = False) -> dict:
    """Run (or resume) the fixed-point sweep and its float reference, then analyse and plot.

    Returns {"summary": path, "files": [...], "result": analyse(...)}."""
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    if spec.arithmetic != "fixed":
        raise SpecError('tkujax fpga: the spec needs controller.arithmetic = "fixed"')
    check_supported(controller_params_from(params or ControllerParams.paper(), spec.controller))
    out = Path(out)
    m_fixed = run_sweep(spec, out / "sweep", params=params, backend=backend, quiet=quiet)
    m_float = run_sweep(float_reference_spec(spec), out / "float", params=params,
                        backend=backend, quiet=quiet)
    if not (m_fixed["complete"] and m_float["complete"]):
        raise RuntimeError(f"{out}: sweep incomplete; rerun the same command to resume")
    res = analyse(load(out / "sweep"), load(out / "float"), spec)
    for row in res["configs"]:     # resources beside agreement
        row["resources"] = resource_summary(fixed_point_config(spec.fpga | row["config"]))
    dest = out / "fpga"
    dest.mkdir(parents=True, exist_ok=True)
    write_resources(spec, dest)
    files = _plots(res, dest)
    (dest / "summary.json").write_text(json.dumps(res, indent=1))
    summary = dest / "summary.md"
    summary.write_text(_markdown(res, spec, {"fixed": m_fixed, "float": m_float}))
    return dict(summary=summary, files=[str(f) for f in files + [dest / "summary.json", summary]],
                result=res)
