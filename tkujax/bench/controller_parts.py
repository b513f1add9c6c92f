"""The controller's pieces timed alone (`tkujax bench --profile`'s `controller_parts`).

Each piece is vmapped over the batch in a scan over the ticks, on synthetic IMU readings:
Kalman, detection, CPG (the paper's, the lateral one and later steps), IK, stance feedback,
quantisation, and the whole `controller_step`. Alone, a piece cannot fuse with its neighbours:
an upper bound of its share in the closed loop. Speeds are reported, never asserted.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.bench.common import n_ticks, timed, traced_paper_params


def _parts(params, batch: int, dtype):
    """{name: (init carry, step(carry, (gyro, accel)) -> carry)} of the controller's pieces, each
    vmapped over the batch; the carry folds in every output so nothing is dead code."""
    from tkujax.control.controller import (detect_push, later_step_feet, controller_init,
                                          controller_step, Sensors, StepsState, stance_offsets)
    from tkujax.control.cpg import cpg_feet, cpg_feet_lateral
    from tkujax.control.kalman import (accel_to_angle, accel_variance, gyro_to_rates,
                                       kalman_init, kalman_step)
    from tkujax.control.solve import solve_legs
    from tkujax.sim.tick import quantise_targets

    zero = jnp.zeros((batch,), dtype)

    def fold(acc, *outs):
        return acc + sum(jnp.sum(jnp.asarray(o, dtype).reshape(batch, -1), -1)
                         for o in jax.tree_util.tree_leaves(outs))

    def vm(f):
        return jax.vmap(f)

    k0 = jax.vmap(lambda _: kalman_init(jnp.stack([jnp.asarray(params.standing_lean, dtype),
                                                   jnp.zeros((), dtype)]), params))(zero)
    s0 = jax.vmap(lambda _: controller_init(params, dtype))(zero)

    def kalman(c, x):
        k, acc = c
        k = vm(lambda k, g, a: kalman_step(k, gyro_to_rates(g), accel_to_angle(a), params,
                                           accel_variance(a, params)))(k, *x)
        return (k, fold(acc, k.phi))

    def detection(acc, x):
        g, a = x
        det = vm(lambda g, a: detect_push(accel_to_angle(a)[0], -accel_to_angle(a)[1],
                                      gyro_to_rates(g)[0], -gyro_to_rates(g)[1], params))(g, a)
        return fold(acc, det)

    def cpg(acc, x):
        g, _ = x
        t = g[:, 0]
        steps = jax.vmap(lambda _: StepsState.init(dtype))(zero)
        x_sup, y_sup = jnp.full_like(t, 0.03), jnp.full_like(t, 0.01)
        return fold(acc, vm(lambda t, x: cpg_feet(t, x, params))(t, x_sup),
                    vm(lambda t, x, y: cpg_feet_lateral(t, x, y, params))(t, x_sup, y_sup),
                    vm(lambda t, s: later_step_feet(t, s, params))(t, steps))

    def ik(acc, x):
        g, _ = x
        p_r = jnp.stack([0.01 * g[:, 0], -params.hip_offset_y + 0.0 * g[:, 1],
                         -params.hip_to_ankle_z + 0.0 * g[:, 2]], -1)
        p_l = p_r * jnp.asarray([1.0, -1.0, 1.0], dtype)
        return fold(acc, vm(lambda a, b: solve_legs(a, b, params))(p_r, p_l))

    def stance(acc, x):
        g, a = x
        return fold(acc, vm(lambda g, a: stance_offsets(a[0], g[0], a[1], g[1], params))(g, a))

    def quantise(acc, x):
        g, _ = x
        return fold(acc, quantise_targets(jnp.tile(g, (1, 4))))

    def whole(c, x):
        s, acc = c
        s, out = vm(lambda s, g, a: controller_step(s, Sensors(g, a), params, 1.0))(s, *x)
        return (s, fold(acc, out))

    return {"kalman": ((k0, zero), kalman), "detection": (zero, detection), "cpg": (zero, cpg),
            "ik": (zero, ik), "stance": (zero, stance), "quantise": (zero, quantise),
            "controller_step": ((s0, zero), whole)}


def profile_controller_parts(batch: int, duration_s: float = 0.3,
                             repeats: int = 1) -> list:
    """ms per tick of each controller piece alone at `batch` (see the module docstring)."""
    params = traced_paper_params()
    ticks = n_ticks(duration_s)
    rng = np.random.default_rng(0)
    gyro = jnp.asarray(rng.normal(0.0, 0.5, (ticks, batch, 3)), jnp.float32)
    accel = jnp.asarray(rng.normal(0.0, 0.5, (ticks, batch, 3)) + [0.0, 0.0, 9.81],
                        jnp.float32)
    rows = []
    for name, (init, step) in _parts(params, batch, jnp.float32).items():
        def run(init=init, step=step):
            return jax.lax.scan(lambda c, x: (step(c, x), None), init, (gyro, accel))[0]

        fn = jax.jit(run)
        sec = timed(fn, repeats)
        rows.append(dict(part=name, seconds=sec, ms_per_tick=1e3 * sec / ticks))
    return rows
