"""A robot file's gait defaults, read from its settled stand (`Robot.gait`, under the robot
file's [walk] table, which overrides them).

The CPG gait (`tkujax.control.gait`) was written for TKU-X, whose stand carries its CoM over the
middle of its feet and whose 3 cm lift (H_Sup) is a small share of its leg. Scaled to a heavy
humanoid on PD servos it falls at every speed (docs/walking.md). Two defaults make it walk:

- com_shift_m: the waist moves forward by half of (front margin - back margin) of the stand's
  CoM in its support polygon (`tkujax.robot.support.com_margins`), so the CoM walks over the
  polygon's middle. Booster T1 stands with its CoM 2.4 cm ahead of it and falls forward walking
  at 0.05 m/s; the Berkeley Humanoid stands 5.4 cm behind it and falls backward in place. Rounded
  to 0.1 mm: the settled stand differs in its last bits from one machine to another.
- lift_m: at most WALK_LIFT_MAX_M, the paper's H_Sup. The controller's lift scales with the
  leg (T1: 7.0 cm); lifted that high, a heavy robot tips over the lifted foot (T1 falls at
  1.6 s; at 3.5 cm T1 falls at 0.1 m/s and the Berkeley Humanoid in place; at 3 cm both step
  20 s; docs/walking.md). A scaled lift within LIFT_TOL_M of it is kept (OP3's, 3.002 cm).

Both give way to the robot file's [walk] keys (OP3's file keeps the stand's CoM: its walking
maps were measured so).
"""

from __future__ import annotations

from tkujax.control.controller_params import ControllerParams
from tkujax.control.gait import WALK_LIMITS

WALK_LIFT_MAX_M = 0.03      # the paper's H_Sup (Table 2)
LIFT_TOL_M = 1e-4           # a scaled lift this close to the cap is at it


def walk_defaults(margins: dict | None, scaled: ControllerParams) -> tuple[tuple[str, float], ...]:
    """(WalkCommand field, value) pairs of the robot's gait defaults (module doc) from its
    stand's CoM margins (`com_margins`; None: no polygon, no shift) and its scaled controller
    defaults."""
    out = []
    if float(scaled.lift_height) > WALK_LIFT_MAX_M + LIFT_TOL_M:
        out.append(("lift_m", WALK_LIFT_MAX_M))
    if margins is not None:
        lo, hi = WALK_LIMITS["com_shift_m"]
        shift = 0.5 * (float(margins["front_m"]) - float(margins["back_m"]))
        out.append(("com_shift_m", round(min(max(shift, lo), hi), 4)))
    return tuple(out)
