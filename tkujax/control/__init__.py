"""The paper's balance controller (Sec. 3) as pure JAX functions, one module per stage.

kalman (Eq. 1-2) -> capture_point (Eq. 5-10, Algorithm 1) -> cpg (Eq. 11-18, Table 2) ->
ik / solve (Eq. 19-28), composed by controller.controller_step.
"""

from tkujax.control.capture_point import capture_point, push_detected, push_gate, push_recovery
from tkujax.control.controller import (ControllerState, Sensors, StepOverride, controller_init,
                                       controller_step,
                                       stand_leg_targets)
from tkujax.control.cpg import cpg_feet, cpg_feet_lateral
from tkujax.control.ik import leg_ik
from tkujax.control.kalman import KalmanState, accel_to_angle, kalman_init, kalman_step
from tkujax.control.controller_params import ControllerParams
from tkujax.control.solve import solve_legs

__all__ = [
    "ControllerParams", "ControllerState", "KalmanState", "Sensors", "accel_to_angle",
    "StepOverride", "capture_point", "controller_init", "controller_step", "cpg_feet",
    "cpg_feet_lateral",
    "kalman_init", "kalman_step", "leg_ik", "push_detected", "push_gate", "push_recovery",
    "solve_legs", "stand_leg_targets",
]
