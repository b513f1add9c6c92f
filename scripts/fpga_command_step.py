"""FPGA twin diagnostic: the closed loop with one servo step added to a command, float against
fixed (the IK-angle analysis of results/fpga/README.md, section 1). Run from the repository
root: `python scripts/fpga_command_step.py ...`; writes under /tmp/fpgadiag."""
# ruff: noqa: E501   (research script)

import sys
import functools
import numpy as np
import jax
import jax.numpy as jnp


def main() -> None:
    sys.path.insert(0, "tests")
    import test_fixed_point as T
    from tkujax.sim.tick import quantise_targets

    fx = jax.jit(functools.partial(T.scan_fx, cfg=T.DEFAULT))(T.PARAMS, *T.push_trace())
    fl = T.float_run()
    qx, qf = np.asarray(fx[0], np.float64), np.asarray(fl[0], np.float64)
    print("eps mrad", 1e3 * np.abs(qx - qf).max(), "servo steps", np.abs(qx - qf).max() / T.SERVO_STEP)
    sx, sf = (np.asarray(quantise_targets(jnp.asarray(q, jnp.float32)), np.float64) for q in (qx, qf))
    print("flipped ticks", int((np.abs(sx - sf).max(-1) > 1e-6).sum()), "of", len(sx))
    a = np.array([T._step_cmd(q, T.PARAMS) for q in qx])
    b = np.array([T._step_cmd(q, T.PARAMS) for q in qf])
    c = np.array([T._step_cmd(q, T.PARAMS) for q in sx])
    d = np.array([T._step_cmd(q, T.PARAMS) for q in sf])
    print(
        "cmd step max mm",
        1e3 * np.abs(b).max(),
        "diff unrounded mm",
        1e3 * np.abs(a - b).max(),
        "served diff mm",
        1e3 * np.abs(c - d).max(),
    )


if __name__ == "__main__":
    main()
