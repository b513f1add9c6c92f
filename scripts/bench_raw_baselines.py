"""Which raw-MJX baseline is the closed loop's? Per batch: the bench's raw (unsettled keyframe,
300 steps), the keyframe at 750 steps, the settled stand at 750 steps (flat scan, shared model),
the same with the per-push model fields, and the closed loop (1.5 s = 750 steps) with its
physics-only ablation. Prints one JSON line per row."""

import json
import sys
import time
import statistics
import jax
import jax.numpy as jnp
from tkujax.bench import loop_fn, push_batch
from tkujax.sim import physics
from tkujax.sim.setup import init
from tkujax.sim.randomize import randomize_model


def timed(fn, reps):
    jax.block_until_ready(fn())
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def raw(batch, n_steps, settle_s, per_push_model, reps):
    host, model, index, stand = init(settle_s=settle_s)
    state = physics.batch_state(stand, batch)
    ctrl = jnp.asarray(host.key("stand").ctrl, jnp.float32)
    recs = push_batch(batch)
    if per_push_model:

        def one(d, rec):
            m = randomize_model(
                model,
                index.chest_body,
                mass_scale=rec["link_mass_scale"],
                torso_com_dx_m=rec["torso_com_offset_x_m"],
                friction=rec["floor_friction"],
                kp_scale=rec["servo_kp_scale"],
            )
            return physics.step_holding(m, d, ctrl, n_steps)[0].qpos
    else:

        def one(d, rec):
            return physics.step_holding(model, d, ctrl, n_steps)[0].qpos

    run = jax.jit(jax.vmap(one))
    t0 = time.perf_counter()
    run.lower(state, recs).compile()
    c = time.perf_counter() - t0
    sec = timed(lambda: run(state, recs), reps)
    return dict(
        steps=n_steps, seconds=sec, compile_s=round(c, 1), steps_per_s=batch * n_steps / sec
    )


def loop(batch, name, reps):
    from tkujax.control.controller_params import ControllerParams
    from tkujax.sweeps.sweep import traced_params

    cfg = {
        "physics_only": {"ablate": ("noise", "controller", "wrench", "records")},
        "full": {},
        "flat_raw": None,
    }[name]
    fn = loop_fn(1.5, cfg or {}, shared_model=name == "physics_only", raw=name == "flat_raw")
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    params = traced_params(ControllerParams.paper())
    t0 = time.perf_counter()
    fn.lower(recs, keys, params).compile()
    c = time.perf_counter() - t0
    sec = timed(lambda: fn(recs, keys, params), reps)
    return dict(steps=750, seconds=sec, compile_s=round(c, 1), steps_per_s=batch * 750 / sec)


def main() -> None:
    batch, reps = int(sys.argv[1]), int(sys.argv[2])
    for row in sys.argv[3].split(","):
        if row == "bench_raw":
            r = raw(batch, 300, 0.0, False, reps)
        elif row == "key750":
            r = raw(batch, 750, 0.0, False, reps)
        elif row == "settled750":
            r = raw(batch, 750, 1.0, False, reps)
        elif row == "settled750_model":
            r = raw(batch, 750, 1.0, True, reps)
        else:
            r = loop(batch, row, reps)
        print(
            "ROW",
            json.dumps(dict(row=row, batch=batch, device=jax.devices()[0].device_kind, **r)),
            flush=True,
        )


if __name__ == "__main__":
    main()
