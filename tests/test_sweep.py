"""Sweeps: spec validation, resume, sharding over 2 devices, 2 processes, bounds, maps."""

import copy
import dataclasses
import json
import math
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from tkujax.analysis import capturability
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.dialects.sweep_spec import SpecError, load_spec, parse_spec
from tkujax.control.params_files import load_controller_params_json as load_params_json
from tkujax.sweeps.sweep import load, run_sweep

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "specs" / "sweep" / "tiny.toml"
GOOD = {"sweep": {"name": "t", "chunk_size": 4, "duration_s": 1.0},
        "push": {"grid": {"impulse_ns": [0.5, 1.0], "azimuth_deg": {"start": 0, "stop": 360,
                                                                   "num": 4, "endpoint": False}}}}


def _with(path: str, value):
    data = copy.deepcopy(GOOD)
    *parents, leaf = path.split(".")
    node = data
    for p in parents:
        node = node.setdefault(p, {})
    node[leaf] = value
    return data


@pytest.mark.parametrize("path, value, match", [
    ("bogus", 1, r"unknown key\(s\) \['bogus'\]"),
    ("sweep.chunksize", 4, r"\[sweep\]: unknown key\(s\) \['chunksize'\]"),
    ("sweep.chunk_size", "4", r"sweep.chunk_size: expected int"),
    ("sweep.chunk_size", 0, r"sweep.chunk_size: 0 is out of range \[1, 1048576\]"),
    ("sweep.duration_s", 99.0, r"sweep.duration_s: 99.0 is out of range \[0.1, 30.0\] s"),
    ("sweep.control", ["maybe"], r"sweep.control"),
    ("push.grid.impulse_ns", [0.5, 250.0],
     r"push.grid.impulse_ns\[1\]: 250.0 is out of range \[0.0, 200.0\]"),
    ("push.grid.impulse_ns", [True], r"push.grid.impulse_ns\[0\]: expected a number"),
    ("push.grid.azimuth_deg", {"start": 0, "stop": 90}, r"push.grid.azimuth_deg: a range needs"),
    ("push.grid.height_m", [2.5], r"push.grid.height_m\[0\]: 2.5 is out of range \[0.05, 2.0\] m"),
    ("push.grid.mass", [1], r"\[push.grid\]: unknown key"),
    ("push.random.impulse_ns", {"uniform": [2.0, 1.0]}, r"lower bound 2.0 exceeds upper bound 1.0"),
    ("push.random.n", -1, r"push.random.n: expected an integer in \[0, 10000000\]"),
    ("push.grid.onset_phase", [0.5, 1.0], r"push.grid.onset_phase: 1.0 is out of range \[0, 1\)"),
    ("push.grid.onset_phase", {"start": 0, "stop": 1, "num": 4},
     r"push.grid.onset_phase: 1.0 is out of range \[0, 1\)"),
    ("push.grid.onset_phase", [-0.1], r"push.grid.onset_phase\[0\]: -0.1 is out of range \[0, 1\)"),
    ("push.random.onset_phase", {"uniform": [1.0, 1.0]},
     r"push.random.onset_phase.uniform\[0\]: 1.0 is out of range \[0, 1\)"),
    ("push.random.onset_phase", {"uniform": [0.0, 1.5]},
     r"push.random.onset_phase.uniform\[1\]: 1.5 is out of range \[0, 1\)"),
    # Controller ranges are ControllerParams.validate's (stated once), named with the key.
    ("controller.accel_gate", -1.0,
     r"controller.accel_gate: -1.0 is out of range: .*accel_gate must be in \[0, 100\] m/s\^2"),
    ("controller.step_period", 5.0,
     r"controller.step_period: 5.0 is out of range: .*step_period must be in \(0, 2\] s"),
    ("controller.eps_forward_deg", 95.0,
     r"controller.eps_forward_deg: 95.0 deg is out of range: .*eps_forward must be in \[0, pi/2\)"),
    ("controller.kalman_r", "x", r"controller.kalman_r: expected a number, .*\(0, inf\)"),
    ("controller.T", 0.3, r"\[controller\]: unknown key\(s\) \['T'\]"),
    ("controller.grid.lift_height", [0.01, 0.5],
     r"controller.grid.lift_height\[1\]: 0.5 is out of range: .*\[0, 0.1\] m"),
    ("controller.grid.step_period", {"start": 0.2, "stop": 3.0, "num": 3},
     r"controller.grid.step_period.stop: 3.0 is out of range"),
    ("randomize.floor_friction", {"uniform": [0.0, 1.0]}, r"randomize.floor_friction.uniform\[0\]"),
    ("randomize.servo_kp_scale", {"normal": [1, 0.1]},
     r"randomize.servo_kp_scale: expected \{uniform"),
])
def test_bad_specs_name_the_key_and_range(path, value, match):
    with pytest.raises(SpecError, match=match):
        parse_spec(_with(path, value))


def test_spec_conflicts_and_empty():
    data = _with("controller.step_period", 0.3)
    data["controller"]["grid"] = {"step_period": [0.2, 0.3]}
    with pytest.raises(SpecError, match=r"\['step_period'\] set both"):
        parse_spec(data)
    with pytest.raises(SpecError, match="nothing to run"):
        parse_spec({"sweep": {}, "push": {}})
    with pytest.raises(SpecError, match="not found"):
        load_spec(ROOT / "specs" / "sweep" / "no_such.toml")


def test_bad_run_options_name_the_option(tmp_path):
    """Options of a run (not the spec) are checked before anything runs or is written."""
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=rf"max_chunks must be an integer >= 1.*{bad!r}"):
            run_sweep(TINY, tmp_path / "s", max_chunks=bad, quiet=True)
    assert not (tmp_path / "s").exists()
    from tkujax.analysis.maps import make_maps

    with pytest.raises(FileNotFoundError, match=r"holds no sweep \(manifest.json not found\)"):
        make_maps(tmp_path)


def test_shipped_specs_expand():
    n = {f.stem: len(load_spec(f).records()["push_id"])   # the sweep dialect (tune, calibrate
         for kind in ("sweep", "capture", "fpga")          # and converge have their own)
         for f in (ROOT / "specs" / kind).glob("*.toml")}
    assert n["stability_map"] >= 10_000
    assert n["paper"] == 8 and n["tiny"] == 8 and n["stability_map_cpu"] == 128
    assert n["ensemble_cpu"] == 384          # its ensemble: results/calibration/expected
    assert n["phase_cpu"] == 2520 and n["phase"] == 4 * (15 * 24 * 15 + 4000)
    assert n["recovery_eval"] == n["recovery_eval_shift"] == 2 * (30 * 24 * 5 + 16000)
    assert n["recovery_grid"] == 2 * 2 * 2 * 3 * 3 * 2 * 2 * 1024


def test_onset_phase_axis():
    """onset = the tick at or before onset_s + phase * 30 ms; random pushes default to a uniform
    phase; specs without the key keep their onsets (and get the derived phase column)."""
    data = _with("push.grid.onset_phase", {"start": 0, "stop": 1, "num": 3, "endpoint": False})
    data["push"]["grid"]["onset_s"] = [0.75, 0.5]
    rec = parse_spec(data).records()
    assert len(rec["push_id"]) == 8 * 2 * 3 * 2
    got = {(round(o, 6), round(p, 6)) for o, p in zip(rec["onset_s"], rec["onset_phase"])}
    assert got == {(0.75, 0.0), (0.76, round(1 / 3, 6)), (0.77, round(2 / 3, 6)),
                   (0.48, 0.0), (0.49, round(1 / 3, 6)), (0.5, round(2 / 3, 6))}
    old = parse_spec(_with("push.grid.onset_s", [0.3, 0.51])).records()
    assert set(np.round(old["onset_s"], 9)) == {0.3, 0.51}
    np.testing.assert_allclose(old["onset_phase"], 0.0, atol=1e-9)
    rnd = parse_spec(_with("push.random", {"n": 200})).records()
    sel = ~rnd["from_grid"]
    assert parse_spec(_with("push.random", {"n": 200})).phase_default
    ph = rnd["onset_phase"][sel]
    assert ph.min() < 0.1 and ph.max() > 0.9 and (ph < 1).all()
    np.testing.assert_allclose(rnd["onset_s"][sel], 0.75 + 0.03 * ph)
    given = parse_spec(_with("push.random", {"n": 5, "onset_s": {"uniform": [0.3, 0.4]}}))
    assert not given.phase_default
    r = given.records()
    assert ((r["onset_s"][~r["from_grid"]] >= 0.3) & (r["onset_s"][~r["from_grid"]] <= 0.4)).all()


def test_expand_grid_random_controller_grid():
    data = _with("push.random", {"n": 3, "impulse_ns": {"uniform": [1.0, 2.0]}})
    data["controller"] = {"grid": {"step_period": [0.25, 0.35]}}
    data["randomize"] = {"link_mass_scale": {"uniform": [0.9, 1.1]}, "gyro_noise_std": 0.01}
    spec = parse_spec(data)
    rec = spec.records()
    # (2 impulses x 4 azimuths + 3 random) x 2 step periods x 2 control settings
    assert len(rec["push_id"]) == (8 + 3) * 2 * 2
    assert set(np.unique(rec["step_period"])) == {0.25, 0.35}
    assert rec["from_grid"].sum() == 8 * 2 * 2
    rnd = rec["impulse_ns"][~rec["from_grid"]]
    assert ((rnd >= 1.0) & (rnd <= 2.0)).all()
    assert ((rec["link_mass_scale"] >= 0.9) & (rec["link_mass_scale"] <= 1.1)).all()
    np.testing.assert_array_equal(rec["impulse_ns"], parse_spec(data).records()["impulse_ns"])
    # One robot draw per push, shared by its 4 settings (2 step periods x off/on): the
    # comparisons between settings are paired. Different pushes get different draws.
    per_setting = rec["link_mass_scale"].reshape(4, 11)
    for block in per_setting[1:]:
        np.testing.assert_array_equal(block, per_setting[0])
    assert len(np.unique(per_setting[0])) == 11


def test_params_json(tmp_path):
    good = tmp_path / "p.json"
    good.write_text(json.dumps({"step_period": 0.25, "eps_forward": math.radians(10)}))
    p = load_params_json(good)
    assert p.step_period == 0.25 and p.leg_length == ControllerParams.paper().leg_length
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"step_periodd": 0.25}))
    with pytest.raises(ValueError, match="unknown field"):
        load_params_json(bad)
    bad.write_text(json.dumps({"step_period": -1.0}))
    with pytest.raises(ValueError, match="step_period must be in"):
        load_params_json(bad)


# --- Running sweeps (one compile shared by this module through make_chunk_fn's cache) ---

@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    manifest = run_sweep(TINY, out, quiet=True, backend="mjx")
    return out, manifest, load(out)


def _assert_same_records(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        if a[k].dtype.kind in "biu":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        else:
            np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, equal_nan=True, err_msg=k)


@pytest.mark.slow
def test_full_run_records_and_manifest(full_run):
    out, manifest, rec = full_run
    assert manifest["complete"] and manifest["n_pushes"] == 8 and manifest["n_chunks"] == 2
    on_disk = json.loads((out / "manifest.json").read_text())
    for key in ("spec", "versions", "git_commit", "devices", "wall_s", "controller_params"):
        assert key in on_disk, key
    for col in ("impulse_ns", "azimuth_deg", "height_m", "onset_s", "fell", "recovery_time_s",
                "step_length_m", "step_width_m", "peak_incl_deg", "capture_point_m"):
        assert rec[col].shape == (8,), col
    np.testing.assert_array_equal(rec["push_id"], np.arange(8))
    # tiny.toml: 0.5 N·s is survived, 3.5 N·s topples the robot, in both directions.
    np.testing.assert_array_equal(rec["fell"], rec["impulse_ns"] > 1.0)


@pytest.mark.slow
def test_exact_replay_matches_the_stored_record_bit_for_bit(full_run, capsys):
    """`tkujax replay --exact` re-runs an MJX record by the sweep's own program at its batch
    shape: a fallen and a survived record equal the stored ones in every column's bits (the
    plain replay, a batch of one, need only agree to rounding)."""
    from tkujax.cli import main
    from tkujax.sweeps.replay import replay

    out, _, rec = full_run
    for i in (int(np.flatnonzero(rec["fell"])[-1]), int(np.flatnonzero(~rec["fell"])[-1])):
        result = replay(out, i, exact=True)
        assert result["exact"] and result["identical"], result["differences"]
        assert set(result["replayed"]) >= {"fell", "peak_incl_deg", "recovery_time_s"}
    assert main(["replay", str(out), "--index", str(i), "--exact"]) == 0
    assert "bit for bit" in capsys.readouterr().out


@pytest.mark.slow
def test_interrupted_sweep_resumes_identically(full_run, tmp_path):
    _, _, reference = full_run
    first = run_sweep(TINY, tmp_path, max_chunks=1, quiet=True, backend="mjx")  # interrupted
    assert not first["complete"] and len(list(tmp_path.glob("chunk_*.npz"))) == 1
    (tmp_path / ".chunk_000001.tmp.npz").write_bytes(b"partial write")  # a crash mid-write
    second = run_sweep(TINY, tmp_path, quiet=True, backend="mjx")
    assert second["complete"] and second["chunks_computed_last_run"] == 1
    _assert_same_records(load(tmp_path), reference)
    again = run_sweep(TINY, tmp_path, quiet=True, backend="mjx")    # finished: not recomputed
    assert again["chunks_computed_last_run"] == 0
    other = load_spec(TINY)
    other.raw["sweep"]["seed"] = 1
    with pytest.raises(SpecError, match="holds another spec's sweep"):
        run_sweep(other, tmp_path, quiet=True, backend="mjx")


def _subprocess_env(**extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop("XLA_FLAGS", None)
    env.update(extra)
    return env


def _assert_same_outcomes(a: dict, b: dict):
    """Same records across device layouts. Sharding changes the per-device batch (4 -> 2), so
    XLA may fuse differently and round differently: equal within 1e-3 for robots that stayed
    up; for robots that fell only the inputs and `fell` are compared, because after a fall the
    tumbling (peak inclination, final foot positions) is chaotic and amplifies 1-ulp changes."""
    np.testing.assert_array_equal(a["fell"], b["fell"])
    up = ~a["fell"].astype(bool)
    for k in a:
        if a[k].dtype.kind in "biu":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        else:
            np.testing.assert_allclose(a[k][up], b[k][up], rtol=1e-3, atol=1e-4, equal_nan=True,
                                       err_msg=k)


@pytest.mark.slow
def test_two_devices_give_the_same_records(full_run, tmp_path):
    _, _, reference = full_run
    code = ("import jax; from tkujax.cli import configure_runtime; configure_runtime(); "
            "assert jax.local_device_count() == 2, jax.devices(); "
            f"from tkujax.sweeps.sweep import run_sweep; "
            f"run_sweep({str(TINY)!r}, {str(tmp_path)!r}, quiet=True, backend='mjx')")
    env = _subprocess_env(XLA_FLAGS="--xla_force_host_platform_device_count=2")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(json.loads((tmp_path / "manifest.json").read_text())["devices"]) == 2
    _assert_same_outcomes(load(tmp_path), reference)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_processes_give_the_same_records(full_run, tmp_path):
    _, _, reference = full_run
    port = _free_port()
    procs = [subprocess.Popen(
        [sys.executable, "-m", "tkujax.cli", "sweep", str(TINY), "--out", str(tmp_path),
         "--process-id", str(i), "--num-processes", "2", "--coordinator", f"127.0.0.1:{port}",
         "--backend", "mjx"],
        env=_subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in range(2)]
    results = [p.communicate(timeout=900) for p in procs]
    for p, (_, err) in zip(procs, results):
        assert p.returncode == 0, err[-3000:]
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["complete"] and manifest["num_processes"] == 2
    _assert_same_outcomes(load(tmp_path), reference)


# --- Capturability bounds against hand-computed values ---

def test_capturability_bounds_by_hand():
    lip = capturability.lip_model()
    p = ControllerParams.paper()
    com_x = lip.com_xy_m[0]
    omega = math.sqrt(9.81 / lip.com_height_m)
    # Default (calibrated) feet: 15.1 x 8.5 cm, centres 2.74 cm BEHIND the ankles, ankles at
    # y = +-4.5 cm, so the toe is 0.0481 m and the heel 0.1029 m from the ankle.
    assert ModelParams().foot_length_m == 0.151 and ModelParams().foot_forward_offset_m == -0.0274
    toe, heel = -0.0274 + 0.0755, 0.0755 + 0.0274
    assert capturability.r_max(lip, 0.0)[0] == pytest.approx(toe - com_x)
    assert capturability.r_max(lip, math.pi)[0] == pytest.approx(heel + com_x)
    assert capturability.r_max(lip, math.pi / 2)[0] == pytest.approx(0.045 + 0.0425)
    corner = math.atan2(0.0875, toe - com_x)
    assert capturability.r_max(lip, corner)[0] == pytest.approx(math.hypot(0.0875, toe - com_x))
    assert capturability.step_reach_m(p) == pytest.approx(2 * math.sqrt(0.22**2 - 0.2**2))
    assert capturability.step_time_s(p) == pytest.approx(0.3 * 0.9)
    j0 = capturability.max_impulse_ns(lip, math.pi / 2, 0, p)[0]
    assert j0 == pytest.approx(4.5 * omega * 0.0875, rel=1e-6)
    q = math.exp(-omega * 0.27)
    d1 = capturability.capture_distance(lip, 0.0, 1, p)[0]
    assert d1 == pytest.approx(toe - com_x + 2 * math.sqrt(0.22**2 - 0.04) * q)
    d_inf = capturability.capture_distance(lip, 0.0, math.inf, p)[0]
    d_200 = capturability.capture_distance(lip, 0.0, 200, p)[0]
    assert d_inf == pytest.approx(d_200, rel=1e-9)
    assert capturability.capture_point_shift_m(lip, 0.5) == pytest.approx(0.5 / (4.5 * omega))


@pytest.mark.slow
def test_map_boundary_matches_individual_rollouts(full_run):
    """The tiny sweep's map puts the fall boundary where independent single rollouts (MuJoCo C
    backend, one push at a time) put it."""
    from tkujax.sim.rollout_mujoco import simulate_mujoco
    from tkujax.analysis.maps import make_maps, max_recoverable_impulse
    from tkujax.sim.push import make_push, stack_pushes
    from tkujax.sim.rollout_mjx import RolloutConfig

    out, _, rec = full_run
    result = make_maps(out)
    for f in result["files"]:
        assert Path(f).stat().st_size > 5000, f
    assert "J_0 theory" in Path(result["summary"]).read_text()
    config = RolloutConfig(duration_s=1.5)
    for control in (False, True):
        azs, jmax = max_recoverable_impulse(rec, control)
        for az, j in zip(azs, jmax):
            fell = []
            for impulse in (0.5, 3.5):
                _, o = simulate_mujoco(stack_pushes([make_push(impulse, az, onset_s=0.3)]),
                                       np.array([float(control)]), ControllerParams.paper(),
                                       config=config)
                fell.append(bool(o["fell"][0]))
            expected = 0.0 if fell[0] else (0.5 if fell[1] else 3.5)
            assert j == expected, (control, az, fell)


@pytest.mark.slow
def test_auto_backend_is_mujoco_c_on_cpu_and_agrees_with_mjx(full_run, tmp_path):
    """On a CPU, "auto" runs MuJoCo C; its outcomes agree with the MJX sweep (>= 95 %: all 8
    here, the tiny sweep's impulses being far from the fall boundary)."""
    from tkujax.sweeps.sweep import choose_backend

    _, _, reference = full_run
    manifest = run_sweep(TINY, tmp_path, quiet=True)
    assert manifest["backend"] == "mujoco"
    rec = load(tmp_path)
    agree = np.mean(rec["fell"] == reference["fell"])
    assert agree >= 0.95
    np.testing.assert_allclose(rec["step_length_m"], reference["step_length_m"], atol=0.01)
    randomized = _with("randomize", {"link_mass_scale": {"uniform": [0.9, 1.1]}})
    assert choose_backend("auto", parse_spec(randomized)) == "mjx"
    with pytest.raises(SpecError, match="cannot vary"):
        choose_backend("mujoco", parse_spec(randomized))


# --- Controller parameters are traced inputs: one compile per batch shape ---

@pytest.mark.slow
def test_a_second_parameter_set_does_not_recompile(full_run, tmp_path, compiles):
    """The tiny sweep again with other controller values (a tuned set, say): same compiled chunk
    (JAX lowers no program at all), different records."""
    other = dataclasses.replace(ControllerParams.paper(), eps_forward=math.radians(8.0),
                                step_period=0.25)
    compiles.reset()
    run_sweep(TINY, tmp_path / "other", params=other, quiet=True, backend="mjx")
    assert compiles.count == 0, f"a new controller parameter set compiled {compiles.names}"
    rec = load(tmp_path / "other")
    _, _, first = full_run
    assert not np.allclose(rec["capture_point_m"], first["capture_point_m"], equal_nan=True)


@pytest.mark.slow
def test_persistent_cache_serves_a_new_process(full_run):
    """A fresh process compiling the same chunk reads it from the persistent cache (counted by
    JAX's own cache-hit event) instead of compiling again."""
    code = (
        "import os, jax, jax.numpy as jnp, numpy as np\n"
        "jax.config.update('jax_compilation_cache_dir', os.environ['CACHE'])\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0)\n"
        "jax.config.update('jax_persistent_cache_min_entry_size_bytes', -1)\n"
        "hits = []\n"
        "jax.monitoring.register_event_listener("
        "lambda e, **k: hits.append(e) if e == '/jax/compilation_cache/cache_hits' else None)\n"
        "from tkujax.control import ControllerParams\n"
        "from tkujax.dialects.sweep_spec import load_spec\n"
        "from tkujax.sweeps.sweep import make_chunk_fn, traced_params, record_inputs\n"
        f"spec = load_spec({str(TINY)!r})\n"
        "recs = record_inputs(spec)\n"
        "keys_in = [k for k in recs if k not in ('push_id', 'from_grid')]\n"
        "from jax.sharding import Mesh, NamedSharding, PartitionSpec\n"
        "sh = NamedSharding(Mesh(np.array(jax.local_devices()), ('push',)), "
        "PartitionSpec('push'))\n"
        "batch = {k: jax.device_put(np.asarray(recs[k][:4], np.float32), sh) for k in keys_in}\n"
        "keys = jax.device_put(jax.random.split(jax.random.PRNGKey(0), 4), sh)\n"
        "fn = make_chunk_fn((), spec.duration_s, None)\n"
        "fn.lower(batch, keys, traced_params(ControllerParams.paper())).compile()\n"
        "print('HITS', len(hits))\n")
    cache = jax.config.jax_compilation_cache_dir
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "CACHE": cache}, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    hits = int(res.stdout.split("HITS")[-1])
    assert hits >= 1, res.stdout
