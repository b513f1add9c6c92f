"""The two recovery readings of tkujax.sim.metrics.outcomes on hand-made series.

recovery_time_s reads hypot(d pitch, d roll); recovery_time_pitch_s reads |d pitch| alone (the
paper's phi). The expected times are written out by hand from the series below (control period
30 ms, samples at t = 0.03 k, onset 0.30 s, band 1 deg): the first sample after the last one
outside the band, minus the onset.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.sim import metrics
from tkujax.sim.records import OUTCOME_FIELDS, Series

N = 60                                   # t = 0.03 .. 1.80 s
T = np.round(np.arange(1, N + 1) * 0.03, 6)
ONSET = 0.30
STAND_DEG = 7.0


def _series(pitch_dev_deg, roll_deg, pelvis_z=None) -> Series:
    cols = dict(t=T, pitch=np.radians(STAND_DEG + np.asarray(pitch_dev_deg, float)),
                roll=np.radians(np.asarray(roll_deg, float)), pitch_est=np.zeros(N),
                roll_est=np.zeros(N), zmp=np.zeros((N, 2)), fsr_total=np.full(N, 44.0),
                com=np.tile([0.0, 0.0, 0.25], (N, 1)), r_ankle=np.zeros((N, 3)),
                l_ankle=np.zeros((N, 3)),
                pelvis_z=np.full(N, 0.3) if pelvis_z is None else pelvis_z,
                lowest_body_z=np.full(N, 0.1), gate=np.zeros(N), x_sup=np.zeros(N),
                y_sup=np.zeros(N), step_weight=np.zeros(N), reachable=np.ones(N))
    return Series(**{k: jnp.asarray(v, jnp.float32) for k, v in cols.items()})


def _between(lo, hi, value):
    """value on the samples with lo < t <= hi, 0 elsewhere."""
    return np.where((T > lo + 1e-9) & (T <= hi + 1e-9), value, 0.0)


# pitch: 3 deg off from t = 0.33 to 0.60 s, then 0.2 deg (inside the band) to the end.
PITCH = _between(ONSET, 0.60, 3.0) + _between(0.60, 1.80, 0.2)
PITCH_BACK_S = 0.63 - ONSET              # first sample inside after the last outside (0.60)


def test_roll_offset_persists_hypot_not_settled_pitch_settled():
    # a 2.3 deg roll offset from 0.45 s to the end (the step landed off the line)
    o = metrics.outcomes(_series(PITCH, _between(0.45, 1.80, 2.3)), ONSET)
    assert not bool(o.fell)
    assert math.isnan(float(o.recovery_time_s))
    assert float(o.recovery_time_pitch_s) == pytest.approx(PITCH_BACK_S, abs=1e-5)


def test_roll_returns_later_both_settle_at_their_own_time():
    # roll 1.5 deg from 0.45 s to 0.90 s: hypot is outside until 0.90, back at 0.93 s
    o = metrics.outcomes(_series(PITCH, _between(0.45, 0.90, 1.5)), ONSET)
    assert float(o.recovery_time_s) == pytest.approx(0.93 - ONSET, abs=1e-5)
    assert float(o.recovery_time_pitch_s) == pytest.approx(PITCH_BACK_S, abs=1e-5)


def test_small_roll_inside_band_with_pitch_readings_agree():
    # roll 0.5 deg: hypot(0.2, 0.5) < 1 after 0.60 s, hypot(3, 0.5) > 1 before: same time
    o = metrics.outcomes(_series(PITCH, _between(0.45, 1.80, 0.5)), ONSET)
    assert float(o.recovery_time_s) == pytest.approx(PITCH_BACK_S, abs=1e-5)
    assert float(o.recovery_time_pitch_s) == pytest.approx(PITCH_BACK_S, abs=1e-5)


def test_pure_roll_push_pitch_reading_zero():
    # a sideways push: roll leaves the band (0.33-0.51 s), pitch never does
    o = metrics.outcomes(_series(np.zeros(N), _between(ONSET, 0.51, 4.0)), ONSET)
    assert float(o.recovery_time_s) == pytest.approx(0.54 - ONSET, abs=1e-5)
    assert float(o.recovery_time_pitch_s) == 0.0


def test_fall_makes_both_nan():
    z = np.where(T > 1.2, 0.05, 0.3)      # the pelvis drops below 0.12 m
    o = metrics.outcomes(_series(PITCH, np.zeros(N), pelvis_z=z), ONSET)
    assert bool(o.fell)
    assert math.isnan(float(o.recovery_time_s)) and math.isnan(float(o.recovery_time_pitch_s))


def test_still_outside_at_end_pitch_nan():
    o = metrics.outcomes(_series(_between(ONSET, 1.80, 2.0), np.zeros(N)), ONSET)
    assert math.isnan(float(o.recovery_time_pitch_s)) and math.isnan(float(o.recovery_time_s))


def test_field_is_an_outcome_column_and_vmaps():
    assert "recovery_time_pitch_s" in OUTCOME_FIELDS
    a = _series(PITCH, _between(0.45, 1.80, 2.3))
    b = _series(PITCH, _between(0.45, 0.90, 1.5))
    both = jax.tree_util.tree_map(lambda x, y: jnp.stack([x, y]), a, b)
    o = jax.jit(jax.vmap(metrics.outcomes))(both, jnp.full(2, ONSET, jnp.float32))
    assert math.isnan(float(o.recovery_time_s[0]))
    np.testing.assert_allclose(np.asarray(o.recovery_time_pitch_s), PITCH_BACK_S, atol=1e-5)
