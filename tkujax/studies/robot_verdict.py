"""The no-harm verdict of a robot's controller on held-out pushes, and naming the controller
in the robot file when it passes (`tkujax tune --robot`, tkujax.studies.robot_tune).

`heldout_verdict` sweeps the held-out spec control off and on with the controller, compares
them (`tkujax.analysis.compare`: 4 directions x impulse bands x phase bands) and returns the
record of `results/robots/<name>/verdict.json`: robot, n_pushes, off_fall, on_fall, ratio,
harmed_cells, method, n_params, wall_s, device, passed and why.
`name_controller` writes the controller next to the robot file and names it there.

The held-out spec is kept as `heldout_spec.json` (`spec_record`): its [robot] file relative to
that file's folder, so the record runs wherever the folder goes along with the robot file
(`read_spec_record` takes the path from the record's folder); absolute only where no relative
path exists (another drive).
"""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

from tkujax.control.params_files import (controller_params_from_dict, is_policy,
                                         save_policy_json, without_notes)
from tkujax.control.controller_params import ControllerParams
from tkujax.analysis.compare import Bands, compare_runs
from tkujax.dialects.sweep_spec import parse_spec
from tkujax.sweeps.sweep import run_sweep
from tkujax.sweeps.sweep_folder import computed_on, computed_with, device_kind

MIN_CELL_PUSHES, HARM_PP = 100, 2.0
_CONTROLLER_LINE = re.compile(r"^\s*controller\s*=.*$", re.MULTILINE)


def controller_params(params: dict) -> ControllerParams:
    """A parameter file's dict (its notes, such as recommended_from, left out) as
    ControllerParams; a policy file's dict: its scalars."""
    if is_policy(params):
        params = params["controller"]
    return controller_params_from_dict(without_notes(params), "the tuned controller")


def controller_schedule(params: dict):
    """The Schedule of a policy file's dict (`save_policy_json`); None for a parameter file's."""
    if not is_policy(params):
        return None
    from tkujax.control.policy import schedule_from_dict

    return schedule_from_dict(params["schedule"], "the tuned policy: schedule")


def verdict_reason(v: dict) -> str:
    """One line: why a `tkujax compare` run entry (`v`) passes the no-harm verdict or not; a
    harmed verdict names the cell that lost the most."""
    if v["cells_checked"] == 0:
        return (f"too few held-out pushes: no direction x impulse x phase cell has "
                f"{MIN_CELL_PUSHES}; raise --heldout-n")
    if v["ratio_to_reference"] is None:
        return "control off never fell on the held-out pushes: nothing to judge"
    if v["fall_rate"] >= v["reference_fall_rate"]:
        return (f"falls {100 * v['fall_rate']:.1f} % against {100 * v['reference_fall_rate']:.1f}"
                " % with control off")
    if v["harmed_cells"]:
        worst = max(v["harmed_cells"], key=lambda c: c.get("diff_pp", 0.0))
        lo, hi = worst.get("impulse_ns", (float("nan"), float("nan")))
        return (f"{len(v['harmed_cells'])} harmed cell(s), the worst {worst.get('sector')} at "
                f"{lo:.2f}-{hi:.2f} N s, phase {worst.get('phase')}: "
                f"+{worst.get('diff_pp', 0):.1f} points")
    return "passed: fewer falls than control off and no harmed cell"


def heldout_verdict(out: Path, robot, spec: dict, params: dict, method: str,
                    n_params: int, reference: Path | None = None) -> dict:
    """Sweep `spec` (a sweep spec's TOML dict) into out/heldout with `params` (a parameter or
    policy file's dict) and judge it (module doc). `reference`: a held-out sweep folder of the same
    spec whose control-off run is compared with (the sweep then runs control on only).
    Resumable: the sweep resumes, the rest reruns."""
    t0 = time.perf_counter()
    if reference is not None:
        spec = spec | {"sweep": spec["sweep"] | {"control": ["on"]}}
    path = out / "heldout_spec.json"
    path.write_text(json.dumps(spec_record(spec, out), indent=1) + "\n")
    controller = controller_params(params)
    # One engine for both sides of the comparison: the pairs of pushes differ by the controller
    # only (a held-out sweep resumed on a CPU would otherwise run MuJoCo C against a GPU's MJX
    # reference; tests/test_robot_tune.py).
    engine = computed_with(Path(reference)) if reference is not None else None
    engine = engine or computed_with(out / "heldout") or "auto"
    manifest = run_sweep(parse_spec(read_spec_record(path)), out / "heldout", params=controller,
                         model_params=robot, quiet=True, backend=engine,
                         schedule=controller_schedule(params))
    if not manifest["complete"]:
        raise RuntimeError(f"{out / 'heldout'}: the held-out sweep is incomplete; rerun to "
                           "resume")
    off = Path(reference if reference is not None else out / "heldout")
    res = compare_runs([f"{off}:off", f"{out / 'heldout'}:on"], out / "compare",
                       labels=["control off", "tuned"], bands=Bands(sectors=4),
                       min_pushes=MIN_CELL_PUSHES, harm_pp=HARM_PP, robot=robot)
    v = res["verdict"]["runs"]["tuned"]
    ratio = v["ratio_to_reference"]
    passed = bool(ratio is not None and ratio < 1.0 and v["no_harm"]
                  and v["cells_checked"] > 0)
    return dict(robot=robot.name, n_pushes=int(v["n"]),
                off_fall=round(float(v["reference_fall_rate"]), 5),
                on_fall=round(float(v["fall_rate"]), 5),
                ratio=None if ratio is None else round(float(ratio), 4),
                harmed_cells=v["harmed_cells"], cells_checked=int(v["cells_checked"]),
                method=method, n_params=n_params,
                wall_s=round(time.perf_counter() - t0, 1),
                device=computed_on(manifest) or device_kind(),
                passed=passed, why=verdict_reason(v))


def relative_path(path: str | Path, folder: str | Path) -> str:
    """`path` relative to `folder` (both resolved; '/' separated), or absolute where no
    relative path exists (another drive)."""
    target = Path(path).resolve()
    try:
        return Path(os.path.relpath(target, Path(folder).resolve())).as_posix()
    except ValueError:
        return str(target)


def spec_record(spec: dict, folder: str | Path) -> dict:
    """`spec` (a spec's TOML dict) as a spec file in `folder` records it: its [robot] file
    relative to the folder (`relative_path`)."""
    robot = spec.get("robot")
    if not isinstance(robot, dict) or not isinstance(robot.get("file"), str):
        return spec
    return spec | {"robot": robot | {"file": relative_path(robot["file"], folder)}}


def read_spec_record(path: str | Path) -> dict:
    """The spec's TOML dict of a `spec_record` file: its [robot] file taken from the file's
    folder (an absolute one as it is)."""
    path = Path(path)
    spec = json.loads(path.read_text())
    robot = spec.get("robot")
    if isinstance(robot, dict) and isinstance(robot.get("file"), str):
        spec["robot"] = robot | {"file": str((path.parent / robot["file"]).resolve())}
    return spec


def name_controller(robot_file: str | Path, params: dict) -> Path:
    """Write `params` (a parameter or policy file's dict) as `<stem>_controller.json` beside
    the robot file and name it there (replacing a `controller = ...` line, else after the
    top-level keys' first line)."""
    robot_file = Path(robot_file)
    path = robot_file.with_name(f"{robot_file.stem}_controller.json")
    save_policy_json(controller_params(params), controller_schedule(params), path)
    line = f'controller = "{path.name}"'
    text = robot_file.read_text()
    if _CONTROLLER_LINE.search(text):
        text = _CONTROLLER_LINE.sub(line, text, count=1)
    else:
        lines = text.splitlines()
        first = next(i for i, s in enumerate(lines) if re.match(r"^\s*imu\s*=", s))
        lines.insert(first + 1, line)
        text = "\n".join(lines) + "\n"
    robot_file.write_text(text)
    return path


def write_controller(robot_file: str | Path | None, params: dict, out: str | Path) -> Path:
    """Write a passing controller: beside the robot file, named there (`name_controller`);
    for the built-in TKU-X (None), as out/controller.json (its shipped policy is the
    package's, replaced by hand only)."""
    if robot_file is not None:
        return name_controller(robot_file, params)
    return save_policy_json(controller_params(params), controller_schedule(params),
                            Path(out) / "controller.json")
