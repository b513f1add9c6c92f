"""FPGA twin diagnostic: the closed loop, float and fixed point, logging each tick's IMU,
commands, gate and x_Sup (results/fpga/README.md, section 1, "What stays equal").
Run from the repository root: `python scripts/fpga_trace.py 2.4 0.5`; writes under
/tmp/fpgadiag."""
# ruff: noqa: E501, E741   (research script)

import sys
import numpy as np
import jax.numpy as jnp
from tkujax.control.controller_params import ControllerParams
from tkujax.control.fixed import FixedPointConfig
from tkujax.sim.push import Push, onset_from_phase
from tkujax.sim.rollout_mjx import RolloutConfig
import tkujax.sim.rollout_mujoco as rm


def main() -> None:
    imp = np.repeat(np.array([0.5, 0.6, 0.7, 0.8, 0.9]), 4)
    az = np.tile(np.array([0, 0, 180, 180]), 5)
    ph = np.tile(np.array([0.2, 0.5, 0.2, 0.5]), 5)
    on = onset_from_phase(float(sys.argv[2]) if len(sys.argv) > 2 else 0.75, ph)
    n = len(imp)
    P = Push(
        jnp.asarray(imp, jnp.float32),
        jnp.radians(jnp.asarray(az, jnp.float32)),
        jnp.full(n, 0.36, jnp.float32),
        jnp.full(n, 0.02, jnp.float32),
        jnp.asarray(on, jnp.float32),
    )
    params = ControllerParams.paper()
    dur = float(sys.argv[1]) if len(sys.argv) > 1 else 2.0
    log = []
    of, ofx = rm._control_tick, rm._control_tick_fx


    def wf(states, gyro, accel, *a, **k):
        r = of(states, gyro, accel, *a, **k)
        log.append(
            (
                np.asarray(gyro),
                np.asarray(accel),
                np.asarray(r[1]),
                np.asarray(r[2].gate),
                np.asarray(r[0].x_sup_m),
            )
        )
        return r


    def wx(states, gyro, accel, *a, **k):
        r = ofx(states, gyro, accel, *a, **k)
        log.append(
            (
                np.asarray(gyro),
                np.asarray(accel),
                np.asarray(r[1]),
                np.asarray(r[3].gate),
                np.asarray(r[0].x_sup_m),
            )
        )
        return r


    rm._control_tick, rm._control_tick_fx = wf, wx
    res = {}
    for name, fx in [("float", None), ("fixed", FixedPointConfig(straight_through=False))]:
        log.clear()
        s, o = rm.simulate_mujoco(
            P, np.ones(n, np.float32), params, config=RolloutConfig(duration_s=dur, fixed=fx)
        )
        res[name] = dict(
            gyro=np.stack([l[0] for l in log], 1),
            accel=np.stack([l[1] for l in log], 1),
            legs=np.stack([l[2] for l in log], 1),
            gate=np.stack([l[3] for l in log], 1),
            xsup=np.stack([l[4] for l in log], 1),
            fell=np.asarray(o["fell"]),
            step=np.asarray(o["step_length_m"]),
            lank=np.asarray(s.l_ankle),
            rank=np.asarray(s.r_ankle),
            pitch=np.asarray(s.pitch),
        )
    np.savez(
        f"/tmp/fpgadiag/trace_{dur}_{sys.argv[2] if len(sys.argv) > 2 else 0.75}.npz",
        **{f"{k}_{f}": v for k, d in res.items() for f, v in d.items()},
        imp=imp,
        az=az,
        ph=ph,
    )
    F, X = res["float"], res["fixed"]
    lsb = np.radians(360 / 4096)
    for i in range(n):
        d = np.abs(F["legs"][i] - X["legs"][i]) / lsb
        first = np.flatnonzero(d.max(-1) > 0.5)
        print(
            f"{imp[i]:.1f} az{az[i]:3d} ph{ph[i]} fell {int(F['fell'][i])}{int(X['fell'][i])} dstep {1e3 * (X['step'][i] - F['step'][i]):7.2f} mm; "
            f"first gate f {np.argmax(F['gate'][i] > 0.5)} x {np.argmax(X['gate'][i] > 0.5)}; cmd diff ticks {first[:12]} maxLSB {d.max():.0f}"
        )


if __name__ == "__main__":
    main()
