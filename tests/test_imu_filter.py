"""The IMU's first-order low-pass (ModelParams.accel_lowpass_hz, gyro_lowpass_hz).

References: the closed-form step response of the recursion; MJX against MuJoCo C with the
filter on; and the behaviour it models: without a filter, the 30 ms IMU sample catches the
20 ms ball pulse at some hit phases and not at others (results/calibration/imu_bandwidth).
"""

import dataclasses
import math

import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim import push as push_lib
from tkujax.sim import rollout_mjx as sim
from tkujax.sim.rollout_mujoco import _ImuFilter, simulate_mujoco
from tkujax.sim.setup import model_index

FILTERED = ModelParams(accel_lowpass_hz=20.0, gyro_lowpass_hz=40.0)


def test_alpha_is_the_exact_rc_discretisation():
    m = ModelParams(accel_lowpass_hz=20.0)
    assert m.imu_lowpass_alpha("accel") == pytest.approx(1 - math.exp(-2 * math.pi * 20 * 0.002))
    assert m.imu_lowpass_alpha("gyro") == 0.0          # off
    idx = model_index(FILTERED)
    assert idx.accel_alpha == pytest.approx(FILTERED.imu_lowpass_alpha("accel"))
    assert idx.gyro_alpha == pytest.approx(FILTERED.imu_lowpass_alpha("gyro"))
    # The default robot filters its accelerometer (7.5 Hz) and not its gyro.
    assert model_index(None).accel_alpha == pytest.approx(ModelParams().imu_lowpass_alpha("accel"))
    assert model_index(None).accel_alpha > 0.0 and model_index(None).gyro_alpha == 0.0
    unfiltered = model_index(ModelParams(accel_lowpass_hz=0.0))
    assert unfiltered.accel_alpha == 0.0 and unfiltered.gyro_alpha == 0.0


@pytest.mark.parametrize("field, value", [("accel_lowpass_hz", 0.5), ("accel_lowpass_hz", -1.0),
                                          ("gyro_lowpass_hz", 300.0),   # > 250 Hz Nyquist
                                          ("gyro_lowpass_hz", float("nan"))])
def test_bad_cutoffs_rejected_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(ModelParams(), **{field: value}).validate()
    with pytest.raises(ValueError, match=field):
        ModelParams.from_overrides([f"{field}={value}"])


def test_filter_recursion_step_response():
    """A constant input x for k steps from y0: y_k = x + (y0 - x)(1 - alpha)^k."""
    idx = model_index(FILTERED)
    n, nsens = 3, 2 + max(idx.gyro_adr, idx.accel_adr) + 3
    y0 = np.zeros((n, nsens))
    f = _ImuFilter(idx, y0)
    steps = np.zeros((n, 15, nsens))
    steps[:, :, idx.accel_adr:idx.accel_adr + 3] = [1.0, -2.0, 9.81]
    steps[:, :, idx.gyro_adr:idx.gyro_adr + 3] = 0.5
    f.advance(steps)
    f.advance(steps)
    for alpha, got, x in ((idx.accel_alpha, f.accel, np.array([1.0, -2.0, 9.81])),
                          (idx.gyro_alpha, f.gyro, np.full(3, 0.5))):
        np.testing.assert_allclose(got, np.broadcast_to(x * (1 - (1 - alpha) ** 30), (n, 3)),
                                   rtol=1e-12)
    unfiltered = _ImuFilter(model_index(ModelParams(accel_lowpass_hz=0.0)), y0)
    unfiltered.advance(steps)
    np.testing.assert_array_equal(unfiltered.accel, steps[:, -1, idx.accel_adr:idx.accel_adr + 3])


def _phase_pushes(n_phases: int, impulse_ns: float, azimuth_deg: float):
    contact = push_lib.BallContact()
    return push_lib.stack_pushes([
        push_lib.make_push(impulse_ns, azimuth_deg, height_m=contact.height_m,
                           onset_s=float(push_lib.onset_from_phase(push_lib.PAPER_ONSET_S,
                                                                   k / n_phases)))
        for k in range(n_phases)])


def test_filter_removes_the_pulse_aliasing():
    """Front baseball, control off, 15 hit phases. Unfiltered, the Kalman angle's peak forward
    of the stand lean depends on whether a 30 ms sample lands in the 20 ms pulse (a backward
    push read as a forward tilt: the accelerometer's linear acceleration); a 10 Hz filter
    spreads every pulse over the next samples alike."""
    contact = push_lib.BallContact()
    pushes = _phase_pushes(15, contact.impulse_ns("baseball"), 180.0)
    params = ControllerParams.paper()
    spread = {}
    for hz in (0.0, 10.0):
        mp = ModelParams(accel_lowpass_hz=hz)
        s, o = simulate_mujoco(pushes, np.zeros(15, np.float32), params, model_params=mp)
        assert not o["fell"].any()
        after = s["t"][0] > push_lib.PAPER_ONSET_S
        peak = np.degrees(s["pitch_est"][:, after].max(axis=1))
        spread[hz] = float(peak.max() - peak.min())
    print(f"\nforward peak of the Kalman angle, spread over 15 phases: {spread[0.0]:.2f} deg "
          f"unfiltered, {spread[10.0]:.2f} deg at 10 Hz")
    assert spread[0.0] > 3.0                      # the aliasing (7 deg in the committed study)
    assert spread[10.0] < 0.3 * spread[0.0]


@pytest.mark.slow
def test_filtered_imu_mjx_agrees_with_c():
    """The same filter on both backends: Kalman angles and outcomes agree (float32 MJX vs
    float64 C, as tests/test_backend_mujoco.py for the unfiltered robot)."""
    contact = push_lib.BallContact()
    vb = contact.impulse_ns("volleyball")
    pushes = push_lib.stack_pushes([
        push_lib.make_push(vb, az, height_m=contact.height_m,
                           onset_s=float(push_lib.onset_from_phase(push_lib.PAPER_ONSET_S, ph)))
        for az in (0.0, 180.0) for ph in (0.0, 0.6)])
    enabled = np.array([1.0, 1.0, 1.0, 0.0], np.float32)
    params = ControllerParams.paper(FILTERED)
    sm, om = sim.simulate(pushes, enabled, params, model_params=FILTERED)
    sc, oc = simulate_mujoco(pushes, enabled, params, model_params=FILTERED)
    before_step = sm["t"][0] < push_lib.PAPER_ONSET_S + 0.12
    np.testing.assert_allclose(np.degrees(sm["pitch_est"][:, before_step]),
                               np.degrees(sc["pitch_est"][:, before_step]), atol=0.3)
    np.testing.assert_array_equal(om["fell"], oc["fell"])
    np.testing.assert_allclose(om["step_length_m"], oc["step_length_m"], atol=0.005)
