"""FPGA twin diagnostic: the float controller alone, one servo step (0.088 deg) added to one
joint command for one tick: how far the realised step moves (the 2.36 mm floor of
results/fpga/README.md, section 1). Run from the repository root; writes under /tmp/fpgadiag."""
# ruff: noqa: E501   (research script)

import sys
import numpy as np
import jax.numpy as jnp
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.push import Push, onset_from_phase
from tkujax.sim.rollout_mjx import RolloutConfig
import tkujax.sim.rollout_mujoco as rm


def main() -> None:
    onset = float(sys.argv[1])
    dur = float(sys.argv[2])
    imp = np.repeat(np.array([0.5, 0.6, 0.7, 0.8, 0.9]), 2)
    az = np.tile(np.array([0, 180]), 5)
    ph = np.full(10, 0.2)
    on = onset_from_phase(onset, ph)
    n = len(imp)
    P = Push(
        jnp.asarray(imp, jnp.float32),
        jnp.radians(jnp.asarray(az, jnp.float32)),
        jnp.full(n, 0.36, jnp.float32),
        jnp.full(n, 0.02, jnp.float32),
        jnp.asarray(on, jnp.float32),
    )
    params = ControllerParams.paper()
    lsb = np.float32(np.radians(360 / 4096))
    state = dict(k=0, tick=None, joint=None)
    of = rm._control_tick


    def wf(states, gyro, accel, *a, **kw):
        r = of(states, gyro, accel, *a, **kw)
        if state["tick"] is not None and state["k"] == state["tick"]:
            legs = np.asarray(r[1]).copy()
            legs[:, state["joint"]] += lsb
            r = (r[0], jnp.asarray(legs), r[2])
        state["k"] += 1
        return r


    rm._control_tick = wf


    def run(tick=None, joint=None):
        state.update(k=0, tick=tick, joint=joint)
        return rm.simulate_mujoco(
            P, np.ones(n, np.float32), params, config=RolloutConfig(duration_s=dur)
        )[1]


    base = run()
    ok = (~np.asarray(base["fell"])) & (np.abs(np.asarray(base["step_length_m"])) > 0.005)
    print("stand+step pushes", [(imp[i], az[i]) for i in np.flatnonzero(ok)])
    t0 = int(round(onset / 0.03))
    worst = 0
    for dt in (2, 4, 6, 9, 12):
        for joint in (2, 3, 8, 9):  # hip pitch, knee of right (0-5) / left (6-11) legs
            o = run(t0 + dt, joint)
            d = 1e3 * np.abs(np.asarray(o["step_length_m"]) - np.asarray(base["step_length_m"]))
            fell_change = int((np.asarray(o["fell"]) != np.asarray(base["fell"])).sum())
            worst = max(worst, d[ok].max())
            print(
                f"tick onset+{dt:2d} joint {joint:2d}: |dstep| on stand+step pushes max {d[ok].max():.2f} mm median {np.median(d[ok]):.2f}; fall changes {fell_change}",
                flush=True,
            )
    print("worst", worst)


if __name__ == "__main__":
    main()
