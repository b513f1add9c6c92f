"""The leg chain's small linear solve (tkujax.sim.leg_chain.spd_solve): equal to numpy's on
damped normal equations, and free of the CPU runtime deadlock that batched LAPACK solves
(jnp.linalg.solve) ran into in the MuJoCo C rollout's host IK."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.sim.leg_chain import spd_solve


@pytest.mark.parametrize("n", [5, 6])
def test_spd_solve_matches_numpy_on_damped_normal_equations(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        jac = rng.normal(size=(6, n))
        h = jac.T @ jac
        h = h + 1e-6 * np.trace(h) * np.eye(n)
        b = rng.normal(size=n)
        x = np.asarray(jax.jit(spd_solve)(jnp.asarray(h), jnp.asarray(b)))
        np.testing.assert_allclose(h @ x, b, atol=1e-4 * np.abs(b).max())
        np.testing.assert_allclose(x, np.linalg.solve(h, b), rtol=1e-3, atol=1e-4)


# Two legs' Newton steps, each solving, batched: the pattern that deadlocked with LAPACK.
_PROGRAM = """
import jax, jax.numpy as jnp, numpy as np
from tkujax.sim.leg_chain import spd_solve
def leg(a, b):
    q = jnp.zeros(6)
    for _ in range(4):
        h = a @ a.T + 0.1 * jnp.eye(6) + jnp.diag(jnp.sin(q) ** 2)
        q = q + spd_solve(h, b - h @ q)
    return q
g = jax.jit(jax.vmap(lambda a, b: jnp.concatenate([leg(a, b), leg(a.T, b)])))
rng = np.random.default_rng(0)
a = rng.random((4096, 6, 6)).astype(np.float32)
b = rng.random((4096, 6)).astype(np.float32)
for i in range(30):
    assert np.isfinite(np.asarray(g(a + 1e-3 * i, b))).all()
print("done")
"""


def test_two_batched_leg_solves_in_one_program_finish():
    out = subprocess.run([sys.executable, "-c", _PROGRAM], capture_output=True, text=True,
                         timeout=240)
    assert out.returncode == 0 and "done" in out.stdout, out.stderr[-2000:]
