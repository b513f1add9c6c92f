"""FPGA-faithful fixed-point twin of the balance controller.

Pure JAX integer arithmetic (int32 words, jit/vmap-able, independent of jax's x64 flag):
  config.py            FixedPointConfig: Q formats per signal group, CORDIC, rounding, latency
  qformat.py           QFormat and the saturating / rounding word arithmetic
  cordic.py            CORDIC sin/cos, atan2 (+ magnitude), sqrt (hyperbolic), acos
  coefficients.py      ControllerParams -> coefficient registers
  kalman_fx.py, capture_point_fx.py, cpg_fx.py, ik_fx.py    the four modules
  controller_fx.py     controller_step_fx: drop-in twin of controller.controller_step
  support.py           check_supported: refuse ControllerParams options the twin lacks
"""

from tkujax.control.fixed.capture_point_fx import capture_point_fx, step_length_fx
from tkujax.control.fixed.coefficients import Coefficients, coef_format, coefficients
from tkujax.control.fixed.config import FixedPointConfig, servo_switch_substep
from tkujax.control.fixed.controller_fx import (FixedControllerOutput, FixedControllerState,
                                                controller_init_fx, controller_step_fx,
                                                servo_command, stand_leg_targets_fx)
from tkujax.control.fixed.cordic import CordicSpec
from tkujax.control.fixed.cpg_fx import cpg_feet_fx
from tkujax.control.fixed.ik_fx import leg_ik_fx, solve_legs_fx
from tkujax.control.fixed.kalman_fx import accel_to_angle_fx, kalman_step_fx
from tkujax.control.fixed.qformat import QFormat, quantize, straight_through, to_float
from tkujax.control.fixed.support import IMPLEMENTED_FIELDS, check_supported, unsupported

__all__ = [
    "Coefficients", "CordicSpec", "IMPLEMENTED_FIELDS", "check_supported", "unsupported",
    "FixedControllerOutput", "FixedControllerState",
    "FixedPointConfig", "QFormat", "accel_to_angle_fx", "capture_point_fx", "coef_format",
    "coefficients", "controller_init_fx", "controller_step_fx", "cpg_feet_fx", "kalman_step_fx",
    "leg_ik_fx", "quantize", "servo_command", "servo_switch_substep", "solve_legs_fx",
    "stand_leg_targets_fx", "step_length_fx", "straight_through", "to_float",
]
