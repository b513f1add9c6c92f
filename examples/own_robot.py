"""Bring your own robot: a robot file (docs/robots.md) checked, stood up, and pushed.

The robot here is one tkujax generates itself (`tkujax.robot.builtin.write_generated_robot`:
an MJCF file and its robot file), so the example needs no third-party files; point ROBOT at
your own `robot.toml` to do the same with your humanoid.

    python examples/own_robot.py            # 2 impulses x 8 azimuths x control off/on
    python examples/own_robot.py --small    # 8 pushes, seconds (CI)

Writes runs/examples/own_robot/: robot/ (the MJCF and its robot file), sweep/ (the sweep and
its maps).
"""

import argparse
import os
from pathlib import Path

import tkujax
from tkujax.robot.builtin import write_generated_robot
from tkujax.studies.robot_inputs import robot_lip
from tkujax.robot.file_summary import robot_stand_summary

ROOT = Path(__file__).resolve().parents[1]
SPEC = """
[sweep]
name = "own_robot"
seed = 0
chunk_size = 16
duration_s = {duration}
control = ["off", "on"]

[push.grid]
impulse_ns = [0.5, 3.0]
azimuth_deg = {azimuths}
onset_s = [0.3]
"""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        default=os.environ.get("TKUJAX_EXAMPLES_SMALL") == "1",
                        help="CI size (also TKUJAX_EXAMPLES_SMALL=1)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "examples" / "own_robot"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    robot_file = write_generated_robot(out / "robot", name="my_robot")

    stand = robot_stand_summary(robot_file, seconds=1.0 if args.small else 5.0)
    print({k: v for k, v in stand.items() if not isinstance(v, dict | list)})

    spec = out / "own_robot.toml"
    spec.write_text(SPEC.format(duration=1.5 if args.small else 2.0,
                                azimuths="[0, 180]" if args.small else
                                "{start = 0, stop = 360, num = 8, endpoint = false}"))
    robot = tkujax.robot_from_file(robot_file)   # the robot, its controller scaled to it
    sweep = out / "sweep"
    tkujax.run_sweep(spec, sweep, robot=robot, backend="mujoco")
    maps = tkujax.make_maps(sweep, robot=robot, lip=robot_lip(robot))
    records = tkujax.load(sweep)
    print(f"{records['fell'].mean():.1%} of {records['fell'].size} pushes fell")
    print("\n".join(maps["files"]))
    return dict(stand=stand, records=records, maps=maps)


if __name__ == "__main__":
    main()
