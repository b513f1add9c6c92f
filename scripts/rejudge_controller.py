"""Re-judge a robot file's controller on the held-out pushes of its committed tune: the
held-out sweep of `tkujax tune --robot` (seed 11, 2.0 s), control off and on, and the no-harm
verdict, with today's simulator (results/robots/*/verdict.json: rejudged_current_fall_test).

    python scripts/rejudge_controller.py specs/robots/g1.toml results/robots/g1/pushes.json OUT
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from tkujax.robot import robot_from_file
from tkujax.studies.robot_tune_specs import heldout_spec
from tkujax.studies.robot_verdict import heldout_verdict


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("robot_file")
    ap.add_argument("pushes_json", help="the tune's pushes.json (its push distributions)")
    ap.add_argument("out", help="a new folder for the sweep, the comparison and verdict.json")
    ap.add_argument("--n", type=int, default=8192, help="held-out pushes (default 8192)")
    args = ap.parse_args(argv)
    robot = robot_from_file(args.robot_file)
    pushes = json.loads(Path(args.pushes_json).read_text())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    spec = heldout_spec(str(Path(args.robot_file).resolve()), robot, pushes, args.n)
    verdict = heldout_verdict(out, robot, spec, dataclasses.asdict(robot.params),
                              method="the robot file's controller, re-judged", n_params=0)
    (out / "verdict.json").write_text(json.dumps(verdict, indent=1) + "\n")
    print(json.dumps(verdict))


if __name__ == "__main__":
    main()
