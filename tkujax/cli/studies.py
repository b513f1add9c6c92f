"""Commands of the fitting and checking studies: tune, calibrate, refine, converge, islands."""

from __future__ import annotations

from pathlib import Path

from tkujax.cli.errors import bounded_float, bounded_int
from tkujax.cli.shared_options import model_params_from_options


def _cmd_calibrate(args) -> int:
    from tkujax.studies.calibrate import run_calibrate
    from tkujax.studies.calibrate.calibrate_spec import load_calibrate_spec

    spec = load_calibrate_spec(args.spec)
    over = {k: v for k, v in (("budget_s", args.budget_s), ("max_evals", args.max_evals),
                              ("workers", args.workers)) if v is not None}
    if over:
        from tkujax.studies.calibrate.calibrate_spec import parse_calibrate_spec
        from tkujax.dialects.sweep_spec import read_toml

        raw = read_toml(args.spec)
        raw.setdefault("search", {}).update(over)      # re-validated like the spec's own keys
        spec = parse_calibrate_spec(raw)
    summary = run_calibrate(spec, args.out)
    print("\n".join(summary["files"]))
    print(Path(args.out, "calibration.md").read_text())
    return 0


def _cmd_refine(args) -> int:
    from tkujax.studies.calibrate.refine import Refiner, refine

    model = model_params_from_options(args.model or [])
    res = refine(args.out, iterations=args.iterations, lr=args.lr,
                 refiner=Refiner(model=model) if model is not None else None,
                 log=lambda m: print(m, flush=True))
    b = res["best"]
    print(f"best: iteration {b['iteration']}, loss {b['loss']:.4f} (start "
          f"{res['history'][0]['loss']:.4f}), {b['params']}; {Path(args.out, 'refine.json')}")
    return 0


def _stage_words(stage: str) -> str:
    """What a `tkujax tune --robot` stage's controller is, in words."""
    from tkujax.studies.robot_tune import FALLBACK_SCALES, fallback_stage

    words = dict(tune="the CMA-ES controller", policy="the line search's policy",
                 retry="the retry's controller", own="the robot's own controller")
    words |= {fallback_stage(s)[0]: fallback_stage(s)[1] for s in FALLBACK_SCALES}
    return words.get(stage, stage)


def _cmd_tune_robot(args) -> int:
    from tkujax.studies.robot_inputs import is_builtin
    from tkujax.studies.robot_tune import (FALLBACK_SCALES, fallback_stage,
                                           tune_robot_controller)

    record = tune_robot_controller(args.robot, args.out, budget_s=args.budget_s or 480.0,
                                   heldout_n=args.heldout_n, write=not args.no_write,
                                   retry=not args.no_retry, structure=args.structure,
                                   policy_method={"auto": None, "on": True,
                                                  "off": False}[args.policy_method])
    stages, chosen = record["stages"], _stage_words(record["chosen_stage"])
    ratio = "-" if record["ratio"] is None else f"{record['ratio']:.3f}"
    print(f"{record['robot']}: {100 * record['on_fall']:.1f} % of {record['n_pushes']} held-out "
          f"pushes fall with {chosen}, {100 * record['off_fall']:.1f} % with control off "
          f"(ratio {ratio}); {len(record['harmed_cells'])} harmed cell(s); {record['why']}")
    if "policy" in stages:
        policy = stages["policy"]
        print(f"the CMA-ES controller: {stages['tune']['why']}; the line search's policy "
              f"({policy['budget_s']:.0f} s): {policy['why']}")
    if "retry" in stages:
        print(f"the first controller: {stages['tune']['why']}; the retry's: "
              f"{stages['retry']['why']}")
    for scale in FALLBACK_SCALES:
        stage, what = fallback_stage(scale)
        if stage in stages:
            print(f"{what}: {stages[stage]['why']}")
    if "own" in stages:
        print(f"the robot's own controller ({stages['own']['where']}): {stages['own']['why']}; "
              + ("kept: this run's is no better" if record["chosen_stage"] == "own"
                 else "replaced: this run's is better"))
    print(f"reported: {chosen}")
    if record.get("controller_file"):
        named = "" if is_builtin(args.robot) else f" and named in {args.robot}"
        print(f"controller written to {record['controller_file']}{named}")
    print(f"verdict: {Path(args.out, 'verdict.json')}")
    return 0 if record["passed"] else 1


def _cmd_tune(args) -> int:
    if args.spec is None:
        if args.robot is None:
            raise ValueError("tune: give a tune SPEC, or --robot FILE to tune that robot's "
                             "controller without one")
        return _cmd_tune_robot(args)
    from tkujax.studies.robot_inputs import tune_robot
    from tkujax.studies.tune import run_tune
    from tkujax.dialects.validation import read_toml

    record = run_tune(args.spec, args.out, iterations=args.iterations,
                      compare=not args.no_compare, evaluation=not args.no_eval,
                      only=args.only, deadline_s=args.deadline_s, budget_s=args.budget_s,
                      robot=tune_robot(read_toml(args.spec), args.robot))
    if "summary" in record and "left" in record:          # a [study] spec
        print(Path(args.out, "study.md").read_text())
        print(f"study: {len(record['left'])} run(s) left"
              + (f"; stopped before {record['stopped']}" if record["stopped"] else ""))
        return 0
    print(Path(args.out, "summary.md").read_text())
    print(f"recommendation: {record['recommendation']['reason']} "
          f"({Path(args.out, 'params_after.json')})")
    return 0


# What a rerun of an interrupted `tkujax tune` does. A plain tune keeps nothing of its search
# in --out (its outputs are written at its end); a [study] keeps its finished runs and
# `--robot` its finished stages, the search in progress starting over in both.
TUNE_RESTARTS = ("a rerun of the same command starts the tune over (a tune keeps no search "
                 "state in --out)")
STUDY_RESUMES = "rerun the same command to resume (finished runs are kept)"
ROBOT_RESUMES = ("rerun the same command to resume (finished stages are kept; a search cut "
                 "short starts over)")


def tune_rerun(args) -> str:
    """What a rerun of `tkujax tune` with `args` does after a Ctrl-C."""
    if args.spec is None:
        return ROBOT_RESUMES
    from tkujax.dialects.validation import read_toml

    try:
        study = "study" in read_toml(args.spec)
    except (OSError, ValueError):          # unreadable now: no study ran from it
        study = False
    return STUDY_RESUMES if study else TUNE_RESTARTS


def _cmd_converge(args) -> int:
    from tkujax.studies.converge import load_spec, run_converge

    spec = load_spec(args.spec)
    only = tuple(x.strip() for x in (args.only or "").split(",") if x.strip())
    run_converge(spec, args.out, only=only, log=lambda m: print(m, flush=True),
                 run=not args.no_run, reference=args.reference)
    return 0


def _cmd_islands(args) -> int:
    from tkujax.studies.calibrate.islands import run_islands

    run_islands(args.out, params=None if args.params is None else args.params.split(","),
                points=args.points, refine=args.refine, slice_phases=args.slice_phases,
                phases=args.phases, window=args.window)
    return 0


def add_study_commands(sub) -> None:
    """tune, calibrate, refine, converge, islands."""
    _add_tune(sub)
    _add_calibrate(sub)
    _add_refine(sub)
    _add_converge(sub)
    _add_islands(sub)


def _add_tune(sub) -> None:
    p = sub.add_parser("tune", help="tune T, gamma, H_Sup, eps_1, eps_2 (...) by CMA-ES, "
                                    "gradients through MJX or their alpha-order mix; evaluate "
                                    "on held-out and shifted pushes")
    p.add_argument("spec", nargs="?", default=None,
                   help="tune spec, e.g. specs/tune/tune_cpu.toml; without one, --robot FILE "
                        "tunes that robot's recovery controller from the robot alone (its "
                        "pushes, the recovery structure, CMA-ES, the no-harm verdict on "
                        "held-out pushes) and names it in the robot file when it passes and "
                        "beats the controller the file names; --robot tkux: the built-in TKU-X, "
                        "against its recommended policy")
    p.add_argument("--out", required=True, help="output folder (history.json, params_*.json, "
                                                 "loss_curve.png, summary.md)")
    p.add_argument("--iterations", type=int, default=None, help="override tune.iterations")
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="a robot file (docs/robots.md): tune on that robot from its scaled "
                        "controller defaults (default: the spec's [robot] file); without a "
                        "spec, tkux names the built-in TKU-X")
    p.add_argument("--no-compare", action="store_true",
                   help="skip the spec's [compare] study (methods x seeds at one budget)")
    p.add_argument("--no-eval", action="store_true", help="skip the held-out evaluation")
    p.add_argument("--only", action="append", default=None, metavar="KEY=V1[,V2]",
                   help="[study] specs: run only these runs (KEY: policy, method or seed; "
                        "repeat for AND), e.g. --only policy=mlp --only seed=0,1")
    p.add_argument("--deadline-s", type=bounded_float(0.0, 30 * 86400.0), default=None,
                   help="[study] specs: start no run that would end after this many seconds "
                        "(finished runs are kept; rerun to resume)")
    p.add_argument("--budget-s", type=bounded_float(1.0, 86_400.0), default=None,
                   help="override the search's wall-clock budget per run (s; [study] specs: "
                        "study.budget_s); without a spec: the whole command's budget "
                        "(default 480 s), 60 %% of it for the search; a retry, when the first "
                        "controller fails, takes as long again")
    p.add_argument("--heldout-n", type=bounded_int(64, 1 << 20), default=8192,
                   help="without a spec: held-out pushes of the verdict (default 8192)")
    p.add_argument("--no-write", action="store_true",
                   help="without a spec: judge, but leave the robot file as it is")
    p.add_argument("--no-retry", action="store_true",
                   help="without a spec: no second search with the harm weight when the first "
                        "controller fails its verdict")
    p.add_argument("--policy-method", choices=("auto", "on", "off"), default="auto",
                   help="without a spec: also train a scheduled policy from the CMA-ES result "
                        "with the gradient line search for the same wall time, and keep the "
                        "better verdict (auto: on a GPU when the policy has at least 160 "
                        "parameters, where the line search beat CMA-ES)")
    p.add_argument("--structure", choices=("step", "shift_step", "stance"), default=None,
                   help="without a spec: tune this recovery structure instead of the one the "
                        "probe chooses (docs/robots.md)")
    p.set_defaults(func=_cmd_tune, rerun=tune_rerun)


def _add_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="fit the model's unknown parameters to the paper's "
                                         "Tables 4-5 (CMA-ES with restarts; resumable)")
    p.add_argument("spec", help="calibrate spec, e.g. specs/calibrate/calibrate_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (archive.jsonl, best.json, "
                                                 "calibration.md, search_trace.png, "
                                                 "model_params.json, controller_params.json)")
    p.add_argument("--budget-s", type=float, default=None, help="override search.budget_s")
    p.add_argument("--max-evals", type=int, default=None, help="override search.max_evals")
    p.add_argument("--workers", type=int, default=None, help="override search.workers")
    p.set_defaults(func=_cmd_calibrate)


def _add_refine(sub) -> None:
    p = sub.add_parser("refine", help="gradient refinement of the calibration through MJX: "
                                      "leg stiffness and damping, ball impulse, chest CoM")
    p.add_argument("--out", required=True, help="output folder (refine.json)")
    p.add_argument("--iterations", type=int, default=10, help="Adam iterations (1-500)")
    p.add_argument("--lr", type=float, default=0.01, help="Adam step per parameter (scales, cm)")
    p.add_argument("--model", action="append", metavar="FILE.json|KEY=VALUE",
                   help="start from this model (default: the calibrated ModelParams())")
    p.set_defaults(func=_cmd_refine)


def _add_converge(sub) -> None:
    p = sub.add_parser("converge", help="fall outcomes at several timesteps / solver "
                                        "iterations against the finest (resumable)")
    p.add_argument("spec", help="converge spec, e.g. specs/converge/convergence_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (spec.json, outcomes_*.npz, "
                                                 "agreement.json, agreement.md)")
    p.add_argument("--only", default=None, help="comma-separated setting names to run now")
    p.add_argument("--no-run", action="store_true",
                   help="run nothing: write the agreement from the settings in --out")
    p.add_argument("--reference", default=None, help="compare against this setting instead of "
                                                     "the spec's (writes agreement_vs_NAME.*)")
    p.set_defaults(func=_cmd_converge)


def _add_islands(sub) -> None:
    p = sub.add_parser("islands", help="island widths of the fitted parameters (1-D slices "
                                       "through the default robot) and its paper rows over "
                                       "the hit phase (MuJoCo C)")
    p.add_argument("--out", required=True, help="output folder (islands.*, "
                                                 "phase_expectation.*)")
    p.add_argument("--points", type=bounded_int(3, 1000), default=41,
                   help="grid values per slice (3-1000)")
    p.add_argument("--refine", type=bounded_int(0, 20), default=4,
                   help="bisections per island edge (0-20)")
    p.add_argument("--params", default=None, help="comma-separated parameters (default all)")
    p.add_argument("--slice-phases", type=bounded_int(1, 100), default=1,
                   help="hit phases per slice value (1: the fit's 0 ms)")
    p.add_argument("--phases", type=bounded_int(0, 100), default=15,
                   help="phases of the default robot's expectation table (0 skips it)")
    p.add_argument("--window", type=float, default=1.0,
                   help="fraction of each parameter's bounds a slice spans, centred on the "
                        "default (default 1: the whole bounds)")
    p.set_defaults(func=_cmd_islands)
