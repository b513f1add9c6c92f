"""Early decisions of a walking lane (tkujax.sim.lanes): "back on its gait".

A synthetic gait (pitch and roll swinging with the cycle) checks the rule against what it says:
inside the envelope of the reference cycles after the push, out of it during a disturbance,
never before the push has ended, and not armed where the reference cycles fall in the gait's
ramp. Slow: an early walking sweep against the full horizon (MJX, TKU-X), the same falls, and
pushes that stand decided before the horizon.
"""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.cli import main
from tkujax.control.gait import WalkCommand
from tkujax.sim.lanes import (GAIT_ANGLE_MARGIN_RAD, back_on_gait_armed, decision_of, SETTLED,
                              UNDECIDED)
from tkujax.sim.options import Episode
from tkujax.sim.push import make_push
from tkujax.sim.records import SERIES_FIELDS, Series

from walk_helpers import full_and_early

PERIOD_S = 0.03
STEP_S = 0.3                    # a gait cycle of 0.6 s = 20 ticks
AMPLITUDE_RAD = 0.02


def _gait_rows(n_ticks, disturb=(0.0, 0.0), amplitude=AMPLITUDE_RAD):
    """Rows of a steady gait (pitch and roll at the cycle's frequency), with `disturb` =
    (from_s, to_s) adding 4x the gait's swing."""
    t = np.arange(1, n_ticks + 1) * PERIOD_S
    swing = amplitude * np.sin(2 * np.pi * t / (2 * STEP_S))
    extra = np.where((t >= disturb[0]) & (t < disturb[1]), 4 * amplitude, 0.0)
    zeros3 = np.zeros((n_ticks, 3))
    fields = {name: np.zeros(n_ticks) for name in SERIES_FIELDS}
    fields.update(t=t, pitch=0.05 + swing + extra, roll=swing, com=zeros3 + [0, 0, 0.3],
                  pelvis_z=np.full(n_ticks, 0.3), lowest_body_z=np.full(n_ticks, 0.1),
                  zmp=np.zeros((n_ticks, 2)), r_ankle=zeros3, l_ankle=zeros3,
                  qpos=None, touchdown_s=None)
    return Series(**{k: (None if v is None else jnp.asarray(v, jnp.float32))
                     for k, v in fields.items()})


def _episode(onset_s, start_s=0.3):
    walk = WalkCommand(speed_mps=0.1, step_period_s=STEP_S, start_s=start_s)
    return Episode(push=make_push(1.0, 0.0, onset_s=onset_s, duration_s=0.03),
                   enabled=jnp.float32(1.0), key=None, walk=walk)


def _decisions(rows, episode):
    """The decision after every tick, as the lane computes it (quiet carried)."""
    quiet, out = jnp.int32(0), []
    for k in range(rows.t.shape[0]):
        row = Series(**{f: (None if getattr(rows, f) is None else getattr(rows, f)[k])
                        for f in SERIES_FIELDS})
        lane = dict(k=jnp.int32(k), rows=rows, quiet=quiet)
        quiet, decision = decision_of(lane, row, None, episode, PERIOD_S)
        out.append(int(decision))
    return np.array(out)


def _first_settled_s(decisions):
    hit = np.flatnonzero(decisions == SETTLED)
    return (hit[0] + 1) * PERIOD_S if len(hit) else None


def test_a_steady_gait_is_back_on_its_gait_two_cycles_after_the_push():
    """Undisturbed after a push at 4 s: decided once two whole cycles have passed after the
    push's end (4.03 + 1.2 s), not before."""
    decisions = _decisions(_gait_rows(200), _episode(onset_s=4.0))
    first = _first_settled_s(decisions)
    assert first is not None and 5.23 - PERIOD_S <= first <= 5.23 + 2 * PERIOD_S
    assert (decisions[:int(5.15 / PERIOD_S)] == UNDECIDED).all()


def test_a_disturbed_gait_is_decided_two_cycles_after_it_settles():
    """A swing of 4x the gait's until 5.5 s: not decided before 5.5 + 1.2 s."""
    decisions = _decisions(_gait_rows(250, disturb=(4.0, 5.5)), _episode(onset_s=4.0))
    first = _first_settled_s(decisions)
    assert first is not None and 6.7 - PERIOD_S <= first <= 6.7 + 2 * PERIOD_S


def test_a_gait_that_stays_disturbed_is_never_decided():
    decisions = _decisions(_gait_rows(200, disturb=(4.0, 10.0)), _episode(onset_s=4.0))
    assert (decisions == UNDECIDED).all()


def test_the_margin_alone_does_not_hide_a_disturbance():
    """A gait with no swing at all: a lean of twice the angle margin is out of the envelope."""
    rows = _gait_rows(200, disturb=(4.0, 10.0), amplitude=0.0)
    rows = Series(**{f: getattr(rows, f) for f in SERIES_FIELDS} |
                  {"pitch": rows.pitch + jnp.where(rows.t >= 4.0, 2 * GAIT_ANGLE_MARGIN_RAD, 0)})
    assert (_decisions(rows, _episode(onset_s=4.0)) == UNDECIDED).all()


@pytest.mark.parametrize("onset_s, armed", [(1.2, False), (3.0, True)])
def test_the_rule_waits_for_reference_cycles_after_the_ramp(onset_s, armed):
    """Steady from start 0.3 + 5 steps x 0.3 = 1.8 s; two reference cycles take 1.2 s."""
    assert bool(back_on_gait_armed(_episode(onset_s))) is armed
    decisions = _decisions(_gait_rows(150), _episode(onset_s))
    assert bool((decisions == SETTLED).any()) is armed


@pytest.mark.slow
def test_early_walking_sweep_matches_the_full_horizon(tmp_path):
    """TKU-X walking at 0.1 m/s, pushed in gait cycle 5 (after the ramp and two reference
    cycles), recovery off and on: early decisions (MJX lanes) give the full horizon's falls;
    every push is decided before the horizon."""
    horizon_s = 6.3
    data = {"sweep": {"duration_s": horizon_s, "chunk_size": 4, "lanes": 4},
            "walk": {"speed_mps": 0.1, "recovery": ["off", "on"], "push_cycle": 5},
            "push": {"grid": {"impulse_ns": [0.5, 1.6], "gait_phase": [0.25, 0.75]}}}
    out = full_and_early(data, tmp_path)
    fell = out["full"]["fell"].astype(bool)
    assert fell.any() and not fell.all()
    np.testing.assert_array_equal(out["early"]["fell"].astype(bool), fell)
    assert (out["early"]["decided_s"] < horizon_s - PERIOD_S).all()


def test_pushes_that_differ_in_gait_phase_share_a_pre_push_snapshot():
    """The gait phase is the push's timing, not the setting: two pushes in the same control
    tick share their walk until it (one snapshot group); another recovery setting does not."""
    from tkujax.sweeps.early import snapshot_groups

    recs = {"onset_s": np.array([6.001, 6.015, 6.001, 6.2]),
            "gait_phase": np.array([0.10, 0.12, 0.10, 0.4]),
            "impulse_ns": np.array([0.5, 0.9, 0.5, 0.5]),
            "walk_recovery": np.array([1.0, 1.0, 0.0, 1.0]),
            "gyro_noise_std": np.zeros(4), "accel_noise_std": np.zeros(4)}
    group, k0 = snapshot_groups(recs, steps=False)
    assert group[0] == group[1] and len(set(group.tolist())) == 3
    np.testing.assert_array_equal(np.sort(k0), [200, 200, 206])


def test_compare_reads_an_early_sweeps_two_settings_as_the_same_pushes(tmp_path):
    """The decision time is an outcome: recovery off and on of one early walking sweep, whose
    pushes are decided at different times, are compared (the committed CPU walking sweep, its
    chunk given a decided_s column that differs between the two settings)."""
    import hashlib
    import shutil
    from pathlib import Path

    source = Path(__file__).resolve().parents[1] / "results/walking/walk_push_map_cpu"
    folder = tmp_path / "sweep"
    shutil.copytree(source, folder, ignore=shutil.ignore_patterns("compare", "maps"))
    chunk = folder / "chunk_000000.npz"
    columns = dict(np.load(chunk))
    columns["decided_s"] = np.where(columns["walk_recovery"] > 0.5, 7.5, 8.1).astype(np.float32)
    np.savez(chunk, **columns)
    manifest = json.loads((folder / "manifest.json").read_text())
    entry = manifest["chunks"]["chunk_000000.npz"]
    entry.update(sha256=hashlib.sha256(chunk.read_bytes()).hexdigest(),
                 bytes=chunk.stat().st_size)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    assert main(["compare", f"{folder}:recovery-off", f"{folder}:recovery-on", "--out",
                 str(tmp_path / "compare"), "--min-pushes", "4"]) == 0
    verdict = json.loads((tmp_path / "compare" / "verdict.json").read_text())
    assert verdict["reference"]["n"] == 64 and len(verdict["runs"]) == 1
