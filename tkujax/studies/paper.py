"""`tkujax paper`: the paper's 8 cases (Tables 4-5, Figs. 13-16) in simulation.

Baseball and volleyball, from the back and from the front, balance control off and on, hit at
0.75 s. Each ball is applied as a 20 ms half-sine impulse: its momentum at impact (m v of the
pendulum rig, `tkujax.sim.push.ball_momentum_ns`) times the contact's transfer factor, at the
contact height (`tkujax.sim.push.BallContact`: calibrated by default, variant="estimated" for
the earlier mid-chest, factor-1 estimate together with ModelParams.estimated()).

0.75 s is a controller tick, so the 20 ms pulse falls between two IMU samples. The paper's robot
was hit at an unknown phase of its 30 ms period, so `run_paper` also replays each case at
`phases` onsets 0.75 + phase * 30 ms (phase.csv, phase.md): the fall fraction and the range of
step length, x_Sup and peak inclination across the period.
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path

import numpy as np

from tkujax.sim import push as push_lib
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim.rollout_mjx import RolloutConfig, simulate

BALL_NAMES = ("baseball", "volleyball")
DIRECTION_NAMES = ("back", "front")
# Tables 4 (back) and 5 (front): recovery time (s, None = fell) and step length (cm, None = X).
PAPER_TABLE = {
    ("back", "baseball", "off"): (0.60, None), ("back", "baseball", "on"): (0.25, 1.36),
    ("back", "volleyball", "off"): (None, None), ("back", "volleyball", "on"): (0.25, 4.15),
    ("front", "baseball", "off"): (0.65, None), ("front", "baseball", "on"): (0.20, 1.09),
    ("front", "volleyball", "off"): (0.97, None), ("front", "volleyball", "on"): (0.37, 3.88),
}
NO_STEP_M = 0.005   # swing-ankle displacement below 5 mm is "no step"
RECOVERY_NOTE = (
    "Two recovery readings (tkujax.sim.metrics): \"sim: recovery\" (recovery_time_s) waits for "
    "hypot(pitch, roll) to stay within 1 deg of the stand; \"pitch only\" "
    "(recovery_time_pitch_s) waits for the pitch alone, the paper's phi (\"pitch-axis\", Figs. "
    "13-16). They differ where a roll offset persists after a step. The calibration fit "
    "(tkujax.studies.calibrate.paper_rows) reads recovery_time_s, the hypot one: see "
    "results/calibration/FINDINGS.md (recovery readings) for why and what it changes.")


def paper_cases() -> list[tuple[str, str, str]]:
    return [(d, b, c) for d in DIRECTION_NAMES for b in BALL_NAMES for c in ("off", "on")]


VARIANTS = ("calibrated", "estimated")


def variant_setup(variant: str, model_params: ModelParams | None = None
                  ) -> tuple[ModelParams | None, push_lib.BallContact, ControllerParams]:
    """(model, ball contact, controller) of a variant: "calibrated" (the defaults) or
    "estimated" (the robot, ball contact and Kalman noises before calibration). A given
    model_params replaces the variant's model."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    if variant == "estimated":
        model_params = model_params or ModelParams.estimated()
        contact = push_lib.BallContact.estimated()
    else:
        contact = push_lib.BallContact()
    return model_params, contact, ControllerParams.paper(model_params, variant=variant)


def run_cases(params: ControllerParams | None = None, model_params: ModelParams | None = None,
              impulse_scale: float = 1.0, config: RolloutConfig = RolloutConfig(),
              onset_s: float = push_lib.PAPER_ONSET_S,
              contact: push_lib.BallContact = push_lib.BallContact(), schedule=None):
    """Simulate the 8 cases (schedule: a scheduled policy's, with `params`; None: the plain
    controller). Returns (cases, series, outcomes, pushes as numpy dict)."""
    params = params or ControllerParams.paper(model_params)
    cases = paper_cases()
    pushes = push_lib.stack_pushes([
        push_lib.make_push(impulse_scale * contact.impulse_ns(b, d), push_lib.DIRECTIONS[d],
                           height_m=contact.contact_height_m(d), onset_s=onset_s)
        for d, b, _ in cases])
    enabled = np.array([1.0 if c == "on" else 0.0 for *_, c in cases], np.float32)
    series, outcomes = simulate(pushes, enabled, params, model_params=model_params, config=config,
                                schedule=schedule)
    return cases, series, outcomes, pushes


def _rows(cases, outcomes, pushes) -> list[dict]:
    rows = []
    for i, (d, b, c) in enumerate(cases):
        fell = bool(outcomes["fell"][i])
        rec = float(outcomes["recovery_time_s"][i])
        rec_pitch = float(outcomes["recovery_time_pitch_s"][i])
        step = float(outcomes["step_length_m"][i])
        rows.append(dict(
            direction=d, ball=b, force_N=push_lib.PAPER_FORCE_N[b], control=c,
            fell="true" if fell else "false",
            recovery_time_s="" if fell or math.isnan(rec) else f"{rec:.2f}",
            recovery_time_pitch_s="" if fell or math.isnan(rec_pitch) else f"{rec_pitch:.2f}",
            # A fall drags the feet too: that is not a recovery step (the paper writes X).
            step_length_cm="" if fell or abs(step) < NO_STEP_M else f"{100 * step:.2f}",
            impulse_Ns=f"{float(pushes.impulse_ns[i]):.3f}",
            peak_incl_deg=f"{float(outcomes['peak_incl_deg'][i]):.2f}",
            capture_point_cm=f"{100 * float(outcomes['capture_point_m'][i]):.2f}"))
    return rows


PHASE_COLUMNS = ["direction", "ball", "control", "phases", "fall_fraction", "fell_at_phases",
                 "step_min_cm", "step_max_cm", "x_sup_min_cm", "x_sup_max_cm", "peak_min_deg",
                 "peak_max_deg"]


def phase_rows(cases, by_phase: list[tuple[float, dict]]) -> list[dict]:
    """Per case, its outcomes across the phases: by_phase = [(phase, outcomes of the 8)]."""
    rows = []
    for i, (d, b, c) in enumerate(cases):
        fell = np.array([bool(o["fell"][i]) for _, o in by_phase])
        # Steps of the pushes that stayed up (a fall drags the feet: not a step, as table.md).
        steps = [100 * float(o["step_length_m"][i]) for _, o in by_phase
                 if not o["fell"][i] and abs(float(o["step_length_m"][i])) >= NO_STEP_M]
        xs = [100 * float(o["capture_point_m"][i]) for _, o in by_phase]
        peaks = [float(o["peak_incl_deg"][i]) for _, o in by_phase]
        rng = lambda v, f: ("", "") if not v else (f"{min(v):{f}}", f"{max(v):{f}}")  # noqa: E731
        rows.append(dict(zip(PHASE_COLUMNS, (
            d, b, c, len(by_phase), f"{fell.mean():.2f}",
            " ".join(f"{ph:.2f}" for (ph, _), f in zip(by_phase, fell) if f),
            *rng(steps, ".2f"), *rng(xs, ".2f"), *rng(peaks, ".2f")))))
    return rows


def _phase_markdown(rows: list[dict], n: int) -> str:
    peak = push_lib.peak_on_sample_phase()
    lines = [f"## The 8 cases across the 30 ms control period ({n} phases)", "",
             f"Onset 0.75 s + phase x 30 ms, phase = 0, {1 / n:g}, ..., {(n - 1) / n:g}; phase 0 "
             f"is the table above, {peak:.1f} puts the 20 ms pulse's peak on the controller's "
             "IMU sample. Steps: pushes that stayed up and stepped >= 5 mm.", "",
             "| direction | ball | control | falls (fraction) | falls at phases | step (cm) | "
             "x_Sup (cm) | peak dev. (deg) |", "|---|---|---|---|---|---|---|---|"]
    span = lambda lo, hi: "X" if not lo else (lo if lo == hi else f"{lo} to {hi}")  # noqa: E731
    for r in rows:
        lines.append(f"| {r['direction']} | {r['ball']} | {r['control']} | {r['fall_fraction']} "
                     f"| {r['fell_at_phases'] or '-'} | {span(r['step_min_cm'], r['step_max_cm'])}"
                     f" | {span(r['x_sup_min_cm'], r['x_sup_max_cm'])} | "
                     f"{span(r['peak_min_deg'], r['peak_max_deg'])} |")
    return "\n".join(lines) + "\n"


def _fmt_paper(rec, step):
    return ("falls" if rec is None else f"{rec:.2f} s"), ("X" if step is None else f"{step:.2f} cm")


def _markdown(rows: list[dict], title: str) -> str:
    lines = [f"## {title}", "",
             "| direction | ball | control | paper: recovery | sim: recovery | "
             "sim: recovery (pitch only) | paper: step | sim: step | sim: peak dev. | "
             "outcome as paper? |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p_rec, p_step = PAPER_TABLE[(r["direction"], r["ball"], r["control"])]
        pr, ps = _fmt_paper(p_rec, p_step)
        sim_fell = r["fell"] == "true"
        sr, srp = ("falls" if sim_fell else (f"{r[k]} s" if r[k] else "not settled")
                   for k in ("recovery_time_s", "recovery_time_pitch_s"))
        ss = f"{r['step_length_cm']} cm" if r["step_length_cm"] else "X"
        same = "yes" if sim_fell == (p_rec is None) else "**no**"
        lines.append(f"| {r['direction']} | {r['ball']} ({r['force_N']} N, {r['impulse_Ns']} N·s)"
                     f" | {r['control']} | {pr} | {sr} | {srp} | {ps} | {ss} | "
                     f"{r['peak_incl_deg']}° | {same} |")
    return "\n".join(lines) + "\n"


def _figures(out: Path, cases, series) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig_no = {("back", "off"): 13, ("back", "on"): 14, ("front", "off"): 15, ("front", "on"): 16}
    for (d, c), num in fig_no.items():
        fig, axes = plt.subplots(2, 2, figsize=(9, 5.5), sharex=True)
        for col, b in enumerate(BALL_NAMES):
            i = cases.index((d, b, c))
            t = series["t"][i]
            axes[0, col].plot(t, np.degrees(series["pitch"][i]), label="true pelvis pitch")
            axes[0, col].plot(t, np.degrees(series["pitch_est"][i]), "--", label="Kalman φ")
            axes[0, col].axhline(12, color="r", lw=0.7, ls=":")
            axes[0, col].axhline(-2, color="r", lw=0.7, ls=":")
            axes[0, col].axvline(0.75, color="k", lw=0.7, ls=":")
            axes[0, col].set_title(f"({'ab'[col]}) {b}")
            axes[0, col].set_ylabel("φ (deg)")
            # ZMP x relative to its standing value, as the paper's figures (starts at 0).
            zx = series["zmp"][i][:, 0]
            axes[1, col].plot(t, 100 * (zx - zx[(t > 0.45) & (t <= 0.75)].mean()), color="g")
            axes[1, col].axvline(0.75, color="k", lw=0.7, ls=":")
            axes[1, col].set_ylabel("ZMP x (cm)")
            axes[1, col].set_xlabel("time (s)")
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"Fig. {num} (simulated): hit from the {d}, balance control {c}")
        fig.tight_layout()
        path = out / f"fig{num}_{d}_control_{c}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def run_paper(out: Path, figures: bool = True, params: ControllerParams | None = None,
              model_params: ModelParams | None = None, impulse_scale: float = 1.0,
              phases: int = 15, variant: str = "calibrated", schedule=None) -> str:
    """Write table.csv, table.md, series.npz, Figs. 13-16 and (phases > 0) phase.csv and
    phase.md to `out`; return a summary (table.md, then phase.md).

    impulse_scale multiplies both balls' impulses (1 = the paper's rig); other values are
    labelled as such in table.md. variant: "calibrated" (default) or "estimated" (the model,
    ball contact and Kalman noises before calibration; see `variant_setup`). phases: onsets
    0.75 s + k / phases * 30 ms, k < phases (each a batch of the 8 cases with the table's
    compiled rollout); 0 skips them. schedule: a scheduled policy's Schedule, run with
    `params` (`tkujax paper --params recommended`); None: the plain controller.
    """
    if not (0.0 < impulse_scale <= 10.0):
        raise ValueError(f"impulse_scale must be in (0, 10], got {impulse_scale!r}")
    if isinstance(phases, bool) or not isinstance(phases, int) or not 0 <= phases <= 100:
        raise ValueError(f"phases must be an integer in [0, 100], got {phases!r}")
    model_params, contact, variant_params = variant_setup(variant, model_params)
    params = params or variant_params
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cases, series, outcomes, pushes = run_cases(params, model_params, impulse_scale,
                                                contact=contact, schedule=schedule)
    wall = time.perf_counter() - t0
    rows = _rows(cases, outcomes, pushes)
    with open(out / "table.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["direction", "ball", "force_N", "control", "fell",
                                                "recovery_time_s", "recovery_time_pitch_s",
                                                "step_length_cm"])
        writer.writeheader()
        writer.writerows({k: r[k] for k in writer.fieldnames} for r in rows)
    import jax

    title = f"The paper's Tables 4-5 beside the simulation ({variant} model)"
    if impulse_scale != 1.0:
        title += f" (ball impulses scaled x{impulse_scale:g}: NOT the paper's rig)"
    md = _markdown(rows, title)
    n_same = sum(1 for r in rows
                 if (r["fell"] == "true") == (PAPER_TABLE[(r["direction"], r["ball"],
                                                           r["control"])][0] is None))
    md += (f"\nFall/no-fall outcomes as in the paper: {n_same}/8. Device: {jax.devices()[0]}, "
           f"wall {wall:.1f} s (including the compile unless it was already cached). "
           "recovery_time_s is empty when the robot fell, or (\"not settled\" here) when it was "
           "still outside the band at the end of the horizon.\n\n"
           f"{RECOVERY_NOTE}\n")
    (out / "table.md").write_text(md)
    np.savez_compressed(out / "series.npz", **{k: v for k, v in series.items()})
    (out / "outcomes.json").write_text(json.dumps(rows, indent=1))
    if figures:
        _figures(out, cases, series)
    if phases == 0:
        return md
    # Phase 0 is the run above; the others change only the onset (a traced value: no compile).
    by_phase = [(0.0, outcomes)] + [
        (k / phases, run_cases(params, model_params, impulse_scale, onset_s=float(
            push_lib.onset_from_phase(push_lib.PAPER_ONSET_S, k / phases)), contact=contact,
            schedule=schedule)[2])
        for k in range(1, phases)]
    prow = phase_rows(cases, by_phase)
    with open(out / "phase.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=PHASE_COLUMNS)
        writer.writeheader()
        writer.writerows(prow)
    phase_md = _phase_markdown(prow, phases)
    (out / "phase.md").write_text(phase_md)
    return md + "\n" + phase_md


def case_trajectory(case: str, control_on: bool, impulse_scale: float = 1.0):
    """One paper case, e.g. case='volleyball-back' (impulse_scale as in run_paper), simulated
    2.1 s: (host model, qpos (n, nq) once per control period, the period in s), for a video
    (`tkujax.render.render_case`)."""
    if not (0.0 < impulse_scale <= 10.0):
        raise ValueError(f"impulse_scale must be in (0, 10], got {impulse_scale!r}")
    try:
        ball, direction = case.split("-")
        contact = push_lib.BallContact()
        push = push_lib.make_push(impulse_scale * contact.impulse_ns(ball, direction),
                                  push_lib.DIRECTIONS[direction],
                                  height_m=contact.contact_height_m(direction))
    except (ValueError, KeyError) as err:
        raise ValueError(f"case must be BALL-DIRECTION with BALL in {BALL_NAMES} and DIRECTION "
                         f"in {DIRECTION_NAMES}, got {case!r}") from err
    import jax

    from tkujax.sim import rollout_mjx as sim
    from tkujax.sim.setup import init

    config = RolloutConfig(duration_s=2.1, record_qpos=True)
    host, model, index, state = init()
    episode = sim.Episode(push, 1.0 if control_on else 0.0, jax.random.PRNGKey(0))
    series = sim.rollout(model, state, episode, ControllerParams.paper(), config=config,
                         index=index)
    return host, np.asarray(series["qpos"]), config.control_period_s
