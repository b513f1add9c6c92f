"""OP3 pushed from the front: what the gated controller's step does (MuJoCo C, CPU).

For a few pushes from the front (azimuth 180 deg: the robot falls backward) it prints, per
controller setting: fall, when the step triggers (after the push's onset), the latched x_sup,
the swing foot, the IK's reachability, the feet's x at touchdown and the capture point then
(world x relative to the rearmost ankle; OP3's heel reaches 6.35 cm behind the ankle).
"""
from __future__ import annotations
import json
import numpy as np
import jax.numpy as jnp
from pathlib import Path
from tkujax.control.params_files import controller_params_from
from tkujax.robot.robot_setup import robot_setup
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco

REPO = Path(__file__).resolve().parents[1]
TUNED = json.loads((REPO / "results/op3/gate/tune/params_tuned.json").read_text())


def diag(over, imps, onset=0.4, height=0.275, dur=0.02, label=""):
    robot = robot_setup(str(REPO / "specs" / "robots" / "op3.toml"))
    n = len(imps)

    def f(v):
        return jnp.asarray(np.broadcast_to(v, (n,)), jnp.float32)

    push = Push(impulse_ns=f(imps), azimuth_rad=f(np.pi), height_m=f(height), duration_s=f(dur),
                onset_s=f(onset))
    on = over is not None
    params = controller_params_from(robot.params, over or {}).validate()
    s, o = simulate_mujoco(push, np.full(n, 1.0 if on else 0.0), params, robot=robot,
                           config=RolloutConfig(duration_s=2.0))
    t, com = np.asarray(s.t), np.asarray(s.com)
    ra, la = np.asarray(s.r_ankle), np.asarray(s.l_ankle)
    w, xs, reach = np.asarray(s.step_weight), np.asarray(s.x_sup), np.asarray(s.reachable)
    pe, pt = np.degrees(np.asarray(s.pitch_est)), np.degrees(np.asarray(s.pitch))
    om = np.sqrt(9.81 / 0.262)
    print(f"== {label}")
    for i in range(n):
        ti = t[i] if t.ndim == 2 else t
        v = np.gradient(com[i, :, 0], ti)
        cp = com[i, :, 0] + v / om
        k = np.argmax(w[i] >= 0.5) if (w[i] >= 0.5).any() else None
        line = f"J={imps[i]:.2f} fell={bool(o.fell[i])} "
        if k is not None:
            # touchdown: 1 period after trigger (approx), report at trigger+step_period
            per = params.step_period
            kt = min(int(np.searchsorted(ti, ti[k] + float(per))), len(ti) - 1)
            back = min(ra[i, kt, 0], la[i, kt, 0])
            line += (f"trig t-onset={ti[k]-onset:.3f}s x_sup={xs[i,k]*100:+.1f}cm "
                     f"pitch_true={pt[i,k]:+.1f} est={pe[i,k]:+.1f} | td(+{per:.2f}s): "
                     f"rA={ra[i,kt,0]*100:+.1f} lA={la[i,kt,0]*100:+.1f} "
                     f"cp={cp[kt]*100:+.1f} cp-rearAnkle={(cp[kt]-back)*100:+.1f}cm "
                     f"unreach={int((reach[i]<0.5).sum())} xsup_final={xs[i,-1]*100:+.1f}")
        else:
            line += "no step"
        line += f" | cp_min={cp.min()*100:+.1f}"
        print(line, flush=True)
    return o


if __name__ == "__main__":
    imps = [1.2, 1.3, 1.4, 1.5, 1.6]
    diag(None, imps, label="off")
    diag(TUNED, imps, label="tuned")
