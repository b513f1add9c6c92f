"""Two controllers on the same pushes and robots: the paper's parameters against the
recommended recovery policy, with difference maps and a no-harm verdict (MuJoCo C backend).

    python examples/compare_controllers.py           # 6 impulses x 8 azimuths, a few minutes
    python examples/compare_controllers.py --small   # 8 pushes per controller, seconds (CI)

Writes runs/examples/compare_controllers/: paper/ and recommended/ (two sweeps of one spec)
and compare/ (summary.md, the difference maps, the table).
"""

import argparse
import os
from pathlib import Path

import tkujax

ROOT = Path(__file__).resolve().parents[1]
SPEC = """
[sweep]
name = "compare_example"
seed = 0
chunk_size = 16
duration_s = {duration}
control = ["on"]

[push.grid]
impulse_ns = {impulses}
azimuth_deg = {azimuths}
onset_s = [0.3]
"""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        default=os.environ.get("TKUJAX_EXAMPLES_SMALL") == "1",
                        help="CI size (also TKUJAX_EXAMPLES_SMALL=1)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "examples" / "compare_controllers"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    spec = out / "spec.toml"
    spec.write_text(SPEC.format(
        duration=1.5 if args.small else 2.0,
        impulses="[1.0, 2.5]" if args.small else "{start = 0.5, stop = 3.0, num = 6}",
        azimuths="[0, 90, 180, 270]" if args.small else
        "{start = 0, stop = 360, num = 8, endpoint = false}"))

    policy_params, schedule = tkujax.recommended_policy()
    runs = {"paper": dict(params=tkujax.ControllerParams.paper()),
            "recommended": dict(params=policy_params, schedule=schedule)}
    for name, kwargs in runs.items():
        tkujax.run_sweep(spec, out / name, backend="mujoco", **kwargs)
        fell = tkujax.load(out / name)["fell"]
        print(f"{name:12s} {fell.mean():.1%} of {fell.size} pushes fell")

    result = tkujax.compare_runs([str(out / name) for name in runs], out / "compare",
                                 labels=list(runs), min_pushes=1 if args.small else 8)
    print(Path(result["summary"]).read_text())
    return result


if __name__ == "__main__":
    main()
