"""The support shift of a recovery step (ControllerParams.step_shift_m, `cpg.support_shift`):
the waist moves toward the support foot before the other lifts.

The profile against its closed form, both feet moved together toward the swing side (the waist
toward the support foot), nothing changed at 0; and on Booster T1 (MuJoCo C; skipped without
the shared models), commanded steps that T1 cannot take unpushed without the shift (it rolls
over the lifted foot) are taken with it.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.control.cpg import cpg_feet_lateral, support_shift

PARAMS = dataclasses.replace(ControllerParams(), step_period=0.4, double_support_ratio=0.5,
                             step_shift_m=0.06)
ROOT = Path(__file__).resolve().parents[1]
T1_FILE = ROOT / "specs/robots/t1.toml"
MODELS = ROOT.parent / "shared/models/booster_t1"


def test_the_shift_ramps_over_the_first_double_support_and_back_over_the_last():
    """Double supports of gamma T / 2 = 0.1 s: a half cosine up, held, a half cosine down."""
    t = np.array([-0.1, 0.0, 0.05, 0.1, 0.2, 0.3, 0.35, 0.4, 0.6])
    expected = 0.06 * np.array([0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 0.5, 0.0, 0.0])
    np.testing.assert_allclose(np.asarray(support_shift(t, PARAMS)), expected, atol=1e-7)


@pytest.mark.parametrize("y_sup, toward", [(0.02, 1.0), (-0.02, -1.0)])
def test_both_feet_move_toward_the_swing_side(y_sup, toward):
    """The waist over the support foot: relative to it both feet move by the shift toward the
    swing foot's side (+y when the left foot swings), and only in y."""
    t = np.linspace(-0.05, 0.5, 23)
    base = dataclasses.replace(PARAMS, step_shift_m=0.0)
    shifted = cpg_feet_lateral(t, 0.03, y_sup, PARAMS)
    plain = cpg_feet_lateral(t, 0.03, y_sup, base)
    for a, b in zip(shifted, plain):
        moved = np.asarray(a) - np.asarray(b)
        np.testing.assert_allclose(moved[:, 1], toward * np.asarray(support_shift(t, PARAMS)),
                                   atol=1e-7)
        np.testing.assert_array_equal(moved[:, [0, 2]], 0.0)


def test_no_shift_changes_nothing():
    t = np.linspace(-0.1, 0.6, 30)
    base = dataclasses.replace(PARAMS, step_shift_m=0.0)
    np.testing.assert_array_equal(np.asarray(support_shift(t, base)), 0.0)


def test_the_shift_is_validated_with_its_range():
    with pytest.raises(ValueError, match=r"step_shift_m must be in \[0, 0.25\] m"):
        dataclasses.replace(ControllerParams(), step_shift_m=0.3).validate()


@pytest.mark.skipif(not MODELS.is_dir(), reason="the shared Booster T1 model is absent")
def test_t1_takes_an_unpushed_step_only_with_the_shift(tmp_path, monkeypatch):
    """Two commanded steps of T1's right foot at zero impulse (MuJoCo C, 2.5 s): both fall
    without the shift (peak inclination beyond 90 deg), both stand with 10 cm of it."""
    from tkujax.cli import main
    from tkujax.sweeps.sweep import load

    monkeypatch.setenv("TKUJAX_MENAGERIE", str(MODELS.parent))
    spec = tmp_path / "steps.toml"
    spec.write_text(f"""[robot]
file = "{T1_FILE}"
[sweep]
name = "t1_shift"
chunk_size = 4
duration_s = 2.5
control = ["on"]
[push.grid]
impulse_ns = [0.0]
height_m = [0.58]
onset_s = [0.5]
[step]
reference = false
[step.grid]
x_m = [0.0, 0.075]
y_m = [-0.15]
start_delay_s = [0.0]
""")
    controller = json.loads((ROOT / "specs/robots/t1_controller.json").read_text())
    fell = {}
    for shift in (0.0, 0.10):
        params = tmp_path / f"shift_{shift}.json"
        params.write_text(json.dumps(controller | {"step_shift_m": shift}))
        out = tmp_path / f"run_{shift}"
        assert main(["sweep", str(spec), "--out", str(out), "--backend", "mujoco",
                     "--params", str(params)]) == 0
        rec = load(out)
        commanded = rec["step_active"] > 0.5
        fell[shift] = rec["fell"][commanded].astype(bool)
        if shift == 0.0:
            assert (rec["peak_incl_deg"][commanded] > 90.0).all()
    assert fell[0.0].all() and not fell[0.10].any()
