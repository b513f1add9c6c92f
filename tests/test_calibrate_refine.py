"""Gradient refinement of the calibration through MJX (tkujax.studies.calibrate.refine).

One paper row (the volleyball from behind, control on: the row whose step length is a
differentiable target) on a 1.5 s horizon, compiled once for the module: the gradient of the
loss against a secant of the same compiled function, and the bounds and validation at the
edges.
"""

import numpy as np
import pytest

from tkujax.model import ModelParams
from tkujax.sim import push as push_lib
from tkujax.sim.rollout_mjx import ProgramOptions, RolloutConfig
from tkujax.studies.calibrate import refine as R

BACK_VOLLEYBALL_ON = 3


@pytest.fixture(scope="module")
def refiner():
    config = RolloutConfig(duration_s=1.5, program=ProgramOptions(remat=True))
    return R.Refiner(config=config, cases=[BACK_VOLLEYBALL_ON])


@pytest.fixture(scope="module")
def at_start(refiner):
    return refiner.value_and_grad(refiner.start())


@pytest.mark.slow
def test_the_row_steps_and_the_loss_is_its_relative_step_error(refiner, at_start):
    val, out, g = at_start
    assert refiner.names == [("back", "volleyball", "on")]
    step = float(out.step_length_m[0])
    assert step > 0.02 and not out.fell[0]
    # The loss is the relative step error (the hinge is 0 for a standing row below 25 deg).
    assert float(out.peak_incl_deg[0]) < R.STAND_MAX_DEG
    assert val == pytest.approx(((step - 0.0415) / 0.0415) ** 2, rel=1e-4)
    assert np.all(np.isfinite(g))


@pytest.mark.slow
def test_impulse_gradient_against_the_secant(refiner, at_start):
    """The step length is a rough function of the parameters (float32 contact dynamics and the
    30 ms detection tick): central differences of the loss in the impulse scale range from
    -0.04 to -0.98 for h = 0.03 % .. 3 % (measured), so no finite difference converges to
    the pathwise gradient. Asserted: the gradient has the sign and the scale of the +-3 %
    secant (a harder push lengthens the too-short step: the loss falls)."""
    _, _, g = at_start
    e = np.array([0.0, 0.0, 0.03, 0.0])
    secant = (refiner.value(refiner.start() + e)[0] - refiner.value(refiner.start() - e)[0]) / 0.06
    print(f"\nimpulse_scale: grad {g[2]:.4f}, +-3 % secant {secant:.4f}")
    assert g[2] < 0 and secant < 0
    assert 1 / 3 < g[2] / secant < 3


def test_bounds_are_the_calibration_bounds_as_scales():
    lo, hi = R.bounds(ModelParams(), push_lib.BallContact())
    assert lo[0] * 16.8 == pytest.approx(8.0) and hi[0] * 16.8 == pytest.approx(32.0)
    assert lo[2] * 1.365 == pytest.approx(0.9) and hi[2] * 1.365 == pytest.approx(1.5)
    assert np.all(lo <= [1, 1, 1, 0]) and np.all([1, 1, 1, 0] <= hi)


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match="iterations must be in"):
        R.refine(tmp_path, iterations=0)
    with pytest.raises(ValueError, match="lr must be in"):
        R.refine(tmp_path, lr=0.0)
    with pytest.raises(ValueError, match="chest_com_dx_m"):
        R.apply(ModelParams(), push_lib.BallContact(),
                dict(leg_kp=16.8, leg_damping=0.868, impulse_factor=1.365, chest_com_dx_m=0.01))
    m, c = R.apply(ModelParams(), push_lib.BallContact(),
                   dict(leg_kp=18.0, leg_damping=0.8, impulse_factor=1.4, chest_com_dx_m=0.0))
    assert m.leg_servo.kp_nm_per_rad == 18.0 and c.impulse_factor == 1.4
