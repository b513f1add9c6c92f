"""Push sequences: several pulses per rollout ([push.sequence]; tkujax.dialects.sequence_table).

The spec: the later pulses' columns, drawn in their ranges, shared by a push's settings, the
other columns unchanged; refusals naming the key (overlapping pulses, a last pulse past the
horizon, too many pulses). The physics against independent references: a pulse of 0 N·s
adds nothing (a sequence whose second pulse is 0 is the single push, bit for bit), and a
sequence whose first pulse is 0 is the single push at the second's onset (MuJoCo C); the
force of a sequence is the sum of its pulses' closed-form half sines; a sweep's records equal
the direct simulation of the same pulses.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push, first_onset, force_at, make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep

PARAMS = ControllerParams.paper()


def _spec(sequence, grid=None, sweep=None, random=None):
    push = {"grid": grid or {"impulse_ns": [0.5, 1.0], "onset_s": [0.3]}, "sequence": sequence}
    if random is not None:
        push["random"] = random
    return {"sweep": {"duration_s": 3.0, "control": ["off", "on"]} | (sweep or {}), "push": push}


def test_later_pulses_are_drawn_in_range_and_shared_by_the_settings():
    seq = {"pulses": 3, "interval_s": {"uniform": [0.5, 1.0]},
           "azimuth_deg": {"uniform": [0, 360]}, "impulse_ns": 0.7}
    rec = parse_spec(_spec(seq, random={"n": 5})).records()
    plain = parse_spec(_spec({"pulses": 1, "interval_s": 0.5}, random={"n": 5})).records()
    for k, v in plain.items():     # the other columns keep their values
        np.testing.assert_array_equal(rec[k], v)
    n = len(rec["push_id"]) // 2   # control off, on: the same pulses
    gap2 = rec["pulse2_onset_s"] - rec["onset_s"]
    gap3 = rec["pulse3_onset_s"] - rec["pulse2_onset_s"]
    assert ((gap2 >= 0.5 - 1e-6) & (gap2 <= 1.0 + 1e-6)).all()
    assert ((gap3 >= 0.5 - 1e-6) & (gap3 <= 1.0 + 1e-6)).all()
    for k in ("pulse2_onset_s", "pulse3_azimuth_deg"):
        np.testing.assert_array_equal(rec[k][:n], rec[k][n:])
    np.testing.assert_array_equal(rec["pulse2_impulse_ns"], 0.7)
    assert len(np.unique(rec["pulse2_azimuth_deg"][:n])) == n


def test_later_pulses_default_to_the_first_pulse():
    rec = parse_spec(_spec({"pulses": 2, "interval_s": 1.0})).records()
    np.testing.assert_allclose(rec["pulse2_onset_s"], rec["onset_s"] + 1.0)
    np.testing.assert_array_equal(rec["pulse2_impulse_ns"], rec["impulse_ns"])
    np.testing.assert_array_equal(rec["pulse2_azimuth_deg"], rec["azimuth_deg"])


@pytest.mark.parametrize("sequence, message", [
    ({"pulses": 9, "interval_s": 1.0}, r"push\.sequence\.pulses: expected an integer in \[1, 8\]"),
    ({"pulses": 2, "interval_s": 0.01}, r"push\.sequence\.interval_s: 0\.01 s is shorter than "
                                        r"the pulse duration"),
    ({"pulses": 4, "interval_s": {"uniform": [0.5, 1.0]}},
     r"\(push\.sequence\.pulses - 1\) x push\.sequence\.interval_s .*after the horizon"),
    ({"pulses": 2}, r"\[push\.sequence\]: give pulses"),
    ({"pulses": 2, "interval_s": 1.0, "impulse_ns": {"uniform": [0, 300]}},
     r"push\.sequence\.impulse_ns\.uniform\[1\]: 300 is out of range \[0\.0, 200\.0\] N·s"),
    ({"pulses": 2, "interval_s": 1.0, "spin": 1}, r"\[push\.sequence\]: unknown key"),
])
def test_refusals_name_the_key(sequence, message):
    with pytest.raises(SpecError, match=message):
        parse_spec(_spec(sequence))


def test_sequence_refuses_commanded_steps_and_early_decisions():
    with pytest.raises(SpecError, match=r"\[push\.sequence\]: a push sequence runs"):
        parse_spec(_spec({"pulses": 2, "interval_s": 1.0}, sweep={"decisions": "early"}))


def test_force_of_a_sequence_is_the_sum_of_its_half_sines():
    """Closed form: F(t) = sum_k J_k pi / (2 tau) sin(pi (t - t_k) / tau) on each pulse."""
    push = Push(jnp.array([1.0, 0.5]), jnp.radians(jnp.array([0.0, 90.0])), jnp.float32(0.36),
                jnp.float32(0.02), jnp.array([0.3, 0.31]))
    for t in (0.305, 0.315, 0.325, 0.5):
        f = np.asarray(force_at(push, jnp.float32(t)))
        want = np.zeros(3)
        for j, az, t0 in ((1.0, 0.0, 0.3), (0.5, 90.0, 0.31)):
            ph = (t - t0) / 0.02
            if 0 <= ph < 1:
                want[:2] += j * np.pi / 0.04 * np.sin(np.pi * ph) * np.array(
                    [np.cos(np.radians(az)), np.sin(np.radians(az))])
        np.testing.assert_allclose(f, want, rtol=1e-5, atol=1e-4)
    assert float(first_onset(push)) == pytest.approx(0.3)


def test_zero_pulses_add_nothing_on_mujoco():
    """[J at t1, 0 at t2] is the single push at t1, and [0 at t1, J at t2] the single push at
    t2, in every simulated series (MuJoCo C, bit for bit); a second push changes the walk of
    one that holds it alone."""
    cfg = RolloutConfig(duration_s=1.5)
    single = [make_push(1.0, 0.0, onset_s=0.3), make_push(1.0, 0.0, onset_s=0.9)]
    seq = [Push(jnp.array([1.0, 0.0]), jnp.zeros(2), jnp.float32(0.36), jnp.float32(0.02),
                jnp.array([0.3, 0.9])),
           Push(jnp.array([0.0, 1.0]), jnp.zeros(2), jnp.float32(0.36), jnp.float32(0.02),
                jnp.array([0.3, 0.9])),
           Push(jnp.array([1.0, 1.0]), jnp.zeros(2), jnp.float32(0.36), jnp.float32(0.02),
                jnp.array([0.3, 0.9]))]
    s_single, _ = simulate_mujoco(stack_pushes(single), 1.0, PARAMS, config=cfg)
    s_seq, _ = simulate_mujoco(stack_pushes(seq), 1.0, PARAMS, config=cfg)
    for k in ("pelvis_z", "pitch", "roll", "com", "l_ankle"):
        np.testing.assert_array_equal(np.asarray(s_seq[k])[:2], np.asarray(s_single[k]))
    assert not np.array_equal(np.asarray(s_seq["com"])[2], np.asarray(s_single["com"])[0])


def test_sweep_records_equal_the_direct_simulation(tmp_path):
    data = _spec({"pulses": 2, "interval_s": {"uniform": [0.4, 0.8]},
                  "azimuth_deg": {"uniform": [0, 360]}},
                 grid={"impulse_ns": [0.6, 1.2], "onset_s": [0.3]},
                 sweep={"duration_s": 1.8, "control": ["on"]})
    run_sweep(parse_spec(data), tmp_path / "out", backend="mujoco", quiet=True)
    rec = load(tmp_path / "out")
    pushes = [Push(jnp.array([rec["impulse_ns"][i], rec["pulse2_impulse_ns"][i]], jnp.float32),
                   jnp.radians(jnp.array([rec["azimuth_deg"][i], rec["pulse2_azimuth_deg"][i]],
                                         jnp.float32)),
                   jnp.float32(0.36), jnp.float32(0.02),
                   jnp.array([rec["onset_s"][i], rec["pulse2_onset_s"][i]], jnp.float32))
              for i in range(len(rec["push_id"]))]
    _, out = simulate_mujoco(stack_pushes(pushes), 1.0, PARAMS,
                             config=RolloutConfig(duration_s=1.8))
    np.testing.assert_array_equal(rec["fell"], out.fell)
    np.testing.assert_allclose(rec["peak_incl_deg"], out.peak_incl_deg, rtol=1e-6)


@pytest.mark.slow
def test_mjx_sweep_of_walking_kick_sequences_on_a_slope_matches_mujoco(tmp_path):
    """Every new spec part in one MJX sweep program (a walk, a sequence of two velocity kicks,
    a 3 deg uphill) against the same sweep on MuJoCo C: the same falls, the distance walked by
    the robots that stood within 1 cm."""
    data = {"sweep": {"duration_s": 2.4, "chunk_size": 4, "floor_pitch_deg": 3.0},
            "walk": {"speed_mps": 0.1, "recovery": "on", "push_cycle": 0},
            "push": {"kind": "velocity_kick",
                     "grid": {"kick_mps": [0.1, 0.6], "azimuth_deg": [0, 90],
                              "gait_phase": [0.25]},
                     "sequence": {"pulses": 2, "interval_s": {"uniform": [0.5, 1.0]},
                                  "kick_mps": {"uniform": [0.1, 0.4]}}}}
    out = {}
    for backend in ("mujoco", "mjx"):
        run_sweep(parse_spec(data), tmp_path / backend, backend=backend, quiet=True)
        out[backend] = load(tmp_path / backend)
    np.testing.assert_array_equal(out["mjx"]["pulse2_onset_s"], out["mujoco"]["pulse2_onset_s"])
    np.testing.assert_array_equal(out["mjx"]["fell"], out["mujoco"]["fell"])
    stood = ~out["mujoco"]["fell"].astype(bool)       # a fall's distance ends where it is seen
    assert stood.any()
    np.testing.assert_allclose(out["mjx"]["distance_m"][stood], out["mujoco"]["distance_m"][stood],
                               atol=0.01)
