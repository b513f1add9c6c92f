"""OP3's recovery architecture with the accelerometer gate, against control off, on a CPU.

Before a GPU tune starts from a set of flags (capture-point trigger, sideways steps, a second
step, stance gains), this checks on MuJoCo C that the gated controller at OP3's scaled defaults
does not fall more often than standing still, on random pushes of the held-out distribution
(specs/robots/op3_heldout.toml: 0.2-2.2 N s, every direction, 0.25-0.30 m, onset 0.3-0.6 s,
10-40 ms). Every variant runs the same pushes ("spec": op3_tune_gate.toml's start); "harm"
counts the pushes that fall with the controller and not with the control off, "saved" the
reverse.

    TKUJAX_MENAGERIE=/path/to/mujoco_menagerie python scripts/op3_gate_check.py --n 256 \
        --out results/op3/gate_check_cpu.json
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import RECOMMENDED
from tkujax.robot.robot_setup import robot_setup
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco

REPO = Path(__file__).resolve().parents[1]
GATE = 0.063
STANCE = {k: RECOMMENDED[k] for k in RECOMMENDED if k.startswith("stance_")}
# name -> ControllerParams overrides on OP3's scaled defaults (None: the control off)
VARIANTS = {
    "off": None,
    "paper": {},
    "gate": dict(accel_gate=GATE),
    "gate+cpt": dict(accel_gate=GATE, cp_trigger=1.0),
    "gate+cpt+lat": dict(accel_gate=GATE, cp_trigger=1.0, lateral_steps=1.0),
    "gate+cpt+2": dict(accel_gate=GATE, cp_trigger=1.0, max_steps=2.0),
    "gate+cpt+lat+2": dict(accel_gate=GATE, cp_trigger=1.0, lateral_steps=1.0, max_steps=2.0),
    "gate+cpt+2+stance": dict(accel_gate=GATE, cp_trigger=1.0, max_steps=2.0, **STANCE),
    "gate+cpt+lat+2+stance": dict(accel_gate=GATE, cp_trigger=1.0, lateral_steps=1.0,
                                  max_steps=2.0, **STANCE),
    "gate+cpt+2+stance+rate1+bwd6": dict(accel_gate=GATE, cp_trigger=1.0, max_steps=2.0,
                                         cp_rate_blend=1.0, cp_trigger_backward_m=0.06,
                                         **STANCE),
    "stance": dict(STANCE),
    "gate+stance": dict(accel_gate=GATE, **STANCE),
    "gate+cpt+stance": dict(accel_gate=GATE, cp_trigger=1.0, **STANCE),
    "recommended": dict(RECOMMENDED),
    "recommended-lat": dict(RECOMMENDED, lateral_steps=0.0),
}
# The GPU tune's start: its spec's [controller] on the scaled defaults.
TUNE_SPEC = REPO / "specs" / "robots" / "op3_tune_gate.toml"
SECTORS = ("behind", "right", "front", "left")


def heldout_like(n: int, seed: int) -> tuple[Push, np.ndarray, np.ndarray]:
    """Random pushes of op3_heldout.toml's distribution; also (impulse, sector index)."""
    rng = np.random.default_rng(seed)
    imp = rng.uniform(0.2, 2.2, n)
    az = rng.uniform(0.0, 360.0, n)
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    push = Push(impulse_ns=f(imp), azimuth_rad=f(np.radians(az)),
                height_m=f(rng.uniform(0.25, 0.30, n)), duration_s=f(rng.uniform(0.01, 0.04, n)),
                onset_s=f(rng.uniform(0.3, 0.6, n)))
    return push, imp, (((az + 45.0) % 360.0) // 90.0).astype(int)


def run(args) -> dict:
    robot = robot_setup(str(REPO / "specs" / "robots" / "op3.toml"))
    pushes, imp, sector = heldout_like(args.n, args.seed)
    config = RolloutConfig(duration_s=args.duration)
    falls = {}
    result = dict(n=args.n, seed=args.seed, duration_s=args.duration, variants={})
    variants = dict(VARIANTS, spec=tomllib.loads(TUNE_SPEC.read_text())["controller"])
    for name in args.variants:
        over = variants[name]
        params = controller_params_from(robot.params, over or {}).validate()
        t0 = time.time()
        _, o = simulate_mujoco(pushes, np.full(args.n, 0.0 if over is None else 1.0), params,
                               robot=robot, config=config)
        fell = np.asarray(o.fell, bool)
        falls[name] = fell
        off = falls.get("off", np.zeros_like(fell))
        result["variants"][name] = dict(
            overrides=over, falls=int(fell.sum()), harm=int((fell & ~off).sum()),
            saved=int((off & ~fell).sum()), wall_s=round(time.time() - t0, 1),
            falls_by_sector={s: int(fell[sector == i].sum()) for i, s in enumerate(SECTORS)},
            falls_over_1_2ns=int(fell[imp >= 1.2].sum()))
        print(name, json.dumps({k: v for k, v in result["variants"][name].items()
                                if k != "overrides"}), flush=True)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--duration", type=float, default=2.0)
    names = list(VARIANTS) + ["spec"]
    ap.add_argument("--variants", nargs="+", choices=names, default=names)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    if args.variants[0] != "off":
        args.variants = ["off"] + [v for v in args.variants if v != "off"]
    result = run(args)
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
