"""The IMU's bandwidth, the hit phase and the paper's rows, on MuJoCo C (CPU):
results/calibration/imu_bandwidth.

Unfiltered, the controller's 30 ms IMU sample catches the 20 ms ball pulse at some hit phases
and not at others: the accelerometer reads the push's linear acceleration as a tilt (a push
from the front as a forward lean), and the paper's rows flip with the phase. A MEMS IMU
low-pass (ModelParams.accel_lowpass_hz) spreads every pulse alike.

  python scripts/imu_bandwidth.py rows --out DIR [--cutoffs 0,5,10,20,40] [--model M.json]
        the paper's 8 rows at 15 hit phases x 3 contact times (10, 20, 30 ms) per cutoff
  python scripts/imu_bandwidth.py search --out FILE.jsonl [--budget-s 1800] [--seed 2]
        CMA-ES over (cutoff, the front hit's height offset and impulse ratio), the rest of the
        default robot held; appends one JSON line per candidate (rerun to continue)
  python scripts/imu_bandwidth.py slices --out FILE.json --center HZ,DZ,RATIO
        one-parameter slices through a point of that search: where the paper's rows hold
  python scripts/imu_bandwidth.py converge --out FILE.json [--n 1000] [--cutoffs 0,20]
        fall outcomes at 2 ms against 0.5 ms (Newton 4, ls 8), control off and on

Row summaries: p = the fraction of trials with the paper's fall outcome; steps = standing
trials with a step >= 5 mm; wrong = those against the paper's way (backward after a push
from behind, forward after one from the front); mean = their mean step (cm).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

PHASES_MS = tuple(2.0 * k for k in range(15))      # the 15 phases of `tkujax paper`
CONTACTS_MS = (10.0, 20.0, 30.0)
ROWS = [(d, b, c) for c in ("off", "on") for d in ("back", "front")
        for b in ("baseball", "volleyball")]


def _setup(model_params, contact):
    from tkujax.control.controller_params import ControllerParams
    from tkujax.sim.push import stack_pushes
    from tkujax.studies.calibrate import paper_rows as E

    samples = [E.Sample(p, c) for c in CONTACTS_MS for p in PHASES_MS]
    pushes = stack_pushes([
        contact.push(b, d, onset_s=E.hit_onset_s(s.phase_ms), duration_s=1e-3 * s.contact_ms)
        for s in samples for d, b in E.CASES])
    return samples, pushes, ControllerParams.paper(model_params), E.CASES


def rows_summary(model_params, contact) -> dict:
    """{"all": {row: summary}, "20ms": {row: summary}} over 15 phases x 3 contact times (all)
    and over the 15 phases at the default 20 ms contact (the phase table of `tkujax paper`)."""
    from tkujax.sim.rollout_mujoco import simulate_mujoco
    from tkujax.studies.paper import PAPER_TABLE

    samples, pushes, params, cases = _setup(model_params, contact)
    n = len(cases) * len(samples)
    raw = {}
    for ctl in ("off", "on"):
        _, o = simulate_mujoco(pushes, np.full(n, 1.0 if ctl == "on" else 0.0, np.float32),
                               params, model_params=model_params)
        for i in range(n):
            d, b = cases[i % len(cases)]
            contact_ms = samples[i // len(cases)].contact_ms
            raw.setdefault((d, b, ctl), []).append(
                (contact_ms, bool(o["fell"][i]), 100.0 * float(o["step_length_m"][i])))
    out = {}
    for subset, keep in (("all", lambda c: True), ("20ms", lambda c: c == 20.0)):
        out[subset] = {}
        for key, trials in raw.items():
            trials = [t for t in trials if keep(t[0])]
            paper_falls = PAPER_TABLE[key][0] is None
            steps = [s for _, f, s in trials if not f and abs(s) >= 0.5]
            wrong = sum(1 for s in steps if (s < 0 if key[0] == "back" else s > 0))
            out[subset]["/".join(key)] = dict(
                p=float(np.mean([f == paper_falls for _, f, _ in trials])), n=len(trials),
                steps=len(steps), wrong=wrong, mean=float(np.mean(steps)) if steps else 0.0)
    return out


def robot(hz: float, dz_m: float, ratio: float):
    """(ModelParams, BallContact) of the default robot with the accelerometer cutoff `hz` and
    the front hit `dz_m` higher and `ratio` times as strong as the one from behind."""
    from tkujax.model import ModelParams
    from tkujax.sim.push import BallContact

    return (ModelParams(accel_lowpass_hz=hz),
            dataclasses.replace(BallContact(), front_height_offset_m=dz_m,
                                front_impulse_ratio=ratio))


def criterion(summary: dict) -> dict:
    """The acceptance of one summary: every row at >= 80 %, no wrong-way step, and
    (so that it does not hold by stepping nowhere) both volleyball rows with control step the
    paper's way in >= 80 % of their trials, as the paper's robot did."""
    worst = min(v["p"] for v in summary.values())
    wrong = sum(v["wrong"] for v in summary.values())
    stepped = min((summary[k]["steps"] - summary[k]["wrong"]) / summary[k]["n"]
                  for k in ("back/volleyball/on", "front/volleyball/on"))
    return dict(min_p=worst, wrong=wrong, volleyball_steps=stepped,
                met=bool(worst >= 0.8 and wrong == 0 and stepped >= 0.8))


def search_loss(summary: dict) -> float:
    """Shortfall below 80 % per row, wrong-way steps, and the volleyball rows' missing steps
    the paper's way (the paper steps after both volleyballs)."""
    loss = 0.0
    for v in summary.values():
        loss += 10.0 * max(0.0, 0.8 - v["p"]) + (5.0 * v["wrong"] / v["steps"] if v["steps"]
                                                  else 0.0)
    for k in ("back/volleyball/on", "front/volleyball/on"):
        v = summary[k]
        loss += 2.0 * (1.0 - (v["steps"] - v["wrong"]) / v["n"])
    return loss


def _markdown(results: list[dict]) -> str:
    lines = ["| cutoff (Hz) | set | " + " | ".join("/".join(r) for r in ROWS) + " | min p | "
             "wrong-way steps |", "|---" * (len(ROWS) + 4) + "|"]
    for r in results:
        for subset in ("20ms", "all"):
            s = r["rows"][subset]
            cells = []
            for row in ROWS:
                v = s["/".join(row)]
                cell = f"{v['p']:.2f}"
                if v["steps"]:
                    cell += f", {v['steps']} st ({v['wrong']} wrong, {v['mean']:+.1f} cm)"
                cells.append(cell)
            c = criterion(s)
            name = "15 phases, 20 ms" if subset == "20ms" else "15 phases x 3 contacts"
            lines.append(f"| {r['accel_lowpass_hz']:g} | {name} | " + " | ".join(cells)
                         + f" | {c['min_p']:.2f} | {c['wrong']} |")
    return "\n".join(lines) + "\n"


def cmd_rows(a) -> None:
    from tkujax.model import ModelParams
    from tkujax.model.params_json import load_model_params_json
    from tkujax.sim.push import BallContact

    base = load_model_params_json(a.model) if a.model else ModelParams()
    contact = BallContact(**json.loads(a.contact)) if a.contact else BallContact()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for hz in a.cutoffs:
        mp = dataclasses.replace(base, accel_lowpass_hz=hz).validate()
        t0 = time.perf_counter()
        results.append(dict(accel_lowpass_hz=hz, rows=rows_summary(mp, contact),
                            wall_s=round(time.perf_counter() - t0, 1)))
        print(f"{hz:g} Hz: {criterion(results[-1]['rows']['20ms'])} "
              f"({results[-1]['wall_s']} s)", flush=True)
    (out / "rows.json").write_text(json.dumps(dict(
        contact=dataclasses.asdict(contact), model=a.model or "ModelParams()",
        phases_ms=PHASES_MS, contacts_ms=CONTACTS_MS, results=results), indent=1) + "\n")
    (out / "rows.md").write_text(_markdown(results))


SEARCH_LO = np.array([math.log10(5.0), -0.03, 0.85])    # log10 cutoff, dz (m), impulse ratio
SEARCH_HI = np.array([math.log10(40.0), 0.03, 1.25])


def cmd_search(a) -> None:
    from cmaes import CMA

    start = np.array([math.log10(a.start_hz), a.start_dz, a.start_ratio])
    opt = CMA(mean=(start - SEARCH_LO) / (SEARCH_HI - SEARCH_LO), sigma=0.2,
              bounds=np.array([[0.0, 1.0]] * 3), population_size=8, seed=a.seed)
    t0 = time.perf_counter()
    with open(a.out, "a") as fh:
        while time.perf_counter() - t0 < a.budget_s:
            told = []
            for _ in range(opt.population_size):
                u = opt.ask()
                v = SEARCH_LO + np.clip(u, 0.0, 1.0) * (SEARCH_HI - SEARCH_LO)
                mp, contact = robot(float(10 ** v[0]), float(v[1]), float(v[2]))
                rows = rows_summary(mp, contact)
                loss = search_loss(rows["all"]) + 2.0 * search_loss(rows["20ms"])
                told.append((u, loss))
                fh.write(json.dumps(dict(accel_lowpass_hz=mp.accel_lowpass_hz,
                                         contact=dataclasses.asdict(contact), loss=loss,
                                         gen=opt.generation, rows=rows)) + "\n")
                fh.flush()
                print(f"gen {opt.generation}: {mp.accel_lowpass_hz:.1f} Hz, front "
                      f"{v[1]:+.3f} m x{v[2]:.3f}: loss {loss:.2f}", flush=True)
            opt.tell(told)


SLICES = dict(accel_lowpass_hz=[5.0, 5.5, 6.0, 6.5, 7.0, 7.5, 8.0, 8.5, 9.0, 9.5, 10.0, 11.0, 12.0],
              front_height_offset_m=[-0.01, -0.005, 0.0, 0.005, 0.01, 0.015, 0.02, 0.025, 0.03],
              front_impulse_ratio=[0.95, 0.975, 1.0, 1.025, 1.05, 1.075, 1.1, 1.125, 1.15,
                                   1.175, 1.2])


def cmd_slices(a) -> None:
    hz0, dz0, ratio0 = a.center
    out = dict(center=dict(accel_lowpass_hz=hz0, front_height_offset_m=dz0,
                           front_impulse_ratio=ratio0), slices={})
    for name, values in SLICES.items():
        pts = []
        for v in values:
            point = {**out["center"], name: v}
            mp, contact = robot(point["accel_lowpass_hz"], point["front_height_offset_m"],
                                point["front_impulse_ratio"])
            rows = rows_summary(mp, contact)
            pts.append(dict(value=v, rows=rows, criterion_20ms=criterion(rows["20ms"]),
                            criterion_all=criterion(rows["all"])))
            print(name, v, pts[-1]["criterion_20ms"], pts[-1]["criterion_all"], flush=True)
        out["slices"][name] = pts
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")


def cmd_converge(a) -> None:
    from tkujax.control.controller_params import ControllerParams
    from tkujax.model import ModelParams
    from tkujax.sim import push as push_lib
    from tkujax.sim.rollout_mujoco import simulate_mujoco

    rng = np.random.default_rng(a.seed)
    az, imp, ph = rng.uniform(0, 360, a.n), rng.uniform(0.2, 1.8, a.n), rng.uniform(0, 1, a.n)
    pushes = push_lib.stack_pushes([
        push_lib.make_push(float(i), float(z), onset_s=float(
            push_lib.onset_from_phase(push_lib.PAPER_ONSET_S, float(f))))
        for i, z, f in zip(imp, az, ph)])
    params = ControllerParams.paper()
    report = dict(n=a.n, seed=a.seed, impulse_ns=[0.2, 1.8], reference="0.5 ms, Newton 4, ls 8",
                  controller="ControllerParams.paper()", cutoffs={})
    for hz in a.cutoffs:
        fell = {}
        for name, step in (("2ms", {}), ("0.5ms", dict(timestep_s=0.0005, solver_iterations=4,
                                                        ls_iterations=8))):
            mp = ModelParams(accel_lowpass_hz=hz, **step)
            for en in (0.0, 1.0):
                _, o = simulate_mujoco(pushes, np.full(a.n, en, np.float32), params,
                                       model_params=mp)
                fell[(name, en)] = o["fell"].astype(bool)
        report["cutoffs"][f"{hz:g}"] = {
            ctl: dict(agreement=float(np.mean(fell[("2ms", en)] == fell[("0.5ms", en)])),
                      fall_2ms=float(fell[("2ms", en)].mean()),
                      fall_ref=float(fell[("0.5ms", en)].mean()))
            for ctl, en in (("off", 0.0), ("on", 1.0))}
        print(hz, report["cutoffs"][f"{hz:g}"], flush=True)
    Path(a.out).write_text(json.dumps(report, indent=1) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    cutoffs = lambda s: [float(v) for v in s.split(",")]   # noqa: E731
    r = sub.add_parser("rows")
    r.add_argument("--out", required=True)
    r.add_argument("--cutoffs", type=cutoffs, default=[0.0, 5.0, 10.0, 20.0, 40.0])
    r.add_argument("--model", default=None, help="a model_params.json (default ModelParams())")
    r.add_argument("--contact", default=None, help='BallContact fields as JSON, e.g. '
                   '\'{"front_height_offset_m": 0.02}\' (default BallContact())')
    r.set_defaults(func=cmd_rows)
    s = sub.add_parser("search")
    s.add_argument("--out", required=True)
    s.add_argument("--budget-s", type=float, default=1800.0)
    s.add_argument("--seed", type=int, default=2)
    s.add_argument("--start-hz", type=float, default=10.6)
    s.add_argument("--start-dz", type=float, default=0.025)
    s.add_argument("--start-ratio", type=float, default=1.13)
    s.set_defaults(func=cmd_search)
    sl = sub.add_parser("slices")
    sl.add_argument("--out", required=True)
    sl.add_argument("--center", type=cutoffs, required=True, help="HZ,DZ_M,RATIO")
    sl.set_defaults(func=cmd_slices)
    c = sub.add_parser("converge")
    c.add_argument("--out", required=True)
    c.add_argument("--n", type=int, default=1000)
    c.add_argument("--seed", type=int, default=1)
    c.add_argument("--cutoffs", type=cutoffs, default=[0.0, 20.0])
    c.set_defaults(func=cmd_converge)
    a = ap.parse_args(argv)
    a.func(a)


if __name__ == "__main__":
    main()
