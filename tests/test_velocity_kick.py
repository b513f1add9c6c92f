"""Velocity kicks: MuJoCo Playground's push protocol as a push kind ([push] kind =
"velocity_kick"; tkujax.sim.push.kick_velocity, tkujax.dialects.kick_table).

The kick against its closed form (kick_mps toward the azimuth, in the one physics step at the
onset, summed over a sequence); the spec (kick_mps columns, onsets on the controller's ticks,
refusals naming the key); a kick of 0 is no push at all, bit for bit (MuJoCo C); just after a
kick the CoM moves along the kick's direction, at no more than the kick (the ground only takes
momentum away); a sweep's records equal the direct simulation; MJX against MuJoCo C (slow).
"""

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push, force_at, kick_velocity, make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep

PARAMS = ControllerParams.paper()


def _kicks(kick_mps, azimuth_deg, onset_s) -> Push:
    n = len(kick_mps)
    return Push(jnp.zeros(n), jnp.radians(jnp.asarray(azimuth_deg, jnp.float32)),
                jnp.full(n, 0.36), jnp.full(n, 0.02), jnp.asarray(onset_s, jnp.float32),
                kick_mps=jnp.asarray(kick_mps, jnp.float32))


def test_kick_velocity_closed_form():
    push = Push(jnp.float32(0), jnp.radians(jnp.float32(30.0)), jnp.float32(0.36),
                jnp.float32(0.02), jnp.float32(0.3), kick_mps=jnp.float32(0.8))
    want = 0.8 * np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    np.testing.assert_allclose(kick_velocity(push, jnp.float32(0.3), 0.002), want, rtol=1e-6)
    for t in (0.298, 0.302, 0.5):
        np.testing.assert_array_equal(kick_velocity(push, jnp.float32(t), 0.002), [0.0, 0.0])
    np.testing.assert_array_equal(force_at(push, jnp.float32(0.31)), np.zeros(3))
    seq = Push(jnp.zeros(2), jnp.radians(jnp.array([0.0, 90.0])), jnp.float32(0.36),
               jnp.float32(0.02), jnp.array([0.3, 0.3]), kick_mps=jnp.array([0.5, 0.25]))
    np.testing.assert_allclose(kick_velocity(seq, jnp.float32(0.3), 0.002), [0.5, 0.25],
                               atol=1e-7)


def _spec(push, sweep=None):
    return {"sweep": {"duration_s": 1.5, "control": ["on"]} | (sweep or {}),
            "push": {"kind": "velocity_kick"} | push}


def test_spec_kicks_land_on_ticks_with_kick_columns():
    rec = parse_spec(_spec({"grid": {"kick_mps": [0.2, 0.6], "azimuth_deg": [0, 90],
                                     "onset_s": [0.31]}})).records()
    assert "impulse_ns" not in rec
    np.testing.assert_array_equal(rec["kick_mps"], [0.2, 0.2, 0.6, 0.6])
    np.testing.assert_allclose(rec["onset_s"], 0.33)     # the first tick at or after 0.31 s
    np.testing.assert_allclose(rec["onset_phase"], 0.0, atol=1e-6)
    seq = parse_spec(_spec({"grid": {"kick_mps": [0.2]}, "sequence": {
        "pulses": 2, "interval_s": {"uniform": [0.1, 0.5]}, "kick_mps": {"uniform": [0, 1]}}}))
    rec = seq.records()
    ticks = rec["pulse2_onset_s"] / 0.03
    np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-6)
    assert 0.0 <= rec["pulse2_kick_mps"][0] <= 1.0


def test_walking_kicks_keep_their_gait_phase():
    """A kick placed by gait phase lands on the phase's tick (TKU-X's gait times are ticks:
    0.57 s + k 0.3 s) and records that phase, 0 and not 0.99999 (float32 periods)."""
    rec = parse_spec({"sweep": {"duration_s": 7.0}, "walk": {"speed_mps": 0.1},
                      "push": {"kind": "velocity_kick", "grid": {
                          "kick_mps": [0.3], "gait_phase": [0.0, 0.25, 0.5, 0.75]}}}).records()
    np.testing.assert_allclose(rec["onset_s"], 0.57 + (9 + np.array([0, .25, .5, .75])) * 0.6,
                               atol=1e-6)
    np.testing.assert_allclose(rec["gait_phase"], [0.0, 0.25, 0.5, 0.75], atol=1e-5)


@pytest.mark.parametrize("push, message", [
    ({"kind": "shove"}, r"push\.kind: expected one of \['impulse', 'velocity_kick'\]"),
    ({"grid": {"kick_mps": [5.5]}}, r"push\.grid\.kick_mps\[0\]: 5\.5 is out of range "
                                    r"\[0\.0, 5\.0\] m/s"),
    ({"grid": {"kick_mps": [0.5], "impulse_ns": [1.0]}},
     r"push\.grid: \['impulse_ns'\] do not apply to velocity kicks"),
    ({"random": {"n": 2, "kick_mps": {"uniform": [0.5, 9]}}},
     r"push\.random\.kick_mps\.uniform\[1\]: 9 is out of range \[0\.0, 5\.0\] m/s"),
])
def test_kick_refusals_name_the_key(push, message):
    with pytest.raises(SpecError, match=message):
        parse_spec(_spec(push))
    with pytest.raises(SpecError, match=r"push\.grid\.kick_mps: a velocity kick needs"):
        parse_spec({"push": {"grid": {"kick_mps": [0.5]}}})


def test_kicks_on_mujoco():
    """A kick of 0 is no push at all (bit for bit); 0.2-1 m/s kicks move the CoM along their
    direction at no more than the kick over the next control period."""
    cfg = RolloutConfig(duration_s=0.6)
    none, _ = simulate_mujoco(stack_pushes([make_push(0.0, onset_s=0.3)]), 1.0, PARAMS,
                              config=cfg)
    zero, _ = simulate_mujoco(_kicks([0.0], [0.0], [0.3]), 1.0, PARAMS, config=cfg)
    for k in ("com", "pitch", "pelvis_z"):
        np.testing.assert_array_equal(np.asarray(zero[k]), np.asarray(none[k]))
    kicks = [0.2, 0.5, 1.0, 0.5]
    az = np.radians([0.0, 90.0, 0.0, 225.0])
    s, _ = simulate_mujoco(_kicks(kicks, np.degrees(az), [0.3] * 4), 1.0, PARAMS, config=cfg)
    com = np.asarray(s.com)
    v = (com[:, 10, :2] - com[:, 9, :2]) / 0.03           # the period right after 0.3 s
    along = v[:, 0] * np.cos(az) + v[:, 1] * np.sin(az)
    across = -v[:, 0] * np.sin(az) + v[:, 1] * np.cos(az)
    assert (along > 0.3 * np.array(kicks)).all() and (along <= np.array(kicks)).all()
    assert (np.abs(across) < 0.05 * np.array(kicks)).all()


def test_kick_sweep_records_equal_the_direct_simulation(tmp_path):
    data = _spec({"grid": {"kick_mps": [0.3, 1.2], "azimuth_deg": [0, 180], "onset_s": [0.3]}})
    run_sweep(parse_spec(data), tmp_path / "out", backend="mujoco", quiet=True)
    rec = load(tmp_path / "out")
    _, out = simulate_mujoco(_kicks(rec["kick_mps"], rec["azimuth_deg"], rec["onset_s"]), 1.0,
                             PARAMS, config=RolloutConfig(duration_s=1.5))
    np.testing.assert_array_equal(rec["fell"], out.fell)
    np.testing.assert_allclose(rec["peak_incl_deg"], out.peak_incl_deg, rtol=1e-6)
    assert rec["fell"].any() and not rec["fell"].all()


def test_mujoco_refuses_kicks_off_the_tick_grid():
    with pytest.raises(ValueError, match="onset_s must be multiples of 0.03 s"):
        simulate_mujoco(_kicks([0.5], [0.0], [0.31]), 1.0, PARAMS,
                        config=RolloutConfig(duration_s=0.6))


@pytest.mark.slow
def test_mjx_kicks_match_mujoco():
    """The same kicks on MJX (float32, the kick inside the physics step) and MuJoCo C (the
    kick on the state between periods): the same falls, peak inclination within 1 deg, the CoM
    within 1 cm."""
    from tkujax.sim.rollout_mjx import simulate

    pushes = _kicks([0.0, 0.2, 0.5, 1.0], [0, 0, 90, 0], [0.3] * 4)
    cfg = RolloutConfig(duration_s=1.2)
    s_c, o_c = simulate_mujoco(pushes, 1.0, PARAMS, config=cfg)
    s_j, o_j = simulate(pushes, 1.0, PARAMS, config=cfg)
    np.testing.assert_array_equal(o_j.fell, o_c.fell)
    np.testing.assert_allclose(o_j.peak_incl_deg, o_c.peak_incl_deg, atol=1.0)
    ok = ~np.asarray(o_c.fell)
    np.testing.assert_allclose(np.asarray(s_j.com)[ok], np.asarray(s_c.com)[ok], atol=0.01)
