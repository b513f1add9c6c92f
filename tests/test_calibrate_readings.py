"""The Algorithm-1 readings added for the calibration (ControllerParams.cp_excess,
cp_update_window), the calibration parameter mapping and the loss: no physics."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.calibrate import targets as T
from tkujax.control.capture_point import capture_point
from tkujax.control.controller import Sensors, controller_init, controller_step, cp_angle
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams

G = 9.81


def _tilted(phi_deg: float) -> Sensors:
    """IMU of a robot at rest tilted by phi (pitch, rad): gravity only, gyro 0."""
    # the inverse of kalman.accel_to_angle's convention, found numerically below
    phi = math.radians(phi_deg)
    return Sensors(jnp.zeros(3), jnp.array([-G * math.sin(phi), 0.0, G * math.cos(phi)]))


def test_cp_angle_readings():
    p = ControllerParams.paper()
    phi = jnp.radians(jnp.array([14.0, 8.0, -5.0]))
    dev = cp_angle(phi, p)
    np.testing.assert_allclose(np.degrees(dev), [7.0, 1.0, -12.0], atol=1e-5)
    ex = cp_angle(phi, dataclasses.replace(p, cp_excess=1.0))
    np.testing.assert_allclose(np.degrees(ex), [2.0, -4.0, -3.0], atol=1e-5)


@pytest.mark.parametrize("window,expect_update", [(0.0, False), (0.03, True)])
def test_update_window(window, expect_update):
    """Angle 13 deg at the detection, 16 deg one period later: latched keeps the first x_Sup,
    updated-until-swing takes the second (then holds it)."""
    p = dataclasses.replace(ControllerParams.paper(), kalman_q=1.0, kalman_r=1e-9,
                            cp_excess=1.0, cp_update_window=window)
    from tkujax.control import kalman
    sign = 1.0 if float(kalman.accel_to_angle(_tilted(10.0).accel)[0]) > 0 else -1.0
    s = controller_init(p)
    xs = []
    for deg in (7.0, 13.0, 16.0, 17.0, 18.0):
        s, _ = controller_step(s, _tilted(sign * deg), p)
        xs.append(float(s.x_sup_m))
    cp = lambda a: float(capture_point(jnp.radians(a), p.leg_length, p.com_height, G))  # noqa: E731
    assert xs[0] == 0.0
    np.testing.assert_allclose(xs[1], cp(1.0), rtol=1e-3)
    np.testing.assert_allclose(xs[-1], cp(4.0) if expect_update else cp(1.0), rtol=1e-3)


def test_default_reading_unchanged():
    p = ControllerParams()
    assert p.cp_excess == 0.0 and p.cp_update_window == 0.0


def test_param_mapping_hard_constraints():
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = P.from_unit(rng.uniform(0, 1, len(P.NAMES)))
        m = P.model_params(x)
        parts = (m.pelvis_mass_kg + m.chest_mass_kg + m.head_mass_kg + 2 * m.arm_mass_kg
                 + 2 * m.leg_mass_kg)
        assert abs(parts - 4.5) < 1e-6 and m.pelvis_mass_kg >= 0.2
        assert abs(m.height_m - 0.5645) < 1e-6
        assert m.leg_servo.stall_torque_nm == 6.0
    d = P.model_params(P.DEFAULT)
    # DEFAULT is the pre-calibration estimate, the search's documented start.
    estimated = ModelParams.estimated().leg_servo.damping_nms_per_rad
    assert abs(d.leg_servo.damping_nms_per_rad - estimated) < 1e-3


def test_loss_zero_at_paper_values():
    res = {}
    for k, (rec, step) in T.PAPER_TABLE.items():
        res[k] = dict(fell=rec is None, rec=math.nan if rec is None else rec,
                      step_cm=0.0 if step is None else (step if k[0] == "back" else -step),
                      peak_deg=50.0, phi_peak_deg=1.0)
    loss, _ = T.table_loss(res)
    assert loss == pytest.approx(0.0)
    assert T.score(res) == dict(falls="8/8", steps="4/4", recoveries="3/3", on_faster="3/3")
