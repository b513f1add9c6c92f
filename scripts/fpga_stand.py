"""FPGA twin diagnostic: the stand pose's leg commands, float against fixed point, with and
without `ik_guard_bits` (the 0.207 -> 0.037 mrad of results/fpga/README.md, section 1)."""

import numpy as np
import jax.numpy as jnp
from tkujax.control.controller_params import ControllerParams
from tkujax.control.controller import stand_leg_targets
from tkujax.control.fixed import FixedPointConfig, stand_leg_targets_fx, to_float, QFormat


def main() -> None:
    p = ControllerParams.paper()
    f = np.asarray(stand_leg_targets(p), np.float64)


    def err(**kw):
        cfg = FixedPointConfig(straight_through=False, **kw)
        x = np.asarray(to_float(stand_leg_targets_fx(p, cfg), cfg.angle, jnp.float32))
        return np.round(1e3 * (x - f)[2:6], 4)


    for kw in [
        dict(),
        dict(cordic_guard_bits=3),
        dict(cordic_guard_bits=0),
        dict(cordic_iterations=12),
        dict(unit=QFormat(2, 21)),
        dict(angle=QFormat(2, 21)),
        dict(length=QFormat(0, 23)),
        dict(coef_bits=24),
        dict(rounding="truncate"),
        dict(unit=QFormat(2, 21), angle=QFormat(2, 21), length=QFormat(0, 23)),
    ]:
        print(kw, err(**kw))


if __name__ == "__main__":
    main()
