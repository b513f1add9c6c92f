"""OP3's falls with the tuned gated controller and a few overrides (MuJoCo C).

Random pushes of op3_heldout.toml's distribution (scripts/op3_gate_check.heldout_like; use a
seed other than the held-out sweep's 11 for development); --front keeps the pushes from the
front sector (azimuth 135-225 deg: the robot falls backward), --side those from the right and
the left of 1.7 N s and more. Every variant runs the same pushes; harm counts pushes that fall
with the variant and not with the control off, vs_tuned the change against the tuned set.

    TKUJAX_MENAGERIE=... python scripts/op3_front_check.py --n 256 --front --variants tuned bwd3
    TKUJAX_MENAGERIE=... python scripts/op3_front_check.py --n 512 --seed 5 --variants widen
"""
from __future__ import annotations
import argparse
import json
import sys
import time
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent))
from op3_gate_check import heldout_like, SECTORS
from tkujax.control.params_files import controller_params_from
from tkujax.robot.robot_setup import robot_setup
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco

REPO = Path(__file__).resolve().parents[1]
TUNED = json.loads((REPO / "results/op3/gate/tune/params_tuned.json").read_text())
VARIANTS = {
    "off": None,
    "tuned": {},
    "bwd2": dict(cp_trigger_backward_m=0.02),
    "bwd3": dict(cp_trigger_backward_m=0.03),
    "bwd4": dict(cp_trigger_backward_m=0.04),
    "bwd5": dict(cp_trigger_backward_m=0.05),
    "bwd3g2": dict(cp_trigger_backward_m=0.03, cp_gain=2.0),
    "bwd3g25": dict(cp_trigger_backward_m=0.03, cp_gain=2.5),
    "bwd3la": dict(cp_trigger_backward_m=0.03, cp_lookahead_s=0.1),
    "bwd3sp2": dict(cp_trigger_backward_m=0.03, step_period=0.2),
    # Sideways steps: toward the capture point (the falling side's foot), or the widening step
    # (cp_gain_lateral < 0: the push side's foot outward), with one step or two.
    "toward": dict(lateral_steps=1.0, cp_trigger_lateral_m=0.05),
    "widen2": dict(lateral_steps=1.0, cp_trigger_lateral_m=0.03, cp_gain_lateral=-1.0),
    "widen1": dict(lateral_steps=1.0, cp_trigger_lateral_m=0.03, cp_gain_lateral=-1.0,
                   max_steps=1.0),
    "widen1bwd3": dict(lateral_steps=1.0, cp_trigger_lateral_m=0.03, cp_gain_lateral=-1.0,
                       max_steps=1.0, cp_trigger_backward_m=0.03),
    # specs/robots/op3_widen.json: the above with a short double support
    "widen": json.loads((REPO / "specs/robots/op3_widen.json").read_text()),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--front", action="store_true")
    ap.add_argument("--side", action="store_true")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS))
    ap.add_argument("--extra", default=None, help="JSON dict name -> overrides")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    variants = dict(VARIANTS, **(json.loads(a.extra) if a.extra else {}))
    names = ["off", "tuned"] + [v for v in a.variants if v not in ("off", "tuned")]
    robot = robot_setup(str(REPO / "specs" / "robots" / "op3.toml"))
    m = a.n * 5 if a.front else a.n * 20 if a.side else a.n
    push, imp, sector = heldout_like(m, a.seed)
    keep = (np.flatnonzero(sector == 2)[: a.n] if a.front else
            np.flatnonzero((sector % 2 == 1) & (imp >= 1.7))[: a.n] if a.side else np.arange(a.n))
    push = Push(*(getattr(push, k)[keep] for k in ("impulse_ns", "azimuth_rad", "height_m",
                                                  "duration_s", "onset_s")))
    imp, sector = imp[keep], sector[keep]
    n = len(keep)
    band = (imp >= 1.2) & (imp < 1.7)
    res = dict(n=n, seed=a.seed, front=a.front, side=a.side, variants={})
    falls = {}
    for name in names:
        over = variants[name]
        p = controller_params_from(robot.params, {**TUNED, **(over or {})}).validate()
        t0 = time.time()
        _, o = simulate_mujoco(push, np.full(n, 0.0 if over is None else 1.0), p, robot=robot,
                               config=RolloutConfig(duration_s=2.0))
        fell = np.asarray(o.fell, bool)
        falls[name] = fell
        off, tu = falls["off"], falls.get("tuned", fell)
        r = dict(overrides=over, falls=int(fell.sum()), harm=int((fell & ~off).sum()),
                 saved=int((off & ~fell).sum()), worse_than_tuned=int((fell & ~tu).sum()),
                 better_than_tuned=int((tu & ~fell).sum()), falls_1_2_to_1_7=int(fell[band].sum()),
                 n_1_2_to_1_7=int(band.sum()),
                 by_sector={s: int(fell[sector == i].sum()) for i, s in enumerate(SECTORS)},
                 wall_s=round(time.time() - t0, 1))
        res["variants"][name] = r
        print(name, json.dumps({k: v for k, v in r.items() if k != "overrides"}), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
