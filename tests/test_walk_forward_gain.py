"""The walking recovery's forward gain (`WalkCommand.recovery_forward_gain`, `[walk]
recovery_forward_gain`): it scales the footstep's forward move only.

A warmed recovery state (every phase bin learned, the gait's capture point 0) meets a capture
point 3 cm ahead of it (a push from behind) or behind it: the pending offset is cp_gain x the
deviation, its forward part times the gain, its backward part untouched; gain 1 gives exactly
the offsets of a command that leaves the field out.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.control.gait import WalkCommand
from tkujax.control.walk_recovery import WARM_VISITS, RecoveryState, recovery_update
from tkujax.dialects.validation import SpecError
from tkujax.dialects.walk_table import parse_walk


def _pending(xi, **command_fields):
    params = ControllerParams.paper()
    command = WalkCommand.for_params(params, 0.1, recovery=1.0, **command_fields)
    state = dataclasses.replace(RecoveryState.init(),
                                seen=jnp.full_like(RecoveryState.init().seen, WARM_VISITS))
    state, deviation = recovery_update(state, jnp.asarray(xi, jnp.float32), 5.0, command,
                                       params, on=1.0, steady=True)
    assert float(state.armed) == 1.0
    return np.asarray(state.pending), float(params.cp_gain)


@pytest.mark.parametrize("gain", [0.0, 0.5, 1.0])
def test_the_gain_scales_forward_moves_only(gain):
    ahead, cp_gain = _pending([0.03, 0.0], recovery_forward_gain=gain)
    np.testing.assert_allclose(ahead, [gain * cp_gain * 0.03, 0.0], atol=1e-7)
    behind, _ = _pending([-0.03, 0.0], recovery_forward_gain=gain)
    np.testing.assert_allclose(behind, [-cp_gain * 0.03, 0.0], atol=1e-7)


def test_gain_one_is_the_default_bit_for_bit():
    for xi in ([0.03, 0.0], [-0.03, 0.0], [0.025, -0.02]):
        default, _ = _pending(xi)
        explicit, _ = _pending(xi, recovery_forward_gain=1.0)
        assert default.tobytes() == explicit.tobytes()


def test_the_walk_table_key_is_checked_and_reaches_the_spec():
    assert parse_walk({"walk": {"recovery_forward_gain": 0}}).recovery_forward_gain == 0.0
    assert parse_walk({"walk": {}}).recovery_forward_gain is None   # the robot's, else 1
    with pytest.raises(SpecError, match=r"walk\.recovery_forward_gain: 2\.5 is out of range "
                                        r"\[0\.0, 2\.0\]"):
        parse_walk({"walk": {"recovery_forward_gain": 2.5}})
