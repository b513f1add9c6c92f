"""`tkujax stand`: the robot holds its `stand` keyframe; report what was measured."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sim import physics
from tkujax.sim.setup import init
from tkujax.model import ModelParams

ENGINES = ("mjx", "mujoco")


def simulate_stand(seconds: float = 5.0, batch: int = 8, engine: str = "mjx",
                   perturb_deg: float = 1.0, seed: int = 0,
                   params: ModelParams | None = None) -> dict:
    """Simulate `batch` robots standing for `seconds`, each starting from the `stand` keyframe
    with its joint angles perturbed by U(-perturb_deg, perturb_deg), holding the stand targets.

    Returns a summary dict (pitch in degrees): per-robot min/max pitch, max deviation from the
    keyframe's lean, final pelvis height, whether any robot fell, wall time and steps/s.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if not (0 < seconds <= 60):
        raise ValueError(f"seconds must be in (0, 60], got {seconds!r}")
    if not (1 <= batch <= 1_000_000):
        raise ValueError(f"batch must be in [1, 1000000], got {batch!r}")
    model = physics.host_model(params)
    n_steps = int(round(seconds / model.opt.timestep))
    key_ctrl = np.array(model.key("stand").ctrl)
    lean_deg = (params or ModelParams()).stand_lean_deg
    rng = np.random.default_rng(seed)
    dq = np.deg2rad(rng.uniform(-perturb_deg, perturb_deg, size=(batch, model.nq - 7)))

    t0 = time.perf_counter()
    compile_s = 0.0
    if engine == "mjx":
        _, device, _, state = init(params, settle_s=0.0)    # the keyframe itself, unsettled
        states = physics.batch_state(state, batch)
        states = states.replace(qpos=states.qpos.at[:, 7:].add(jnp.asarray(dq, states.qpos.dtype)))
        run = jax.jit(jax.vmap(lambda s: physics.step_holding(
            device, s, jnp.asarray(key_ctrl), n_steps)))
        run = run.lower(states).compile()
        compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        _, trace = jax.block_until_ready(run(states))
        trace = jax.tree_util.tree_map(np.asarray, trace)
    else:
        traces = []
        for i in range(batch):
            data = physics.stand_data(model)
            data.qpos[7:] += dq[i]
            traces.append(physics.step_holding_c(model, data, key_ctrl, n_steps)[1])
        trace = {k: np.stack([t[k] for t in traces]) for k in traces[0]}
    wall = time.perf_counter() - t0

    pitch_deg = np.rad2deg(trace["pitch"])
    height = trace["base_pos"][:, :, 2]
    return dict(
        engine=engine, batch=batch, seconds=seconds, device=str(jax.devices()[0]),
        stand_lean_deg=lean_deg,
        pitch_min_deg=pitch_deg.min(axis=1).round(3).tolist(),
        pitch_max_deg=pitch_deg.max(axis=1).round(3).tolist(),
        max_pitch_deviation_deg=float(np.abs(pitch_deg - lean_deg).max()),
        final_pelvis_height_m=height[:, -1].round(4).tolist(),
        fell=bool((height.min(axis=1) < 0.15).any()),
        compile_s=round(compile_s, 2), wall_s=round(wall, 2),
        physics_steps_per_s=round(batch * n_steps / wall, 1),
    )
