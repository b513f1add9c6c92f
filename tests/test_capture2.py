"""Two commanded steps (StepOverride.steps = 2) and the J_N table: the feet against hand-computed
positions (no physics), steps = 1 bit-identical to one step, the [step.grid] keys of the second
step, and jn_table on hand-made records."""

import copy
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control import ControllerParams, StepOverride
from tkujax.control.controller import override_feet
from tkujax.control.cpg import cpg_feet_lateral
from tkujax.studies.capture.region import jn_table
from tkujax.dialects.sweep_spec import SpecError, load_spec, parse_spec
from tkujax.sweeps.sweep import step_override

P = ControllerParams.paper()      # T = 0.3 s, gamma = 0.2: lift 0.03 s, land 0.27 s after start
D_Y, D_Z, H = 0.045, 0.20, 0.03   # hip_offset_y, hip_to_ankle_z, lift_height (paper)


def _feet(ov, t):
    z = jnp.zeros(3, jnp.float32)
    r, lf, td = override_feet(ov, jnp.float32(t), jnp.float32(-1e9), z, z, jnp.float32(-1.0), P)
    return np.asarray(r), np.asarray(lf), float(td)


def test_paper_constants():
    assert (P.step_period, P.double_support_ratio, P.lift_height) == (0.3, 0.2, H)
    assert (P.hip_offset_y, P.hip_to_ankle_z) == (D_Y, D_Z)


# First step: left foot (y >= 0) by (0.10, 0.05), from the onset t = 0; lands at 0.27 s. Second
# step: the right foot by (0.08, -0.04), starting at 0.27 + delay2 s.
TWO = dict(x_m=0.10, y_m=0.05, onset_s=0.0, steps=2.0, x2_m=0.08, y2_m=-0.04)


@pytest.mark.parametrize("t, right, left", [
    # Before the first step's lift: the stand pose.
    (0.01, (0.0, -D_Y, -D_Z), (0.0, D_Y, -D_Z)),
    # First step landed, second not lifted (0.28 - 0.27 = 0.01 < 0.03): +-(0.05, 0.025).
    (0.28, (-0.05, -D_Y - 0.025, -D_Z), (0.05, D_Y + 0.025, -D_Z)),
    # Mid second swing (0.27 + 0.03 + 0.12): x at sin(pi/4) of its amplitude, the right foot
    # at full lift; right +(0.04, -0.02) s, left -(0.04, -0.02) s, s = sin(pi/4).
    (0.42, (-0.05 + 0.04 * 0.5 ** 0.5, -D_Y - 0.025 - 0.02 * 0.5 ** 0.5, -D_Z + H),
     (0.05 - 0.04 * 0.5 ** 0.5, D_Y + 0.025 + 0.02 * 0.5 ** 0.5, -D_Z)),
    # Both landed: left (0.05 - 0.04, 0.025 + 0.02), right (-0.05 + 0.04, -0.025 - 0.02).
    (1.0, (-0.01, -D_Y - 0.045, -D_Z), (0.01, D_Y + 0.045, -D_Z)),
])
def test_two_step_feet_hand_computed(t, right, left):
    r, lf, td = _feet(StepOverride(**TWO), t)
    np.testing.assert_allclose(r, right, atol=2e-6)
    np.testing.assert_allclose(lf, left, atol=2e-6)
    assert td == pytest.approx(0.54, abs=1e-6)          # the second touchdown: 0.27 + 0.27


def test_two_step_delay_and_mirror():
    """delay2_s shifts the second step; a right first step (y < 0) gives a left second step."""
    r, lf, td = _feet(StepOverride(**(TWO | dict(delay2_s=0.1))), 0.39)   # 0.39 - 0.37 < 0.03
    np.testing.assert_allclose(r, (-0.05, -D_Y - 0.025, -D_Z), atol=2e-6)
    assert td == pytest.approx(0.64, abs=1e-6)
    ov = StepOverride(x_m=0.06, y_m=-0.04, onset_s=0.2, steps=2.0, x2_m=0.1, y2_m=0.06)
    r, lf, td = _feet(ov, 2.0)
    # First (right): right +(0.03, -0.02), left -(0.03, -0.02); second (left): left
    # +(0.05, 0.03), right -(0.05, 0.03).
    np.testing.assert_allclose(r, (0.03 - 0.05, -D_Y - 0.02 - 0.03, -D_Z), atol=2e-6)
    np.testing.assert_allclose(lf, (-0.03 + 0.05, D_Y + 0.02 + 0.03, -D_Z), atol=2e-6)
    assert td == pytest.approx(0.2 + 0.54, abs=1e-6)


@pytest.mark.parametrize("t", [0.0, 0.05, 0.15, 0.27, 0.3, 0.42, 0.6, 1.5])
def test_one_step_bit_identical(t):
    """steps = 1: the second-step fields change nothing, bit for bit, and the feet are the
    one-step CPG's (cpg_feet_lateral) exactly."""
    base = StepOverride(x_m=0.1, y_m=0.05, onset_s=0.0)
    other = StepOverride(x_m=0.1, y_m=0.05, onset_s=0.0, steps=1.0, x2_m=-0.07, y2_m=0.09,
                         delay2_s=0.2)
    a, b = _feet(base, t), _feet(other, t)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    # The one-step override's own computation: the period as a float32 array (StepOverride
    # period_s <= 0 selects params.step_period by `where`).
    p_ov = dataclasses.replace(P, step_period=jnp.float32(P.step_period))
    ref = cpg_feet_lateral(jnp.float32(t) - jnp.float32(0.0), jnp.float32(0.1), jnp.float32(0.05),
                           p_ov)
    np.testing.assert_array_equal(a[0], np.asarray(ref[0]))
    np.testing.assert_array_equal(a[1], np.asarray(ref[1]))
    assert a[2] == pytest.approx(0.27, abs=1e-6)


def test_swing_left_argument():
    """cpg_feet_lateral(swing_left=None) is the sign rule; an explicit choice overrides it."""
    t, x, y = jnp.float32(1.0), jnp.float32(0.1), jnp.float32(0.04)
    auto = cpg_feet_lateral(t, x, y, P)
    forced = cpg_feet_lateral(t, x, y, P, swing_left=True)
    np.testing.assert_array_equal(np.asarray(auto[0]), np.asarray(forced[0]))
    r, lf = cpg_feet_lateral(t, x, y, P, swing_left=False)
    np.testing.assert_allclose(np.asarray(r), (0.05, -D_Y + 0.02, -D_Z), atol=1e-6)
    np.testing.assert_allclose(np.asarray(lf), (-0.05, D_Y - 0.02, -D_Z), atol=1e-6)


def test_two_step_override_jits_with_traced_steps():
    """steps is a traced option: one compiled function serves 1 and 2."""
    f = jax.jit(lambda s: override_feet(
        StepOverride(**(TWO | dict(steps=s))), jnp.float32(1.0), jnp.float32(-1e9),
        jnp.zeros(3), jnp.zeros(3), jnp.float32(-1.0), P)[2])
    assert float(f(1.0)) == pytest.approx(0.27, abs=1e-6)
    assert float(f(2.0)) == pytest.approx(0.54, abs=1e-6)


SMALL = {"sweep": {"name": "small", "chunk_size": 8, "duration_s": 2.0, "control": ["on"]},
         "push": {"grid": {"impulse_ns": [0.0, 1.0], "azimuth_deg": [0], "onset_s": [0.3]}},
         "step": {"grid": {"x_m": [-0.06, 0.0, 0.12], "y_m": [0.0, 0.06],
                           "start_delay_s": [0.0]}}}


def test_second_step_spec_keys():
    bad = [("steps", [1.5], r"step.grid.steps: expected 1 or 2"),
           ("steps", [3], r"step.grid.steps\[0\]: 3 is out of range \[1.0, 2.0\]"),
           ("x2_m", [0.5], r"step.grid.x2_m\[0\]: 0.5 is out of range \[-0.3, 0.3\] m"),
           ("y2_m", [-0.4], r"step.grid.y2_m\[0\]: -0.4 is out of range \[-0.3, 0.3\] m"),
           ("delay2_s", [-0.1], r"step.grid.delay2_s\[0\]: -0.1 is out of range \[0.0, 2.0\]")]
    for key, value, match in bad:
        data = copy.deepcopy(SMALL)
        data["step"]["grid"][key] = value
        with pytest.raises(SpecError, match=match):
            parse_spec(data)
    # Old specs: one step, the second-step columns at their defaults, the same count.
    rec = parse_spec(SMALL).records()
    assert len(rec["push_id"]) == 2 * (6 + 1)
    assert (rec["step_steps"] == 1).all() and not rec["step_x2_m"].any()
    ov = step_override(rec)
    assert (np.asarray(ov.steps) == 1).all()
    # One and two steps: each single step once, each pair once, plus the reference.
    data = copy.deepcopy(SMALL)
    data["step"]["grid"] |= {"steps": [1, 2], "x2_m": [0.0, 0.1], "y2_m": [0.0],
                             "delay2_s": [0.0]}
    rec = parse_spec(data).records()
    assert len(rec["push_id"]) == 2 * (1 + 6 + 6 * 2)
    act = rec["step_active"] > 0.5
    assert (rec["step_steps"][act] == 1).sum() == 12 and (rec["step_steps"] == 2).sum() == 24
    assert not rec["step_x2_m"][act & (rec["step_steps"] == 1)].any()
    rec = load_spec("specs/capture/capture2_cpu.toml").records()
    assert len(rec["push_id"]) == 36 * (1 + 25 + 25 * 15)
    assert len(load_spec("specs/capture/capture_region_cpu.toml").records()["push_id"]) == 1952


def test_jn_table_hand_made():
    """Two impulses from one direction: a single step survives at 1.0 only, a pair at 1.0 and
    2.0; the controller's own step at none."""
    j = np.array([1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0])
    rec = dict(impulse_ns=j, azimuth_deg=np.zeros(8), step_active=np.array([0, 1, 1, 1] * 2, float),
               step_steps=np.array([1, 1, 2, 2] * 2, float),
               fell=np.array([1, 0, 1, 0, 1, 1, 1, 0.0]), step_start_delay_s=np.zeros(8),
               step_from_detection=np.zeros(8), step_period_s=np.zeros(8))
    (row,) = jn_table(rec)
    assert row["j1_empirical"] == 1.0 and row["j2_empirical"] == 2.0
    assert row["survivors_1"] == ["1/1", "0/1"] and row["survivors_2"] == ["1/2", "1/2"]
    assert row["controller_max_survived"] == 0.0
    del rec["step_steps"]           # a one-step sweep recorded before the two-step override
    (row,) = jn_table(rec)
    assert row["j2_empirical"] is None and row["j1_empirical"] == 2.0
