"""Walking from the controller's CPG (tkujax.control.gait, walking, walk_recovery;
docs/walking.md).

The gait against closed forms (step, lift, double support, the first step = the paper's recovery
step, the gait phase); walking that has not started = standing, bit for bit; TKU-X (and OP3 when
its Menagerie model is there) stepping in place and walking forward on MuJoCo C; `tkujax walk`;
pushes placed by gait phase; the footstep recovery: silent on an undisturbed walk (bit for bit),
a forward footstep after a push from behind; MJX against MuJoCo C on a short walk (slow: an MJX
compile).
"""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.cpg import cpg_feet
from tkujax.control.gait import (GaitState, WalkCommand, advance, gait_feet, gait_init,
                                 gait_phase, hurry, move_footstep, planned_feet, step_vector,
                                 time_at_phase, touchdown_time)
from tkujax.control.walk_recovery import PHASE_BINS, RecoveryState, phase_weights, step_offset
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.walking.walk import run_walk, walk_metrics, walker
from tkujax.walking.walk_push import push_at_gait_phase

PARAMS = ControllerParams.paper()
OP3_FILE = Path(__file__).resolve().parent.parent / "specs" / "robots" / "op3.toml"
OP3_MODEL = Path(__file__).resolve().parent.parent.parent / "shared" / "models" / "robotis_op3"


def _walk_to(command: WalkCommand, t_end: float, dt: float = 0.001):
    """The gait's feet on a fine clock from 0 to t_end: (times, p_right, p_left, counts)."""
    state = gait_init(command)
    ts = np.arange(0.0, t_end, dt, dtype=np.float32)

    def tick(state, t):
        state, _ = advance(state, t, command)
        return state, (gait_feet(state, t, command, PARAMS), state.count)

    _, ((p_r, p_l), count) = jax.lax.scan(tick, state, ts)
    return ts, np.asarray(p_r), np.asarray(p_l), np.asarray(count)


def test_first_step_is_the_papers_recovery_step():
    """No ramp, no sway: the first step from the stand is cpg_feet with x_Sup = speed x T."""
    cmd = WalkCommand.for_params(PARAMS, 0.1, sway_m=0.0, ramp_steps=0.0, start_s=0.0)
    ts, p_r, p_l, _ = _walk_to(cmd, 0.3)
    ref_r, ref_l = cpg_feet(ts, 0.1 * 0.3, PARAMS)
    np.testing.assert_allclose(p_r, np.asarray(ref_r), atol=1e-7)
    np.testing.assert_allclose(p_l, np.asarray(ref_l), atol=1e-7)


def test_steady_steps_move_each_foot_by_the_step():
    """After the ramp each step carries the swing foot from -d/2 to +d/2 and the support foot
    from +d/2 to -d/2 relative to the waist (d = speed x T), sideways too; the lift peaks at
    H_Sup mid-step; both feet are down for gamma of each step."""
    T, gamma, lift = 0.3, 0.2, 0.03
    cmd = WalkCommand.for_params(PARAMS, 0.2, 0.05, sway_m=0.0, ramp_steps=2.0, start_s=0.0)
    ts, p_r, p_l, count = _walk_to(cmd, 8 * T)
    d = np.array([0.2, 0.05]) * T
    d_y, d_z = PARAMS.hip_offset_y, PARAMS.hip_to_ankle_z
    for k in (4, 5):                                   # steady steps (count 4, 5)
        idx = np.flatnonzero(count == k)
        left_swings = k % 2 == 0                       # lateral >= 0: the left foot leads
        swing, support = (p_l, p_r) if left_swings else (p_r, p_l)
        y0 = d_y if left_swings else -d_y
        np.testing.assert_allclose(swing[idx[0], :2], [-d[0] / 2, y0 - d[1] / 2], atol=1e-6)
        np.testing.assert_allclose(swing[idx[-1], :2], [d[0] / 2, y0 + d[1] / 2], atol=2e-6)
        np.testing.assert_allclose(support[idx[0], :2], [d[0] / 2, -y0 + d[1] / 2], atol=1e-6)
        np.testing.assert_allclose(support[idx[-1], :2], [-d[0] / 2, -y0 - d[1] / 2], atol=2e-6)
        z = swing[idx, 2] + d_z
        assert abs(z.max() - lift) < 1e-5 and abs(ts[idx][np.argmax(z)] - ts[idx[0]] - T / 2) < 2e-3
        np.testing.assert_array_equal(support[idx, 2], np.float32(-d_z))
        both_down = np.mean(swing[idx, 2] == np.float32(-d_z))
        assert abs(both_down - gamma) < 0.01, both_down


def test_ramp_and_planned_feet():
    cmd = WalkCommand(speed_mps=0.2, lateral_mps=-0.1, step_period_s=0.25, ramp_steps=3.0)
    for k, frac in ((0, 0.25), (1, 0.5), (2, 0.75), (3, 1.0), (10, 1.0)):
        np.testing.assert_allclose(np.asarray(step_vector(cmd, k)),
                                   np.array([0.2, -0.1]) * 0.25 * frac, rtol=1e-6)
    d = jnp.array([0.04, 0.01])
    np.testing.assert_allclose(np.asarray(planned_feet(1.0, d, jnp.array([0.01, 0.0]))),
                               [-0.02, -0.005, 0.03, 0.005])
    np.testing.assert_allclose(np.asarray(planned_feet(0.0, d, jnp.zeros(2))),
                               [0.02, 0.005, -0.02, -0.005])
    assert float(gait_init(cmd).swing_left) == 1.0       # walking right: the right foot leads


def test_gait_phase_is_zero_at_left_touchdowns():
    """Phase 0 at the left foot's nominal touchdown, 1/2 at the right's; time_at_phase inverts."""
    for lateral in (0.0, -0.05):
        cmd = WalkCommand.for_params(PARAMS, 0.1, lateral, ramp_steps=0.0)
        ts, p_r, p_l, _ = _walk_to(cmd, 3.0)
        d_z = PARAMS.hip_to_ankle_z
        for foot, phase in ((p_l, 0.0), (p_r, 0.5)):
            up = foot[:, 2] > -d_z
            lands = ts[1:][up[:-1] & ~up[1:]]
            got = np.asarray(gait_phase(lands, cmd))
            assert np.all(np.minimum(np.abs(got - phase), 1 - np.abs(got - phase)) < 0.01), got
        t = time_at_phase(0.3, 2, cmd)
        assert abs(float(gait_phase(t, cmd)) - 0.3) < 1e-5


def test_one_program_serves_every_speed(compiles):
    """The command's fields are traced leaves: a new speed, period or lift does not recompile."""
    f = jax.jit(jax.vmap(lambda c: gait_feet(advance(gait_init(c), 1.0, c)[0], 1.0, c, PARAMS)))
    stack = lambda cs: jax.tree_util.tree_map(lambda *v: jnp.stack(v), *cs)  # noqa: E731
    f(stack([WalkCommand(speed_mps=0.1), WalkCommand(speed_mps=-0.1)]))
    n = compiles.count
    f(stack([WalkCommand(speed_mps=0.3, step_period_s=0.4), WalkCommand(lift_m=0.02)]))
    assert compiles.count == n


def test_validate_names_the_field():
    with pytest.raises(ValueError, match="WalkCommand.speed_mps must be in"):
        WalkCommand(speed_mps=3.0).validate()
    with pytest.raises(ValueError, match="WalkCommand.recovery must be 0 or 1"):
        WalkCommand(recovery=0.5).validate()
    assert isinstance(GaitState, type)


def test_walk_not_started_is_standing_bit_for_bit():
    """A walk whose first step lies beyond the horizon runs the walking controller, and every
    recorded field but the touchdown time equals the standing rollout's bit for bit (a push
    with control off; no push with control on: the stance feedback, no step)."""
    pushes = stack_pushes([make_push(0.8, 0.0), make_push(0.0)])
    enabled = np.array([0.0, 1.0])
    config = RolloutConfig(duration_s=0.9)
    for params in (PARAMS, ControllerParams.recommended()):
        stand, _ = simulate_mujoco(pushes, enabled, params, config=config)
        walk, _ = simulate_mujoco(pushes, enabled, params, config=config,
                                  walk=WalkCommand(start_s=50.0))
        assert not np.any(np.asarray(stand.step_weight))          # the standing robot stood
        for key, value in stand.items():
            if key != "touchdown_s":
                np.testing.assert_array_equal(np.asarray(getattr(walk, key)), np.asarray(value),
                                              err_msg=key)


@pytest.fixture(scope="module")
def tkux_walks():
    who = walker(None)
    cmds = [WalkCommand.for_params(who.gait_params, v) for v in (0.0, 0.15, -0.1)]
    series, _ = run_walk(who, cmds, 4.0, "mujoco")
    return [walk_metrics(series, i, c) for i, c in enumerate(cmds)]


def test_tkux_steps_in_place_and_walks(tkux_walks):
    """TKU-X on MuJoCo C, 4 s: it does not fall stepping in place, walking forward or backward;
    the measured step period is T; forward and backward it covers ground the right way."""
    in_place, forward, backward = tkux_walks
    for m in tkux_walks:
        assert not m["fell"], m
        assert abs(m["step_period_s"] - 0.3) < 0.01, m
        assert abs(m["heading_drift_deg"]) < 10.0, m
    assert abs(in_place["mean_forward_mps"]) < 0.04, in_place
    assert abs(forward["mean_forward_mps"] - 0.15) < 0.04, forward
    assert abs(forward["step_length_m"] - 0.15 * 0.3) < 0.01, forward
    assert abs(backward["mean_forward_mps"] + 0.1) < 0.04, backward


def test_heading_hold_while_walking_sideways():
    """TKU-X walking 0.1 m/s to the left for 8 s turns 7 deg with the hip yaws held at 0
    (heading_gain 0) and under 3 deg with the default heading hold."""
    who = walker(None)
    cmds = [WalkCommand.for_params(who.gait_params, 0.0, 0.1, heading_gain=g) for g in (0.0, 0.5)]
    series, _ = run_walk(who, cmds, 8.0, "mujoco")
    free, held = (walk_metrics(series, i, c)["heading_drift_deg"] for i, c in enumerate(cmds))
    assert abs(free) > 5.0 and abs(held) < 3.0, (free, held)
    assert cmds[1].heading_gain == WalkCommand().heading_gain


@pytest.mark.skipif(not OP3_MODEL.exists(), reason="no ../shared/models/robotis_op3")
def test_op3_steps_in_place_and_walks():
    who = walker(str(OP3_FILE))
    cmds = [WalkCommand.for_params(who.gait_params, v) for v in (0.0, 0.15)]
    series, _ = run_walk(who, cmds, 4.0, "mujoco")
    in_place, forward = (walk_metrics(series, i, c) for i, c in enumerate(cmds))
    for m in (in_place, forward):
        assert not m["fell"], m
        assert abs(m["step_period_s"] - float(cmds[0].step_period_s)) < 0.02, m
    assert abs(in_place["mean_forward_mps"]) < 0.05, in_place
    assert 0.1 < forward["mean_forward_mps"] < 0.25, forward


def test_walk_command_line(capsys):
    from tkujax.cli import main

    assert main(["walk", "--seconds", "2", "--speed-mps", "0.1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == "tkux" and out["fell"] is False
    assert out["command"]["step_length_m"] == pytest.approx(0.03)
    for key in ("distance_m", "mean_speed_mps", "heading_drift_deg", "step_period_s",
                "step_length_m"):
        assert key in out


def test_walk_command_line_writes_the_walk_as_a_video_and_a_picture(tmp_path, capsys):
    """`tkujax walk --gif --png`: a GIF that shows the walk's time at one frame per
    1 / WALK_GIF_FPS s and a picture of WALK_STRIP_FRAMES frames side by side (skips where no
    GL context can be made)."""
    from PIL import Image

    from tkujax import render
    from tkujax.cli import main
    from tkujax.render import WALK_FRAME_SIZE, WALK_GIF_FPS, WALK_STRIP_FRAMES

    ok, why = render.rendering_available()
    if not ok:
        pytest.skip(f"no offscreen rendering here: {why}")
    gif, png = tmp_path / "walk.gif", tmp_path / "walk.png"
    assert main(["walk", "--seconds", "0.9", "--speed-mps", "0", "--gif", str(gif),
                 "--png", str(png)]) == 0
    assert json.loads(capsys.readouterr().out)["figures"] == {"gif": str(gif), "png": str(png)}
    samples = int(round(0.9 / 0.03))               # one qpos per 30 ms control period
    every = int(round(1.0 / (WALK_GIF_FPS * 0.03)))
    with Image.open(gif) as video:
        assert video.size == WALK_FRAME_SIZE
        shown_ms = 0
        for k in range(video.n_frames):      # identical frames may be merged, not dropped
            video.seek(k)
            shown_ms += video.info["duration"]
    assert shown_ms == -(-samples // every) * round(1000.0 * every * 0.03)
    with Image.open(png) as picture:
        assert picture.size == (WALK_STRIP_FRAMES * WALK_FRAME_SIZE[0], WALK_FRAME_SIZE[1])


def test_yawed_ik_through_mujoco_kinematics():
    """solve_legs_yaw on TKU-X: MuJoCo's forward kinematics put each ankle at its target
    (1 mm), the sole level (within the hip roll's |sin(roll) sin(lean)| + 1 deg, as
    solve_legs) and the foot turned by the hip yaw (0.5 deg); yaw 0 is solve_legs exactly."""
    import mujoco

    from tkujax.control.solve import solve_legs, solve_legs_yaw
    from tkujax.model import LEG_ACTUATORS, load_model

    model = load_model()
    data = mujoco.MjData(model)
    adr = np.array([model.joint(n).qposadr[0] for n in LEG_ACTUATORS])
    d_y, d_z = PARAMS.hip_offset_y, PARAMS.hip_to_ankle_z
    for dx, dy, lift, yaw_r, yaw_l in ((0.03, 0.0, 0.0, 0.1, -0.05), (-0.04, 0.01, 0.02, -0.1, 0.1),
                                       (0.0, -0.01, 0.03, 0.05, 0.0), (0.02, 0.0, 0.01, 0.0, 0.0)):
        p_r = jnp.array([dx, -d_y + dy, -d_z])
        p_l = jnp.array([-dx, d_y + dy, -d_z + lift])
        q, ok = solve_legs_yaw(p_r, p_l, yaw_r, yaw_l, PARAMS)
        assert bool(ok)
        if yaw_r == yaw_l == 0.0:
            flat, _ = solve_legs(p_r, p_l, PARAMS)
            np.testing.assert_array_equal(np.asarray(q), np.asarray(flat))
        data.qpos[:] = model.key("stand").qpos
        data.qpos[adr] = np.asarray(q)
        mujoco.mj_kinematics(model, data)
        waist = data.site("waist").xpos
        for site, target, yaw, roll in (("r_ankle", p_r, yaw_r, q[1]),
                                        ("l_ankle", p_l, yaw_l, q[7])):
            frame = data.site(site).xmat.reshape(3, 3)
            np.testing.assert_allclose(data.site(site).xpos - waist, np.asarray(target), atol=1e-3)
            tilt = np.degrees(np.arccos(min(1.0, frame[2, 2])))
            assert tilt < 1.0 + np.degrees(abs(np.sin(float(roll)) * np.sin(PARAMS.standing_lean)))
            assert abs(np.degrees(np.arctan2(frame[1, 0], frame[0, 0]) - yaw)) < 0.5


def test_push_at_gait_phase():
    cmd = WalkCommand.for_params(PARAMS, 0.1)
    for phase in (0.0, 0.3, 0.5, 0.875):
        push = push_at_gait_phase(cmd, phase, 0.8, 90.0, cycle=4)
        assert abs(float(gait_phase(push.onset_s, cmd)) - phase) < 1e-4
        assert float(push.onset_s) > float(cmd.start_s) + 4 * 2 * 0.3
    with pytest.raises(ValueError, match="gait_phase must be in"):
        push_at_gait_phase(cmd, 1.0, 0.8)
    with pytest.raises(ValueError, match="cycle must be an integer"):
        push_at_gait_phase(cmd, 0.5, 0.8, cycle=1.5)


def test_footstep_offsets_centred_and_outward():
    """A footstep offset grows the step by it, centred on the waist; sideways only outward for
    the swing foot; the phase bins' weights interpolate and sum to 1."""
    state = GaitState(count=jnp.asarray(3.0), start_s=jnp.asarray(1.0),
                      swing_left=jnp.asarray(1.0), feet_from=jnp.zeros(4),
                      feet_to=jnp.array([-0.015, 0.0, 0.015, 0.0]), yaw_from=jnp.zeros(2),
                      yaw_to=jnp.zeros(2), lead_s=jnp.asarray(0.0))
    moved = move_footstep(state, jnp.array([0.02, 0.01]))
    np.testing.assert_allclose(np.asarray(moved.feet_to), [-0.025, -0.005, 0.025, 0.005])
    rec = dataclasses.replace(RecoveryState.init(), pending=jnp.array([0.03, -0.02]),
                              armed=jnp.asarray(1.0))
    np.testing.assert_allclose(np.asarray(step_offset(rec, 1.0)), [0.03, 0.0])   # left: +y only
    np.testing.assert_allclose(np.asarray(step_offset(rec, 0.0)), [0.03, -0.02])
    for phase in (0.0, 0.01, 0.5, 0.97):
        w = np.asarray(phase_weights(phase))
        assert w.shape == (PHASE_BINS,) and abs(w.sum() - 1.0) < 1e-6 and np.count_nonzero(w) <= 2
        centres = (np.arange(PHASE_BINS) + 0.5) / PHASE_BINS
        d = (centres - phase + 0.5) % 1.0 - 0.5                  # periodic distance
        assert abs(float(w @ d)) < 1e-6                          # the weights' centre is phase


def test_footstep_recovery_silent_without_push_and_steps_after_one():
    """TKU-X at 0.1 m/s on MuJoCo C, 6.7 s: without a push the recovery never triggers (the
    walk is bit-identical to recovery off, with or without recovery_hurry); after 1.2 N s from
    behind in mid-swing (gait phase 0.25 of the 10th cycle) it moves a footstep forward, where
    recovery off moves none, and with recovery_hurry 0.3 the same offset's step lands sooner."""
    who = walker(None)
    off, on = (WalkCommand.for_params(who.gait_params, 0.1, recovery=r) for r in (0.0, 1.0))
    hurried = dataclasses.replace(on, recovery_hurry=0.3)
    push = push_at_gait_phase(off, 0.25, 1.2, 0.0)
    pushes = stack_pushes([make_push(0.0)] * 3 + [push] * 3)
    series, _ = run_walk(who, [off, on, hurried] * 2, float(push.onset_s) + 0.6, "mujoco",
                         pushes=pushes)
    for key, value in series.items():
        for lane in (1, 2):
            np.testing.assert_array_equal(np.asarray(value)[lane], np.asarray(value)[0],
                                          err_msg=key)
    x_sup = np.asarray(series.x_sup)
    assert not np.any(x_sup[3]) and np.max(x_sup[4]) > 0.01, np.max(x_sup[4])
    # The step that took the offset: its touchdown as the controller planned it, on and hurried.
    moved = np.flatnonzero(x_sup[4])[0]
    touchdown = np.asarray(series.touchdown_s)
    gained = touchdown[4, moved + 1] - touchdown[5, moved + 1]
    assert 0.005 < gained < 0.3 * float(on.step_period_s), gained


@pytest.mark.slow
def test_mjx_agrees_with_mujoco_on_a_short_walk():
    """TKU-X walking 0.15 m/s for 2.4 s: the same fall outcome (none) on MJX and MuJoCo C and
    the CoM within WALK_COM_TOL_M (float32 against float64 physics through 6 touchdowns)."""
    who = walker(None)
    cmd = WalkCommand.for_params(who.gait_params, 0.15)
    c_series, c_out = run_walk(who, [cmd], 2.4, "mujoco")
    m_series, m_out = run_walk(who, [cmd], 2.4, "mjx")
    assert not bool(c_out.fell[0]) and not bool(m_out.fell[0])
    gap = np.abs(np.asarray(m_series.com[0]) - np.asarray(c_series.com[0])).max()
    assert gap < WALK_COM_TOL_M, gap


WALK_COM_TOL_M = 0.01


def test_hurry_cuts_the_rest_of_the_swing():
    """recovery_hurry h: while active and before touchdown the step's clock runs 1 / (1 - h)
    times as fast (its start moves back by period x h / (1 - h), which lead_s adds up); after
    touchdown, inactive, or with h = 0 the gait is unchanged."""
    cmd = WalkCommand.for_params(PARAMS, 0.1, recovery_hurry=0.25)
    state, _ = advance(gait_init(cmd), float(cmd.start_s), cmd)
    period = 0.03
    hurried = hurry(state, float(cmd.start_s) + 0.1, cmd, 1.0, period)
    gained = period * 0.25 / 0.75
    assert abs(float(state.start_s - hurried.start_s) - gained) < 1e-6
    assert abs(float(hurried.lead_s) - gained) < 1e-6
    assert float(touchdown_time(hurried, cmd)) < float(touchdown_time(state, cmd))
    landed = float(touchdown_time(state, cmd)) + 0.001
    for same in (hurry(state, landed, cmd, 1.0, period),
                 hurry(state, float(cmd.start_s) + 0.1, cmd, 0.0, period),
                 hurry(state, float(cmd.start_s) + 0.1,
                       dataclasses.replace(cmd, recovery_hurry=0.0), 1.0, period)):
        for a, b in zip(jax.tree_util.tree_leaves(same), jax.tree_util.tree_leaves(state)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
