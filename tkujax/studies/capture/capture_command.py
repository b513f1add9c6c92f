"""`tkujax capture SPEC --out DIR`: a [step] sweep (run_sweep: chunked, resumable, sharded,
multi-process), then its capture regions, theory overlays, J_1 table, figures and the
gradient-optimal steps, into DIR/capture/. On a robot file (robot=, feet=: see
tkujax.studies.capture.on_robot) the theory and the reach are the robot's."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.studies.capture import figures, theory
from tkujax.studies.capture.on_robot import capture_robot_value, check_capture_robot
from tkujax.studies.capture.region import analyse
from tkujax.dialects.sweep_spec import SpecError, SweepSpec, load_spec
from tkujax.control.params_files import controller_params_from
from tkujax.sweeps.sweep import run_sweep
from tkujax.sweeps.sweep_state import sweep_state


def optimise_cases(regs, spec: SweepSpec, params: ControllerParams, n_cases: int,
                   iterations: int) -> list[dict]:
    """Gradient-optimal steps for up to n_cases pushes (J > 0, non-empty region, first step
    timing), started from the LIP capture point at touchdown (clipped to the grid box)."""
    import jax.numpy as jnp

    from tkujax.sim.push import Push
    from tkujax.studies.capture.optimize import MarginProblem, optimise_steps

    timing0 = min(r.timing for r in regs)
    cand = [r for r in regs if r.timing == timing0 and r.impulse_ns > 0 and r.captured.any()
            and np.isfinite(r.icp_td).all()]
    # Spread over impulses and directions: the hardest (largest J) per azimuth first.
    cand.sort(key=lambda r: (-r.impulse_ns, r.azimuth_deg))
    chosen, seen = [], set()
    for r in cand:
        if r.azimuth_deg not in seen:
            chosen.append(r)
            seen.add(r.azimuth_deg)
    chosen = (chosen + [r for r in cand if r not in chosen])[:n_cases]
    if not chosen:
        return []
    box = float(np.abs(chosen[0].targets).max())
    recs = spec.records()
    pick = lambda k: np.array([recs[k][r.case_id] for r in chosen], np.float32)  # noqa: E731
    pushes = Push(jnp.asarray(pick("impulse_ns")), jnp.radians(jnp.asarray(pick("azimuth_deg"))),
                  jnp.asarray(pick("height_m")), jnp.asarray(pick("duration_s")),
                  jnp.asarray(pick("onset_s")))
    timing = np.array([r.timing for r in chosen])
    problem = MarginProblem(params, duration_s=spec.duration_s)
    start = np.clip(np.array([r.icp_td for r in chosen]), -box, box)
    res = optimise_steps(problem, start, pushes, timing, iterations=iterations, max_target_m=box)
    grid_best = np.array([r.best_cell for r in chosen])
    m_grid, fell_grid = problem.margin(grid_best, pushes, timing)
    out = []
    for k, r in enumerate(chosen):
        h0 = res["history"][0]
        out.append(dict(
            case_id=r.case_id, impulse_ns=r.impulse_ns, azimuth_deg=r.azimuth_deg,
            capture_point=np.round(start[k], 4).tolist(),
            capture_point_margin_deg=h0["margin_deg"][k], capture_point_fell=h0["fell"][k],
            gradient_opt=np.round(res["best"][k], 4).tolist(),
            gradient_opt_margin_deg=float(res["best_margin_deg"][k]),
            gradient_opt_fell=bool(res["best_fell"][k]),
            grid_best=np.round(grid_best[k], 4).tolist(), grid_best_margin_deg=float(m_grid[k]),
            grid_best_fell=bool(fell_grid[k]),
            gradient_opt_in_region=r.distance_to_region(res["best"][k]) == 0.0,
            margin_curve=[h["margin_deg"][k] for h in res["history"]]))
    return out


def _summary_md(manifest: dict, rows: list[dict], j1: list[dict], opt: list[dict],
                files: list[Path], jn: list[dict] | None = None) -> str:
    f = lambda v, s=100, d=1: (  # noqa: E731
        "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{s * v:.{d}f}")
    lines = [f"# Capture regions `{manifest['name']}`: {manifest['n_pushes']} rollouts",
             "", f"Backend {manifest['backend']}, devices {', '.join(manifest['devices'])}, "
             f"wall {manifest['wall_s']} s (compile included).", "",
             "Per push and step timing; targets and points in cm (swing ankle vs its stand pose); "
             "gap = distance from the controller's own step to the region (0 inside) and to its "
             "centroid.", "",
             "| J (N·s) | az (deg) | delay (ms) | captured / targets | area (cm²) | centroid | "
             "ICP at touchdown | Koolen R₁ | controller step | ctrl fell | gap region | "
             "gap centroid |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['impulse_ns']:.2f} | {r['azimuth_deg']:.0f} | {1000 * r['start_delay_s']:.0f} | "
            f"{r['n_captured']}/{r['n_targets']} | {r['area_cm2']:.0f} | "
            f"({f(r['centroid_x_m'])}, {f(r['centroid_y_m'])}) | "
            f"({f(r['icp_td_x_m'])}, {f(r['icp_td_y_m'])}) | "
            f"{'non-empty' if r['koolen_nonempty'] else 'empty'} | "
            f"({f(r['controller_x_m'])}, {f(r['controller_y_m'])}) | "
            f"{'-' if r['controller_fell'] is None else int(r['controller_fell'])} | "
            f"{f(r['gap_region_m'])} | {f(r['gap_centroid_m'])} |")
    lines += ["", "J₁ per direction (N·s): empirical = largest tested impulse with a non-empty "
              "region; theory = Koolen R₁ meets the reach l_max, with the measured step time Δt "
              "(push onset to touchdown).", "",
              "| az (deg) | delay (ms) | Δt (s) | J₁ empirical | J₁ theory | "
              "controller's own: largest survived |",
              "|---|---|---|---|---|---|"]
    for r in j1:
        lines.append(f"| {r['azimuth_deg']:.0f} | {1000 * r['start_delay_s']:.0f} | "
                     f"{r['dt_s']:.3f} | {r['j1_empirical']:.2f} | {f(r['j1_theory'], 1, 2)} | "
                     f"{r['controller_max_survived']:.2f} |")
    if jn and any(r["j2_empirical"] is not None for r in jn):
        lines += ["", "Empirical N-step limits (N·s): J_N = the largest tested impulse for which "
                  "any commanded single step (N = 1) or any commanded pair of steps (N = 2, the "
                  "other foot second) did not fall; a lower bound (grid targets only). "
                  "Survivors: targets (or pairs) that did not fall / tried, per impulse.", "",
                  "| az (deg) | delay (ms) | J₁ | J₂ | controller's own | impulses | "
                  "survivors N = 1 | survivors N = 2 |", "|---|---|---|---|---|---|---|---|"]
        for r in jn:
            ctrl = r["controller_max_survived"]
            lines.append(
                f"| {r['azimuth_deg']:.0f} | {1000 * r['start_delay_s']:.0f} | "
                f"{r['j1_empirical'] if r['j1_empirical'] is not None else '-'} | "
                f"{r['j2_empirical'] if r['j2_empirical'] is not None else '-'} | "
                f"{'-' if ctrl is None else ctrl} | "
                f"{', '.join(f'{j:g}' for j in r['impulses_tested'])} | "
                f"{', '.join(r['survivors_1'] or [])} | {', '.join(r['survivors_2'] or [])} |")
    if opt:
        lines += ["", "Gradient-optimal steps (Adam on the capture margin through MJX, from the "
                  "LIP capture point at touchdown); margin = minus the RMS inclination deviation "
                  "after onset (deg, higher is better).", "",
                  "| J | az | capture point (cm) → margin, fell | grid best cell | "
                  "gradient optimum |",
                  "|---|---|---|---|---|"]
        for o in opt:
            cell = lambda p, m, fl: f"({100 * p[0]:.1f}, {100 * p[1]:.1f}) → {m:.2f}°, {int(fl)}"  # noqa: E731
            cp = cell(o['capture_point'], o['capture_point_margin_deg'], o['capture_point_fell'])
            gb = cell(o['grid_best'], o['grid_best_margin_deg'], o['grid_best_fell'])
            go = cell(o['gradient_opt'], o['gradient_opt_margin_deg'], o['gradient_opt_fell'])
            lines.append(f"| {o['impulse_ns']:.2f} | {o['azimuth_deg']:.0f} | "
                         f"{cp} | {gb} | {go} |")
    lines += ["", "Figures: " + ", ".join(f"`{p.name}`" for p in files), ""]
    return "\n".join(lines)


def run_capture(spec: SweepSpec | str | Path, out: str | Path,
                params: ControllerParams | None = None, optimise: int = 4,
                iterations: int = 15, robot=None, feet: theory.Feet | None = None,
                allow_incomplete: bool = False, **sweep_kwargs) -> dict:
    """Run (or resume) the [step] sweep, then write DIR/capture/: regions.json, j1.json,
    optimise.json, summary.md and the figures. optimise: how many pushes get a
    gradient-optimal step (0 skips it; TKU-X only). robot, feet: a robot file's Robot and
    its capture geometry (`tkujax.studies.robot_inputs.capture_robot` loads both; the spec's [robot]
    file needs them), None for TKU-X. sweep_kwargs go to run_sweep (backend, max_chunks,
    process ids, ...). A sweep left incomplete (max_chunks, other processes) is not analysed
    (complete False) unless allow_incomplete: then its chunks done are, every output marked
    "incomplete: k of n chunks" (`tkujax.sweeps.sweep_state`)."""
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    if not spec.step_grid:
        raise SpecError("tkujax capture needs a spec with a [step.grid] table")
    if not 0 <= optimise <= 1000 or not 1 <= iterations <= 1000:
        raise SpecError(f"optimise must be in [0, 1000] and iterations in [1, 1000], got "
                        f"{optimise}, {iterations}")
    robot = capture_robot_value(robot)
    params = params or (ControllerParams.paper() if robot is None else robot.params)
    base = controller_params_from(params, spec.controller)
    feet = check_capture_robot(spec, robot, feet, base)
    if robot is not None:
        # The gradient study's MJX problem is built on TKU-X's model.
        optimise = 0
        sweep_kwargs["robot"] = robot
    manifest = run_sweep(spec, out, params=params, **sweep_kwargs)
    state = sweep_state(out)
    if not state.complete and not allow_incomplete:
        return dict(manifest=manifest, complete=False, incomplete=state.mark)
    feet = feet or theory.stand_feet(params=base)
    res = analyse(out, feet, allow_incomplete)
    dest = res["dir"]
    files = figures.region_panels(res["regions"], dest, feet.reach_m, state.mark)
    files.append(figures.j1_figure(res["j1"], dest, state.mark))
    opt = []
    if optimise:
        t0 = time.perf_counter()
        opt = optimise_cases(res["regions"], spec, base, optimise, iterations)
        (dest / "optimise.json").write_text(json.dumps(
            dict(wall_s=round(time.perf_counter() - t0, 1), iterations=iterations, cases=opt),
            indent=1))
    text = _summary_md(manifest, res["rows"], res["j1"], opt, files, res["jn"])
    if state.mark:
        text = f"**{state.mark}**: the regions below hold the records of " \
            f"{state.chunks_done} of {state.n_chunks} chunks.\n\n" + text
    (dest / "summary.md").write_text(text)
    return dict(manifest=manifest, complete=state.complete, incomplete=state.mark,
                regions=res["rows"], j1=res["j1"],
                jn=res["jn"], optimise=opt, files=[str(p) for p in files],
                summary=str(dest / "summary.md"), feet=feet)
