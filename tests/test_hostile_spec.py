"""Hostile sweep specs through `tkujax sweep`: every bad value stops the command before anything
runs, with exit 2 and one line naming the key (and its range), and writes no record. Plus the
spec files themselves (a folder, bytes that are not UTF-8, no file, bad TOML) and the limits
(a 32-million-push grid is refused at once)."""

from __future__ import annotations

import time

import pytest
from hostile_helpers import TINY, nothing_written, refused

SWEEP = """
[sweep]
name = "hostile"
seed = {seed}
chunk_size = {chunk}
duration_s = {duration}
control = {control}
"""
GRID = """
[push.grid]
impulse_ns = {impulse}
azimuth_deg = {azimuth}
onset_s = {onset}
"""
OK = dict(seed="0", chunk="2", duration="0.3", control='["off"]', impulse="[0.5]",
          azimuth="[0, 180]", onset="[0.1]")


def spec_text(extra: str = "", **over) -> str:
    """TINY-like spec text with [sweep] / [push.grid] values replaced and `extra` appended."""
    values = OK | over
    return SWEEP.format(**values) + GRID.format(**values) + extra


# (case id, spec text, key the message must name)
CASES = [
    ("seed_negative", spec_text(seed="-1"), "sweep.seed"),
    ("seed_65_bits", spec_text(seed="18446744073709551616"), "sweep.seed"),
    ("seed_33_bits", spec_text(seed="4294967296"), "sweep.seed"),
    ("seed_float", spec_text(seed="1.5"), "sweep.seed"),
    ("seed_bool", spec_text(seed="true"), "sweep.seed"),
    ("seed_string", spec_text(seed='"0"'), "sweep.seed"),
    ("chunk_zero", spec_text(chunk="0"), "sweep.chunk_size"),
    ("chunk_too_big", spec_text(chunk="2000000"), "1048576"),
    ("chunk_float", spec_text(chunk="2.0"), "sweep.chunk_size"),
    ("duration_nan", spec_text(duration="nan"), "sweep.duration_s"),
    ("duration_inf", spec_text(duration="inf"), "sweep.duration_s"),
    ("duration_short", spec_text(duration="0.05"), "sweep.duration_s"),
    ("duration_long", spec_text(duration="31.0"), "sweep.duration_s"),
    ("control_empty", spec_text(control="[]"), "sweep.control"),
    ("control_twice", spec_text(control='["on", "on"]'), "sweep.control"),
    ("control_number", spec_text(control="[1]"), "sweep.control"),
    ("control_nested", spec_text(control="[[1]]"), "sweep.control"),
    ("control_string", spec_text(control='"on"'), "sweep.control"),
    ("impulse_nan", spec_text(impulse="[nan]"), "push.grid.impulse_ns[0]"),
    ("impulse_negative", spec_text(impulse="[-1]"), "push.grid.impulse_ns[0]"),
    ("impulse_huge", spec_text(impulse="[1e308]"), "push.grid.impulse_ns[0]"),
    ("height_far_off", spec_text("height_m = [9.0]\n"), "push.grid.height_m[0]"),
    ("impulse_empty", spec_text(impulse="[]"), "push.grid.impulse_ns"),
    ("impulse_text", spec_text(impulse='["a"]'), "push.grid.impulse_ns[0]"),
    ("impulse_bool", spec_text(impulse="[true]"), "push.grid.impulse_ns[0]"),
    ("impulse_range_no_num", spec_text(impulse="{start = 0, stop = 1}"), "push.grid.impulse_ns"),
    ("impulse_range_num_zero", spec_text(impulse="{start = 0, stop = 1, num = 0}"),
     "push.grid.impulse_ns.num"),
    ("impulse_range_endpoint", spec_text(impulse='{start = 0, stop = 1, num = 2, endpoint = "y"}'),
     "push.grid.impulse_ns.endpoint"),
    ("impulse_range_extra_key", spec_text(impulse="{start = 0, stop = 1, num = 2, step = 1}"),
     "push.grid.impulse_ns"),
    ("azimuth_nan", spec_text(azimuth="[nan]"), "push.grid.azimuth_deg[0]"),
    ("azimuth_inf", spec_text(azimuth="[-inf]"), "push.grid.azimuth_deg[0]"),
    ("azimuth_out", spec_text(azimuth="[400]"), "push.grid.azimuth_deg[0]"),
    ("azimuth_second_nan", spec_text(azimuth="[0, nan]"), "push.grid.azimuth_deg[1]"),
    ("onset_after_horizon", spec_text(onset="[0.4]"), "push.grid.onset_s"),
    ("pulse_cut_by_horizon", spec_text(onset="[0.29]"), "push.grid.duration_s"),
    ("onset_nan", spec_text(onset="[nan]"), "push.grid.onset_s[0]"),
    ("height_off_robot", spec_text("height_m = [1.0]\n"), "height_m"),
    ("pulse_too_long", spec_text("duration_s = [0.25]\n"), "push.grid.duration_s"),
    ("phase_one", spec_text("onset_phase = [1.0]\n"), "push.grid.onset_phase"),
    ("phase_negative", spec_text("onset_phase = [-0.1]\n"), "push.grid.onset_phase"),
    ("phase_pushes_past_horizon", spec_text("onset_phase = [0.9]\n", onset="[0.27]"),
     "push.grid.onset_phase"),
    ("grid_unknown_key", spec_text("force_n = [1]\n"), "[push.grid]"),
    ("random_n_negative", spec_text("[push.random]\nn = -1\n"), "push.random.n"),
    ("random_n_float", spec_text("[push.random]\nn = 1.5\n"), "push.random.n"),
    ("random_n_huge", spec_text("[push.random]\nn = 100000000\n"), "push.random.n"),
    ("random_reversed", spec_text("[push.random]\nn = 2\nimpulse_ns = {uniform = [2, 1]}\n"),
     "push.random.impulse_ns.uniform"),
    ("random_nan_bound", spec_text("[push.random]\nn = 2\nimpulse_ns = {uniform = [nan, 1]}\n"),
     "push.random.impulse_ns.uniform[0]"),
    ("random_scalar", spec_text("[push.random]\nn = 2\nimpulse_ns = 3\n"),
     "push.random.impulse_ns"),
    ("random_onset_past_horizon",
     spec_text("[push.random]\nn = 2\nonset_s = {uniform = [0.1, 0.5]}\n"), "push.random.onset_s"),
    ("random_default_onset_past_horizon", spec_text("[push.random]\nn = 2\n"),
     "push.random.onset_s"),
    ("grid_32_million", spec_text("height_m = {start = 0.3, stop = 0.4, num = 32}\n",
                                  impulse="{start = 0.1, stop = 3, num = 1000}",
                                  azimuth="{start = 0, stop = 359, num = 1000}"), "[push]"),
    ("random_over_record_limit",
     spec_text("[push.random]\nn = 9000000\nonset_s = {uniform = [0.1, 0.2]}\n",
               control='["off", "on"]'), "limit"),
    ("controller_nan", spec_text("[controller]\nstep_period = nan\n"), "controller.step_period"),
    ("controller_deg_huge", spec_text("[controller]\neps_forward_deg = 1e9\n"),
     "controller.eps_forward_deg"),
    ("controller_unknown", spec_text("[controller]\nbogus = 1\n"), "[controller]"),
    ("controller_control_period", spec_text("[controller]\ncontrol_period = 0.02\n"),
     "control_period"),
    ("controller_grid_empty", spec_text("[controller.grid]\ncp_gain = []\n"),
     "controller.grid.cp_gain"),
    ("controller_grid_nan", spec_text("[controller.grid]\ncp_gain = [nan]\n"),
     "controller.grid.cp_gain[0]"),
    ("controller_both", spec_text("[controller]\ncp_gain = 1.0\n[controller.grid]\n"
                                  "cp_gain = [1.0]\n"), "controller"),
    ("arithmetic_unknown", spec_text('[controller]\narithmetic = "decimal"\n'),
     "controller.arithmetic"),
    ("randomize_out", spec_text("[randomize]\nlink_mass_scale = {uniform = [0.1, 1]}\n"),
     "randomize.link_mass_scale"),
    ("randomize_nan", spec_text("[randomize]\nfloor_friction = nan\n"), "randomize.floor_friction"),
    ("randomize_unknown", spec_text("[randomize]\ngravity = 1\n"), "[randomize]"),
    ("ensemble_empty", spec_text('[randomize]\nensemble = ""\n'), "randomize.ensemble"),
    ("ensemble_missing", spec_text('[randomize]\nensemble = "/no/such/ensemble.json"\n'),
     "randomize.ensemble"),
    ("ensemble_number", spec_text("[randomize]\nensemble = 3\n"), "randomize.ensemble"),
    ("step_out", spec_text("[step.grid]\nx_m = [1.0]\n"), "step.grid.x_m[0]"),
    ("step_reference_int", spec_text("[step]\nreference = 1\n[step.grid]\nx_m = [0.0]\n"),
     "step.reference"),
    ("step_without_grid", spec_text("[step]\nreference = true\n"), "[step]"),
    ("step_steps_three", spec_text("[step.grid]\nsteps = [3]\n"), "step.grid.steps"),
    ("robot_missing", spec_text('[robot]\nfile = "/no/such/robot.toml"\n'), "robot.file"),
    ("top_level_unknown", spec_text("[bogus]\na = 1\n"), "[top level]"),
    ("no_pushes", SWEEP.format(**OK), "[push]"),
    ("decisions_unknown", spec_text().replace("[push.grid]", 'decisions = "soon"\n[push.grid]'),
     "sweep.decisions"),
    ("lanes_zero", spec_text().replace("[push.grid]", 'decisions = "early"\nlanes = 0\n'
                                                      "[push.grid]"), "sweep.lanes"),
    ("lanes_above_chunk", spec_text().replace("[push.grid]", 'decisions = "early"\nlanes = 3\n'
                                                             "[push.grid]"), "sweep.lanes"),
    ("tree_passes_unknown", spec_text().replace("[push.grid]", 'tree_passes = "x"\n[push.grid]'),
     "sweep.tree_passes"),
    ("sweep_unknown", spec_text().replace("[push.grid]", "speed = 2\n[push.grid]"), "[sweep]"),
    ("name_number", spec_text().replace('name = "hostile"', "name = 3"), "sweep.name"),
    ("fpga_unknown", spec_text('[controller]\narithmetic = "fixed"\n[fpga]\nbogus = 1\n'), "fpga"),
]


@pytest.mark.parametrize("text, key", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_bad_spec_value_is_refused_before_anything_runs(capsys, tmp_path, text, key):
    spec = tmp_path / "spec.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    t0 = time.perf_counter()
    refused(capsys, key, "sweep", spec, "--out", out, "--backend", "mujoco")
    assert time.perf_counter() - t0 < 20.0      # no simulation, no expansion of the grid
    nothing_written(out)


def test_a_32_million_push_grid_is_refused_at_once(tmp_path):
    from tkujax.dialects.sweep_spec import MAX_RECORDS, SpecError, parse_spec

    text = dict(CASES_BY_ID)["grid_32_million"]
    spec = tmp_path / "big.toml"
    spec.write_text(text)
    import tomllib

    t0 = time.perf_counter()
    with pytest.raises(SpecError, match=f"32,000,000 records.*{MAX_RECORDS:,}"):
        parse_spec(tomllib.loads(text))
    assert time.perf_counter() - t0 < 2.0


CASES_BY_ID = [(c[0], c[1]) for c in CASES]


def _spec_file(tmp_path, kind: str):
    path = tmp_path / "spec.toml"
    if kind == "folder":
        path.mkdir()
    elif kind == "latin1":
        path.write_bytes(TINY.replace('"hostile"', '"h\xe9"').encode("latin-1"))
    elif kind == "binary":
        path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    elif kind == "bad_toml":
        path.write_text("[sweep\nname = 1\n")
    elif kind == "empty":
        path.write_text("")
    return path


@pytest.mark.parametrize("kind, says", [
    ("folder", "is a folder"),
    ("latin1", "not UTF-8"),
    ("binary", "not UTF-8"),
    ("missing", "not found"),
    ("bad_toml", "not valid TOML"),
    ("empty", "[push]"),
])
def test_a_spec_file_that_is_not_one_is_named(capsys, tmp_path, kind, says):
    spec = _spec_file(tmp_path, kind)
    line = refused(capsys, says, "sweep", spec, "--out", tmp_path / "out", "--backend", "mujoco")
    if kind != "empty":
        assert str(spec) in line
    nothing_written(tmp_path / "out")
