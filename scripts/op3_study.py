"""ROBOTIS OP3 pushed, in one run on a GPU: does a recovery controller tuned for OP3 save it
without harm? Steps, each resumable (a finished step is skipped) and time-boxed:

1. picture: OP3 at its stand, rendered offscreen (optional: a failure is recorded, not fatal);
2. map: the stability map with the control off and on at OP3's scaled defaults
   (specs/robots/op3_map.toml), `tkujax map` of it: fall boundaries, and the capture regions
   against the LIP theory of OP3 (its mass, CoM height and feet);
3. tune: a recovery controller by CMA-ES from the scaled defaults (specs/robots/op3_tune.toml);
4. verdict: held-out pushes (specs/robots/op3_heldout.toml) with the control off and with the
   tuned controller, `tkujax compare` of the two: the tuned controller passes when it falls at
   most 0.75 x as often as the control off and harms no direction x impulse x phase cell with
   >= 100 pushes (harmed: > 2 points worse than the control off).

    TKUJAX_MENAGERIE=/path/to/mujoco_menagerie python scripts/op3_study.py --out runs/op3_study
    python scripts/op3_study.py --smoke --out /tmp/op3_smoke      # tiny, on a CPU

`--variant widen` does the same from specs/robots/op3_widen.json (the widening sideways step,
op3_tune_widen.toml) into OUT/widen and judges the tune's recommendation (params_after.json).

`--variant gate` tunes and judges the controller with the accelerometer gate on
(specs/robots/op3_tune_gate.toml: the paper's Kalman filter otherwise reads a push's own
acceleration as a lean the other way, and OP3 stepped away from its capture point), into
OUT/gate: steps tune and verdict, on the same held-out pushes (op3_heldout.toml; the tuned
parameter file carries the gate and the other flags), sized for one GPU call of ~9 minutes:

    python scripts/op3_study.py --variant gate --out runs/op3_study --deadline-s 540

summary.json holds each step's status, wall time and figures; --tar packs the folder.
"""

from __future__ import annotations

import argparse
import json
import sys
import tarfile
import time
import tomllib
import traceback
from pathlib import Path
from typing import NamedTuple

REPO = Path(__file__).resolve().parents[1]
SPECS = REPO / "specs" / "robots"
STEPS = ("picture", "map", "tune", "verdict")
MAX_FALL_RATIO = 0.75
T_START = time.time()                   # --deadline-s counts from here


class Variant(NamedTuple):
    """What a study variant runs: its specs, its sub-folder of --out, its default steps and
    time boxes, and how much of the tune's time box its generations get: `search_share` of
    it, or with `search_reserve_s` all of it but that reserve, which holds the compiles, the
    control-off pass, the held-out evaluation and the generation running at the budget's end
    (a fixed reserve, so a longer time box goes to generations). `judged`: the tune's file
    that the verdict judges (params_tuned.json: the tuned set; params_after.json: the tune's
    recommendation, the start unless the tuned set beat it on the tune's own evaluation)."""

    tune: str
    heldout: str
    folder: str
    steps: tuple[str, ...]
    budgets_s: str
    search_share: float = 0.45
    search_reserve_s: float | None = None
    judged: str = "params_tuned.json"


VARIANTS = {
    "paper": Variant("op3_tune.toml", "op3_heldout.toml", "", STEPS, "30,130,230,110"),
    # One GPU call: ~10 s start, the tune ~335 s (compile ~70 s, generations of 11 x 256
    # pushes ~25 s each, evaluation ~65 s), the verdict ~155 s (two chunks of 8,192 x 2 s).
    "gate": Variant("op3_tune_gate.toml", "op3_heldout.toml", "gate", ("tune", "verdict"),
                    "30,130,345,190", search_reserve_s=170.0),
    # The widening sideways step (op3_tune_widen.toml), the verdict on the tune's
    # recommendation; one GPU call of ~10 minutes: the tune ~400 s, the verdict ~160 s.
    "widen": Variant("op3_tune_widen.toml", "op3_heldout.toml", "widen", ("tune", "verdict"),
                     "30,130,400,175", search_reserve_s=170.0, judged="params_after.json"),
}


def _spec(name: str) -> dict:
    return tomllib.loads((SPECS / name).read_text())


def _robot_path(args) -> str:
    return str(Path(args.robot).resolve())


def map_spec(smoke: bool) -> dict:
    spec = _spec("op3_map.toml")
    if smoke:
        spec["sweep"].update(chunk_size=12, duration_s=1.0)
        spec["push"]["grid"].update(impulse_ns=[0.5, 2.5], azimuth_deg=[0, 90, 180],
                                    onset_phase=[0.0])
    return spec


def tune_spec(smoke: bool, iterations: int | None, name: str = "op3_tune.toml") -> dict:
    spec = _spec(name)
    if iterations:
        spec["tune"]["iterations"] = iterations
    if smoke:
        spec["tune"].update(popsize=3, iterations=1, batch=4, remat=False)
        spec["evaluate"].update(n=4, impulse_ns=[1.0], azimuth_deg=[0])
    return spec


def heldout_spec(smoke: bool, name: str = "op3_heldout.toml") -> dict:
    spec = _spec(name)
    if smoke:
        spec["sweep"].update(chunk_size=24, duration_s=1.0)
        spec["push"]["random"]["n"] = 24
    return spec


def _sweep(spec: dict, out: Path, robot, deadline: float, params=None) -> dict:
    """Run (or resume) a sweep chunk by chunk until it is complete or the deadline passes."""
    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.sweeps.sweep import run_sweep

    parsed = parse_spec(spec)
    while True:
        manifest = run_sweep(parsed, out, params=params, model_params=robot, max_chunks=1,
                             quiet=True)
        if manifest["complete"] or time.time() > deadline:
            return manifest


def step_picture(args, out: Path, deadline: float) -> dict:
    from tkujax import render
    from tkujax.robot.robot_setup import robot_setup

    ok, why = render.rendering_available()
    if not ok:
        return dict(status="skipped", why=f"offscreen rendering unavailable: {why}")
    robot = robot_setup(_robot_path(args))
    # Every geom group: the boxes the simulation collides with beside the visual meshes.
    frame = render.render_frames(robot.setup.host_model, robot.settled.qpos[None], 640, 480,
                                 all_geom_groups=True)[0]
    return dict(status="done", file=str(render.save_image(frame, out / "op3_stand.png")))


def step_map(args, out: Path, deadline: float) -> dict:
    from tkujax.robot.robot_setup import robot_setup
    from tkujax.studies.robot_inputs import robot_lip
    from tkujax.analysis.maps import make_maps
    from tkujax.sweeps.sweep import load

    robot = robot_setup(_robot_path(args))
    spec = map_spec(args.smoke)
    spec["robot"]["file"] = _robot_path(args)
    manifest = _sweep(spec, out / "map", robot, deadline)
    if not manifest["complete"]:
        return dict(status="incomplete", n_pushes=manifest["n_pushes"])
    maps = make_maps(out / "map", robot=robot, lip=robot_lip(robot))
    rec = load(out / "map")
    on = rec["control"].astype(bool)
    return dict(status="done", n_pushes=manifest["n_pushes"], backend=manifest["backend"],
                falls_off=int(rec["fell"][~on].sum()), falls_on=int(rec["fell"][on].sum()),
                files=maps["files"], summary=maps["summary"])


def search_budget_s(args, variant: Variant, left_s: float) -> float:
    """Seconds of CMA-ES generations (compile excluded) out of the `left_s` of the tune's time
    box: --tune-search-s, else the variant's share or all but its reserve. The compiles, the
    control-off pass and the held-out evaluation take the rest."""
    if args.tune_search_s is not None:
        return float(args.tune_search_s)
    if variant.search_reserve_s is not None and not args.smoke:
        return max(10.0, left_s - variant.search_reserve_s)
    return max(10.0, left_s * variant.search_share)


def step_tune(args, out: Path, deadline: float) -> dict:
    from tkujax.robot.robot_setup import robot_setup
    from tkujax.studies.tune import run_tune

    variant = VARIANTS[args.variant]
    spec = tune_spec(args.smoke, args.tune_iterations, variant.tune)
    spec["robot"]["file"] = _robot_path(args)
    budget = search_budget_s(args, variant, deadline - time.time())
    print(f"[tune] {variant.tune}: generations for {budget:.0f} s (compile excluded)",
          flush=True)
    record = run_tune(spec, out / "tune", quiet=False, compare=False, budget_s=budget,
                      robot=robot_setup(_robot_path(args)))
    return dict(status="done", spec=variant.tune, iterations=record["iterations"],
                search_s=round(budget, 1), wall_s=record["wall_s"],
                recommendation=record["recommendation"], params_user=record["params_user"],
                params=str(out / "tune" / "params_tuned.json"))


def step_verdict(args, out: Path, deadline: float) -> dict:
    from tkujax.control.params_files import load_controller_params_json
    from tkujax.robot.robot_setup import robot_setup
    from tkujax.analysis.compare import Bands, compare_runs

    tuned = (Path(args.params) if args.params
             else out / "tune" / VARIANTS[args.variant].judged)
    if not tuned.is_file():
        # Not "skipped": a later run resumes here once the tune has finished.
        return dict(status="waiting", why="no tuned controller (the tune step did not finish)")
    robot = robot_setup(_robot_path(args))
    heldout = args.heldout or VARIANTS[args.variant].heldout
    spec = heldout_spec(args.smoke, heldout)
    spec["robot"]["file"] = _robot_path(args)
    run = out / "heldout"
    manifest = _sweep(spec, run, robot, deadline, params=load_controller_params_json(tuned))
    if not manifest["complete"]:
        return dict(status="incomplete", n_pushes=manifest["n_pushes"])
    res = compare_runs([f"{run}:off", f"{run}:on"], out / "compare",
                       labels=["control off", "tuned"], bands=Bands(sectors=4),
                       min_pushes=args.min_pushes, harm_pp=2.0, robot=robot)
    v = res["verdict"]["runs"]["tuned"]
    ratio = v["ratio_to_reference"]
    passed = bool(ratio is not None and ratio <= MAX_FALL_RATIO and v["no_harm"])
    return dict(status="done", spec=heldout, params=str(tuned),
                fall_rate_off=v["reference_fall_rate"], fall_rate_tuned=v["fall_rate"],
                ratio=ratio, cells_checked=v["cells_checked"],
                harmed_cells=len(v["harmed_cells"]), passed=passed, summary=res["summary"])


def _finished(name: str, args, summary: dict) -> bool:
    return summary["steps"].get(name, {}).get("status") in ("done", "skipped") and not args.redo


def run_step(name: str, args, out: Path, budget_s: float, summary: dict,
             later_s: float = 0.0) -> None:
    """Run one step unless it is done; record its status and wall time in `summary`. With
    --deadline-s the time box ends early enough to leave the later steps theirs (later_s)
    before the deadline: a slow start shortens the tune's generations, not the verdict."""
    if _finished(name, args, summary):
        print(f"[{name}] already {summary['steps'][name]['status']}", flush=True)
        return
    t0 = time.time()
    if args.deadline_s is not None:
        budget_s = max(10.0, min(budget_s, T_START + args.deadline_s - t0 - later_s))
    print(f"[{name}] start (time box {budget_s:.0f} s)", flush=True)
    fn = {"picture": step_picture, "map": step_map, "tune": step_tune,
          "verdict": step_verdict}[name]
    try:
        result = fn(args, out, t0 + budget_s)
    except Exception as err:  # noqa: BLE001 -- recorded; the next steps still run
        traceback.print_exc()
        result = dict(status="failed", error=f"{type(err).__name__}: {err}")
    result["wall_s"] = round(time.time() - t0, 1)
    summary["steps"][name] = result
    print(f"[{name}] {result['status']} in {result['wall_s']} s", flush=True)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="output folder (resumable)")
    ap.add_argument("--robot", default=str(SPECS / "op3.toml"), help="the robot file")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes: the pipeline end to end")
    ap.add_argument("--variant", choices=list(VARIANTS), default="paper",
                    help="paper: op3_tune.toml into OUT; gate: the accelerometer gate "
                         "(op3_tune_gate.toml) into OUT/gate, steps tune and verdict; widen: "
                         "the widening sideways step (op3_tune_widen.toml) into OUT/widen")
    ap.add_argument("--steps", nargs="+", choices=STEPS, default=None,
                    help="default: the variant's")
    ap.add_argument("--budgets-s", default=None,
                    help="time box of each step in STEPS order, s (sweeps stop between chunks, "
                         "resumable; the tune's size is set by --tune-iterations; default: "
                         "the variant's)")
    ap.add_argument("--deadline-s", type=float, default=None,
                    help="no time box ends later than this many seconds after the start")
    ap.add_argument("--tune-iterations", type=int, default=None,
                    help="CMA-ES generations (default: the spec's)")
    ap.add_argument("--tune-search-s", type=float, default=None,
                    help="seconds of CMA-ES generations, compile excluded (default: from the "
                         "tune's time box, as the variant says)")
    ap.add_argument("--min-pushes", type=int, default=100, help="verdict: cells checked")
    ap.add_argument("--params", default=None,
                    help="verdict: judge this controller parameter file instead of the tune's "
                         "(e.g. specs/robots/op3_front.json)")
    ap.add_argument("--heldout", default=None,
                    help="verdict: this held-out spec of specs/robots (default: the variant's, "
                         "op3_heldout.toml; op3_heldout_b.toml: a second set, another seed)")
    ap.add_argument("--redo", action="store_true", help="run finished steps again")
    ap.add_argument("--tar", default=None, help="pack the output folder into this .tar.gz")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    from tkujax.cli.runtime import configure_runtime

    configure_runtime()                  # headless GL (EGL) and the persistent compile cache
    args = parse_args(argv)
    variant = VARIANTS[args.variant]
    if args.smoke:
        args.min_pushes = 1
    root = Path(args.out)
    out = root / variant.folder
    out.mkdir(parents=True, exist_ok=True)
    path = out / "summary.json"
    summary = json.loads(path.read_text()) if path.is_file() else dict(steps={})
    budgets = dict(zip(STEPS, (float(b) for b in (args.budgets_s or variant.budgets_s)
                                                     .split(","))))
    import jax

    summary.update(robot=_robot_path(args), smoke=args.smoke, variant=args.variant,
                   tune_spec=variant.tune, heldout_spec=variant.heldout,
                   devices=[str(d) for d in jax.devices()])
    t0 = time.time()
    steps = [n for n in STEPS if n in (args.steps or variant.steps)]
    for i, name in enumerate(steps):
        later = sum(budgets[n] for n in steps[i + 1:] if not _finished(n, args, summary))
        run_step(name, args, out, budgets[name], summary, later)
        path.write_text(json.dumps(summary, indent=1, default=str))
    summary["wall_s_last_run"] = round(time.time() - t0, 1)
    path.write_text(json.dumps(summary, indent=1, default=str))
    if args.tar:
        with tarfile.open(args.tar, "w:gz") as tar:
            tar.add(root, arcname=root.name)
    print(json.dumps({k: v.get("status") for k, v in summary["steps"].items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
