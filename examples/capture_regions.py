"""One-step capture regions: where a step saves the robot after a push, against the linear
inverted pendulum's theory and the controller's own step (MuJoCo C backend).

    python examples/capture_regions.py           # specs/capture/capture_region_cpu.toml, ~2 min
    python examples/capture_regions.py --small   # 2 pushes x 3 x 3 step targets, seconds (CI)

Writes runs/examples/capture_regions/ (the [step] sweep) and its capture/ folder: regions.json,
j1.json, summary.md and the figures.
"""

import argparse
import os
from pathlib import Path

import tkujax

ROOT = Path(__file__).resolve().parents[1]
SMALL_SPEC = """
[sweep]
name = "example_capture_small"
seed = 0
chunk_size = 32
duration_s = 1.5
control = ["on"]

[push.grid]
impulse_ns = [1.5]
azimuth_deg = [0, 180]
onset_s = [0.3]

[controller]
lateral_steps = 1

[step]
reference = true

[step.grid]
x_m = {start = -0.1, stop = 0.1, num = 3}
y_m = {start = -0.1, stop = 0.1, num = 3}
start_delay_s = [0.0]
"""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        default=os.environ.get("TKUJAX_EXAMPLES_SMALL") == "1",
                        help="CI size (also TKUJAX_EXAMPLES_SMALL=1)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "examples" / "capture_regions"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.small:
        out.mkdir(parents=True, exist_ok=True)
        spec = out.parent / f"{out.name}.toml"
        spec.write_text(SMALL_SPEC)
    else:
        spec = ROOT / "specs" / "capture" / "capture_region_cpu.toml"
    # optimise=0: no gradient-optimal steps (they compile MJX); backend: MuJoCo C.
    result = tkujax.run_capture(spec, out, optimise=0, backend="mujoco")
    print("\n".join(result["files"]))
    print(Path(result["summary"]).read_text())
    return result


if __name__ == "__main__":
    main()
