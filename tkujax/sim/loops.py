"""The two loop structures that run a closed loop's `TickPieces` (ProgramOptions.loop):

  nested_loop  a scan over control ticks, each with a scan over its physics substeps;
  flat_loop    one scan over physics steps, the control tick and the Series row in
               `lax.cond`s on the step counter.

The same arithmetic: the Series agree to float rounding. Both take the initial carry
(d, imu, ctrl_state) and the per-tick PRNG keys and return the stacked per-tick rows.
`ProgramOptions.gradient_window_ticks` truncates backpropagation in both (`window_stop`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.sim.closed_loop import TickPieces
from tkujax.sim.options import ProgramOptions, checkpoints


def window_stop(state, at_boundary: jax.Array):
    """`state` with jax.lax.stop_gradient on its float leaves where `at_boundary` (a traced
    scalar bool) holds: a select between equal values, so forward values are unchanged, bit
    for bit, and no cotangent crosses the boundary."""
    def leaf(x):
        if not jnp.issubdtype(jnp.result_type(x), jnp.inexact):
            return x
        return jnp.where(at_boundary, jax.lax.stop_gradient(x), x)

    return jax.tree.map(leaf, state)


def _substeps(pieces: TickPieces, program: ProgramOptions, carry, n: int):
    """`n` physics substeps of carry = (d, imu) in a scan."""
    carry, _ = jax.lax.scan(lambda c, _: (pieces.substep(c), None), carry, None, length=n,
                            unroll=program.unroll_substeps)
    return carry


def nested_loop(pieces: TickPieces, program: ProgramOptions, carry, tick_keys: jax.Array):
    """A scan over control ticks (one per key), each with a scan over its physics substeps;
    carry = (d, imu, ctrl_state). Returns the rows, stacked."""
    wrap_tick, _ = checkpoints(program.remat)
    window = program.gradient_window_ticks

    def tick(carry, xs):
        if window is not None:
            key, k = xs
            carry = window_stop(carry, k % window == 0)
        else:
            key = xs
        d, imu, ctrl_state = carry
        ctrl_state, command, earlier, out = pieces.control(imu, ctrl_state, key)
        with jax.named_scope("physics"):
            if pieces.switch > 0:
                # Fractional latency: the earlier command holds until the static switch substep.
                d, imu = _substeps(pieces, program, (d.replace(ctrl=earlier), imu), pieces.switch)
            d, imu = _substeps(pieces, program, (d.replace(ctrl=command), imu),
                               pieces.substeps - pieces.switch)
        return (d, imu, ctrl_state), pieces.record(d, out, ctrl_state)

    n_ticks = tick_keys.shape[0]
    xs = tick_keys if window is None else (tick_keys, jnp.arange(n_ticks, dtype=jnp.int32))
    _, rows = jax.lax.scan(wrap_tick(tick), carry, xs, unroll=program.unroll_ticks)
    return rows


def flat_loop_carry(pieces: TickPieces, carry, tick_keys: jax.Array):
    """The flat loop's initial carry from the nested one's (d, imu, ctrl_state): the tick's
    controller output and command, and the buffer of rows (zeros of their shapes)."""
    d, imu, ctrl_state = carry
    shapes = jax.eval_shape(pieces.control, imu, ctrl_state, tick_keys[0])
    out0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes[3])
    row = jax.eval_shape(pieces.record, d, out0, ctrl_state)
    buffer0 = jax.tree.map(lambda a: jnp.zeros((tick_keys.shape[0],) + a.shape, a.dtype), row)
    return (d, imu, ctrl_state, out0, d.ctrl, buffer0)


def flat_loop(pieces: TickPieces, program: ProgramOptions, carry, tick_keys: jax.Array):
    """One scan over n_ticks * substeps physics steps; carry from `flat_loop_carry`. Step i
    opens tick k = i // substeps when i % substeps == 0 (the controller) and closes it when
    i % substeps == substeps - 1 (its row, written into the buffer in the carry). The conds'
    predicates come from the scan counter alone, so under vmap they stay branches (a batched
    predicate would make vmap run both sides and select). Returns the rows, stacked."""
    control = checkpoints(program.remat)[0](pieces.control)   # the tick checkpoint: the control
    substeps, switch, window = pieces.substeps, pieces.switch, program.gradient_window_ticks

    def step(carry, i):
        d, imu, ctrl_state, out, command, buffer = carry
        k, j = i // substeps, i % substeps
        if window is not None:
            d, imu, ctrl_state = window_stop((d, imu, ctrl_state), i % (window * substeps) == 0)

        def open_tick(imu, ctrl_state, out, command, ctrl):
            ctrl_state, command, earlier, out = control(imu, ctrl_state, tick_keys[k])
            return ctrl_state, out, command, earlier

        def keep(imu, ctrl_state, out, command, ctrl):
            return ctrl_state, out, command, ctrl

        ctrl_state, out, command, ctrl = jax.lax.cond(j == 0, open_tick, keep,
                                                      imu, ctrl_state, out, command, d.ctrl)
        if switch > 0:
            ctrl = jnp.where(j == switch, command, ctrl)
        d, imu = pieces.substep((d.replace(ctrl=ctrl), imu))

        def close_tick(buffer):
            new = pieces.record(d, out, ctrl_state)
            return jax.tree.map(lambda b, x: jax.lax.dynamic_update_index_in_dim(b, x, k, 0),
                                buffer, new)

        buffer = jax.lax.cond(j == substeps - 1, close_tick, lambda b: b, buffer)
        return (d, imu, ctrl_state, out, command, buffer), None

    n_steps = tick_keys.shape[0] * substeps
    (*_, rows), _ = jax.lax.scan(step, carry, jnp.arange(n_steps, dtype=jnp.int32),
                                 unroll=program.unroll_substeps)
    return rows
