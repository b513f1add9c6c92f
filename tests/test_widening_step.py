"""The sideways step's gain (ControllerParams.cp_gain_lateral): at its default the first step
is the one toward the capture point, unchanged; negative, the foot on the push's side steps
outward (the widening step) and the other foot's later step is sagittal only.

No physics: a synthetic IMU reading a steady sideways fall toward +y drives `controller_step`
(the closed loop on OP3: results/op3/README.md)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.capture_point import capture_point_rate
from tkujax.control.controller import Sensors, controller_init, controller_step, detect_push
from tkujax.control.controller_params import ControllerParams

G = 9.81


@pytest.fixture(scope="module")
def lateral() -> ControllerParams:
    return dataclasses.replace(ControllerParams.paper(), lateral_steps=1.0, cp_trigger=1.0,
                               cp_rate_blend=1.0, max_steps=2.0, cp_trigger_lateral_m=0.05)


@pytest.fixture(scope="module")
def step_fn():
    return jax.jit(controller_step)


def _falling_left(step_fn, params, n_periods, rate=1.5):
    """States of a robot whose roll reads a steady fall toward +y (psi > 0: roll < 0)."""
    state = controller_init(params)
    lean = params.standing_lean
    states = []
    for k in range(n_periods):
        roll = -0.02 * k
        accel = jnp.array([-G * math.sin(lean), G * math.sin(roll), G * math.cos(roll)],
                          jnp.float32)
        state, _ = step_fn(state, Sensors(jnp.array([-rate, 0.0, 0.0], jnp.float32), accel),
                           params)
        states.append(state)
    return states


def test_default_gain_is_the_step_toward_the_capture_point(lateral):
    assert ControllerParams().cp_gain_lateral == 1.0
    psi, rate = jnp.float32(0.05), jnp.float32(0.9)
    det = detect_push(jnp.float32(lateral.standing_lean), psi, jnp.float32(0.0), rate, lateral)
    want = lateral.cp_gain * capture_point_rate(psi, rate, lateral)
    assert float(det.y_new) == float(want) and float(want) > 0.0


def test_negative_gain_widens_with_the_push_side_foot(lateral, step_fn):
    n = int(round(2 * lateral.step_period / lateral.control_period)) + 6
    toward = _falling_left(step_fn, lateral, n)
    widen = _falling_left(step_fn, dataclasses.replace(lateral, cp_gain_lateral=-0.5), n)
    # Toward the capture point: the left (falling-side) foot swings out to +y.
    first = toward[0].steps
    assert float(first.swing_left) == 1.0 and float(toward[0].y_sup_m) > 0.0
    # Widening: the first detection is the same, y_Sup is -0.5 of it, the right foot swings
    # outward (-y) and the left (support) foot moves toward +y under the waist.
    assert float(widen[0].y_sup_m) == pytest.approx(-0.5 * float(toward[0].y_sup_m), rel=1e-6)
    w = widen[0].steps
    y_sup = float(widen[0].y_sup_m)
    assert float(w.swing_left) == 0.0
    np.testing.assert_allclose(np.asarray(w.feet_to)[[1, 3]], [y_sup / 2, -y_sup / 2], atol=1e-7)
    # The second step (the left foot, as the fall goes on): its sideways part moves a foot
    # outward only, and the widening gain points inward for the left foot, so it is sagittal:
    # both feet end under the hips again (y = 0; no pitch here, so x stays ~0).
    counts = [float(s.steps.count) for s in widen]
    assert max(counts) == 2.0
    second = widen[counts.index(2.0)].steps
    to = np.asarray(second.feet_to)
    assert float(second.swing_left) == 1.0 and abs(to[2]) < 1e-3
    np.testing.assert_array_equal(to[[1, 3]], [0.0, 0.0])
    # With the default gain the second step (the right foot) is sagittal too: outward only.
    k2 = [float(s.steps.count) for s in toward].index(2.0)
    np.testing.assert_array_equal(np.asarray(toward[k2].steps.feet_to)[[1, 3]], [0.0, 0.0])


@pytest.mark.parametrize("value", [-3.5, 3.5, math.nan])
def test_validate_names_the_gain_and_its_range(value):
    with pytest.raises(ValueError, match=r"ControllerParams\.cp_gain_lateral must be in \[-3, 3\]"):
        dataclasses.replace(ControllerParams(), cp_gain_lateral=value).validate()


def test_sweep_spec_takes_the_gain_and_names_its_range():
    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.dialects.validation import SpecError

    base = {"sweep": {"name": "w"}, "push": {"grid": {"impulse_ns": [0.5]}}}
    spec = parse_spec(base | {"controller": {"cp_gain_lateral": -1.0}})
    assert spec.controller["cp_gain_lateral"] == -1.0
    with pytest.raises((SpecError, ValueError), match=r"cp_gain_lateral.*\[-3, 3\].*-4"):
        parse_spec(base | {"controller": {"cp_gain_lateral": -4.0}})


def test_op3_widen_start_is_its_tune_specs_start():
    """specs/robots/op3_tune_widen.toml's [controller] is op3_widen.json (the controller judged
    on the GPU), so the tune starts where the verdict's controller is."""
    import json
    import tomllib
    from pathlib import Path

    from tkujax.control.params_files import controller_params_from_dict

    robots = Path(__file__).parents[1] / "specs" / "robots"
    start = controller_params_from_dict(json.loads((robots / "op3_widen.json").read_text()),
                                        "op3_widen.json")
    assert start.cp_gain_lateral == -1.0 and start.lateral_steps == 1.0
    tune = tomllib.loads((robots / "op3_tune_widen.toml").read_text())
    assert "cp_gain_lateral" in tune["tune"]["params"]
    for key, value in tune["controller"].items():
        assert getattr(start, key) == pytest.approx(value, rel=1e-12), key
