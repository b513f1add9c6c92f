"""`tkujax bench` on a CPU with tiny sizes: valid JSON, every stage's status and wall time, the
JSON rewritten after each stage, a failing stage recorded while the next runs, the budget, the
CLI's modes, the profile's table. Speeds are reported, never asserted. Batch 4 x 1.5 s matches
tests/test_sweep.py's tiny sweep, so the closed-loop program compiled there is reused through
make_chunk_fn's cache (and the persistent cache)."""

import json

import pytest

from tkujax.bench import MODES, parse_grad_variants, run_bench, runner, stages, summary_markdown


@pytest.mark.slow
def test_bench_end_to_end(tmp_path):
    out = tmp_path / "bench.json"
    result = run_bench(out, batches=(4,), duration_s=1.5, raw_steps=5, repeats=1, cpu_batch=4,
                       grad_batch=None, compile_batch=0, scaling_batch=None)
    on_disk = json.loads(out.read_text())
    assert on_disk == json.loads(json.dumps(result))
    for section in ("raw", "closed_loop"):
        (row,) = on_disk[section]
        assert row["batch"] == 4 and row["seconds"] > 0 and row["physics_steps_per_s"] > 0
    assert on_disk["closed_loop"][0]["pushes_per_s"] > 0
    assert on_disk["cpu_peer"]["batch"] == 4 and on_disk["cpu_peer"]["pushes_per_s"] > 0
    assert on_disk["versions"]["mujoco"] and on_disk["device"]
    assert [s["name"] for s in on_disk["stages"]] == ["raw_4", "closed_loop_4", "cpu_peer"]
    assert all(s["status"] == "done" and s["wall_s"] > 0 for s in on_disk["stages"])
    # each wall is rounded to 0.01 s: the sum may pass the total by that much per stage
    assert on_disk["complete"] and on_disk["total_wall_s"] >= sum(
        s["wall_s"] for s in on_disk["stages"]) - 0.01 * len(on_disk["stages"])
    md = out.with_suffix(".md").read_text()
    assert "| 4 |" in md and "CPU peer" in md and "Total wall time" in md


def test_gradient_step_line_says_when_its_first_call_read_the_cache():
    base = dict(device_kind="cpu", n_devices=1, versions={}, repeats=1, duration_s=1.5, raw=[],
                closed_loop=[])
    step = dict(batch=8, duration_s=1.5, n_params=8, remat="substep", float64=False,
                seconds=2.0, pushes_per_s=4.0, first_call_s=38.0, peak_device_bytes=None,
                grad_finite=True)
    cold = summary_markdown(dict(base, gradient_step=dict(step, first_call_cache_hits=0)))
    warm = summary_markdown(dict(base, gradient_step=dict(step, first_call_cache_hits=1)))
    assert "first call (compile) 38 s," in cold and "persistent cache" not in cold
    assert "first call (compile) 38 s (read from the persistent cache" in warm


def _fake_stages(monkeypatch, seen: list, out):
    """Instant stand-ins for the measuring functions; each checks that the JSON on disk
    already holds every stage before it (written incrementally)."""
    def on_disk_stages():
        return [s["name"] for s in json.loads(out.read_text())["stages"]] if out.exists() else []

    def raw(b, steps, repeats):
        seen.append((f"raw_{b}", on_disk_stages()))
        return dict(batch=b, steps=steps, seconds=1.0, physics_steps_per_s=100.0 * b)

    def closed(b, duration, repeats, compiled=None, unroll_substeps=None):
        u = unroll_substeps or 1
        seen.append((f"closed_loop_{b}", on_disk_stages()))
        return dict(batch=b, duration_s=duration, unroll_substeps=u, seconds=1.0,
                    pushes_per_s=float(b) * u, physics_steps_per_s=80.0 * b * u)

    def cpu(b, duration, repeats):
        seen.append(("cpu_peer", on_disk_stages()))
        raise RuntimeError("no MuJoCo C here")

    monkeypatch.setattr(stages, "raw_stepping", raw)
    monkeypatch.setattr(stages, "closed_loop", closed)
    monkeypatch.setattr(stages, "cpu_peer", cpu)


def test_stages_written_incrementally_failure_recorded(tmp_path, monkeypatch, capsys):
    out = tmp_path / "b.json"
    seen = []
    _fake_stages(monkeypatch, seen, out)
    result = run_bench(out, batches=(8, 16), compile_batch=0, cpu_batch=4)
    assert seen == [("raw_8", []), ("closed_loop_8", ["raw_8"]),
                    ("raw_16", ["raw_8", "closed_loop_8"]),
                    ("closed_loop_16", ["raw_8", "closed_loop_8", "raw_16"]),
                    ("cpu_peer", ["raw_8", "closed_loop_8", "raw_16", "closed_loop_16"])]
    on_disk = json.loads(out.read_text())
    assert on_disk == json.loads(json.dumps(result))
    status = {s["name"]: s["status"] for s in on_disk["stages"]}
    assert status == {"raw_8": "done", "closed_loop_8": "done", "raw_16": "done",
                      "closed_loop_16": "done", "cpu_peer": "failed"}
    assert "no MuJoCo C here" in on_disk["stages"][-1]["error"]
    assert on_disk["complete"] and "total_wall_s" in on_disk
    err = capsys.readouterr().err
    assert "closed_loop_16: start" in err and "cpu_peer: FAILED" in err
    md = out.with_suffix(".md").read_text()
    assert "| 16 | 1 | 1.6e+03 | 1.28e+03 | 16 | 0.80 |" in md and "| cpu_peer | failed" in md


def test_resume_runs_only_the_unfinished_stages(tmp_path, monkeypatch):
    """A run cut by its budget, resumed: the finished stages are kept (not run again), the
    skipped and failed ones run, total_wall_s adds the runs up; other settings are refused by
    name."""
    out = tmp_path / "b.json"
    seen = []
    _fake_stages(monkeypatch, seen, out)
    clock = iter(range(0, 10_000, 10))     # each perf_counter() call: 10 s later; a stage
    monkeypatch.setattr(runner.time, "perf_counter", lambda: float(next(clock)))  # takes 4
    run_bench(out, batches=(8, 16), compile_batch=0, cpu_batch=4, budget_s=55, quiet=True)
    first = json.loads(out.read_text())
    status = {st["name"]: st["status"] for st in first["stages"]}
    assert status == {"raw_8": "done", "closed_loop_8": "done", "raw_16": "skipped",
                      "closed_loop_16": "skipped", "cpu_peer": "skipped"}
    seen.clear()
    run_bench(out, batches=(8, 16), compile_batch=0, cpu_batch=4, quiet=True, resume=True)
    second = json.loads(out.read_text())
    assert [name for name, _ in seen] == ["raw_16", "closed_loop_16", "cpu_peer"]
    assert [(st["name"], st["status"]) for st in second["stages"]] == [
        ("raw_8", "done"), ("closed_loop_8", "done"), ("raw_16", "done"),
        ("closed_loop_16", "done"), ("cpu_peer", "failed")]
    assert [r["batch"] for r in second["raw"]] == [8, 16]
    assert [r["batch"] for r in second["closed_loop"]] == [8, 16]
    assert second["runs"] == 2 and second["complete"]
    assert second["total_wall_s"] > first["total_wall_s"] > 0
    assert "over 2 runs (resumed)" in out.with_suffix(".md").read_text()
    seen.clear()
    run_bench(out, batches=(8, 16), compile_batch=0, cpu_batch=4, quiet=True, resume=True)
    assert [name for name, _ in seen] == ["cpu_peer"]       # only the failed stage again
    with pytest.raises(ValueError, match="batches was \\[8, 16\\], now \\[8\\]"):
        run_bench(out, batches=(8,), compile_batch=0, cpu_batch=4, quiet=True, resume=True)
    fresh = tmp_path / "fresh.json"
    run_bench(fresh, batches=(8,), compile_batch=0, cpu_batch=0, quiet=True, resume=True)
    assert "runs" not in json.loads(fresh.read_text())       # nothing to resume: a new run


def test_loop_structures_timed_side_by_side(tmp_path, monkeypatch):
    """--unroll-substeps 1,15: one raw run per batch, one closed loop per structure, each in
    its own stage and row; a bad structure fails before any stage runs."""
    out = tmp_path / "b.json"
    seen = []
    _fake_stages(monkeypatch, seen, out)
    run_bench(out, batches=(8,), compile_batch=0, cpu_batch=0, unroll_substeps=(1, 15),
              quiet=True)
    on_disk = json.loads(out.read_text())
    assert [st["name"] for st in on_disk["stages"]] == ["raw_8", "closed_loop_8_unroll1",
                                                        "closed_loop_8_unroll15"]
    assert len(seen) == 3
    assert on_disk["unroll_substeps"] == [1, 15]
    assert [r["unroll_substeps"] for r in on_disk["closed_loop"]] == [1, 15]
    md = out.with_suffix(".md").read_text()
    assert "| 8 | 1 | 800 | 640 | 8 | 0.80 |" in md
    assert "| 8 | 15 | 800 | 9.6e+03 | 120 | 12.00 |" in md
    with pytest.raises(ValueError, match="unroll_substeps"):
        run_bench(tmp_path / "c.json", batches=(8,), compile_batch=0, cpu_batch=0,
                  unroll_substeps=(0,))
    assert not (tmp_path / "c.json").exists()


def test_budget_skips_later_stages(tmp_path, monkeypatch):
    out = tmp_path / "b.json"
    _fake_stages(monkeypatch, [], out)
    run_bench(out, batches=(8,), compile_batch=0, cpu_batch=0, budget_s=0.0, quiet=True)
    on_disk = json.loads(out.read_text())
    assert [s["status"] for s in on_disk["stages"]] == ["skipped", "skipped"]
    assert on_disk["raw"] == [] and on_disk["complete"]
    assert "skipped" in summary_markdown(on_disk)


def test_unknown_stage_and_variant_fail_early(tmp_path):
    with pytest.raises(ValueError, match="unknown bench stage"):
        run_bench(tmp_path / "b.json", stages=("warp",))
    with pytest.raises(ValueError, match="unknown profile variant"):
        run_bench(tmp_path / "b.json", stages=("profile",), profile_batches=(2,),
                  profile_variants=("no_gravity",))
    assert not (tmp_path / "b.json").exists()


@pytest.mark.parametrize("kw, message", [
    (dict(batches=(1024, -5)), r"batches \(each\) must be an integer in \[1, 10000000\], got -5"),
    (dict(batches=(2.5,)), r"batches \(each\).*got 2.5"),
    (dict(repeats=0), r"repeats must be an integer in \[1, 100000\], got 0"),
    (dict(duration_s=-1.0), r"duration_s must be in \(0, 60\] seconds, got -1.0"),
    (dict(cpu_batch=-1), r"cpu_batch must be an integer in \[0, 10000000\], got -1"),
    (dict(profile_batches=(0,)), r"profile_batches \(each\).*got 0"),
    (dict(compile_workers=0), r"compile_workers must be an integer in \[1, 256\], got 0"),
    (dict(budget_s=-1), r"budget_s must be in \[0, 1e6\] seconds, got -1"),
])
def test_bad_sizes_fail_before_any_stage_naming_the_argument(tmp_path, kw, message):
    with pytest.raises(ValueError, match=message):
        run_bench(tmp_path / "b.json", **kw)
    assert not (tmp_path / "b.json").exists()


def test_cli_names_the_option_of_a_bad_integer_list(tmp_path, capsys):
    from tkujax.cli import main as cli_main

    def main(argv):
        return cli_main(["bench", *argv])

    assert main(["--out", str(tmp_path / "b.json"), "--batches", "0,abc"]) == 2
    assert "--batches: a comma list of integers, got '0,abc'" in capsys.readouterr().err
    assert main(["--out", str(tmp_path / "b.json"), "--batches", "-5"]) == 2
    assert "batches (each) must be an integer in [1, 10000000], got -5" in \
        capsys.readouterr().err
    assert main(["--out", str(tmp_path / "b.json"), "--variant", "speed=9"]) == 2
    assert "--variant 'speed=9': expected KEY=VALUE" in capsys.readouterr().err
    assert main(["--out", str(tmp_path / "b.json"), "--variant", "unroll_substeps=0"]) == 2
    assert "unroll_substeps must be >= 1, got [0]" in capsys.readouterr().err


def test_parse_grad_variants():
    assert parse_grad_variants("remat=tick;remat=nested,unroll_substeps=3;autotune=0;"
                               "llvm=0,ptxas=0") == [
        {"remat": "tick"}, {"remat": "nested", "unroll_substeps": 3}, {"autotune": 0},
        {"llvm": 0, "ptxas": 0}]
    for bad in ("remat=sometimes", "unroll_ticks=x", "speed=9", "remat", "llvm=1", "ptxas=x"):
        with pytest.raises(ValueError):
            parse_grad_variants(bad)


def test_gradient_compile_variants_pass_their_xla_options(monkeypatch):
    """Each variant's XLA options reach the compile (and ask for the step's time), its rollout
    options stay rollout options; on a backend other than the GPU the GPU options are skipped
    and recorded as such."""
    import jax

    import tkujax.studies.tune.benchmark as tb

    calls = []

    def fake(batch, duration_s, compiler_options=None, rollout_options=None, cached=True,
             step_repeats=0):
        calls.append((compiler_options, rollout_options, step_repeats))
        return dict(batch=batch, cold_s=1.0)

    monkeypatch.setattr(tb, "gradient_compile_times", fake)
    variants = [{"remat": "substep"}, {"remat": "substep", "llvm": 0, "ptxas": 0},
                {"autotune": 0}]
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    rows = stages.gradient_compile(8, 0.3, variants)
    assert calls == [
        (None, {"remat": "substep"}, 0),
        ({"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True,
          "xla_gpu_disable_gpuasm_optimizations": True}, {"remat": "substep"}, 3),
        ({"xla_gpu_autotune_level": 0}, {}, 3)]
    assert rows[1]["variant"] == {"remat": "substep", "llvm": 0, "ptxas": 0}
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    calls.clear()
    rows = stages.gradient_compile(8, 0.3, variants)
    assert calls == [(None, {"remat": "substep"}, 0)]
    assert rows[1]["skipped"] == "llvm, ptxas: GPU only" and rows[2]["skipped"]


def test_cli_modes(tmp_path, monkeypatch):
    """The CLI's default and --full sizes, --stages, --profile and the --variant options reach
    run_bench's BenchConfig."""
    import dataclasses

    from tkujax.bench import runner
    from tkujax.cli import main as cli_main

    def main(argv):
        return cli_main(["bench", *argv])

    calls = []

    def fake_run_bench(out, config, resume=False):
        calls.append(dict(dataclasses.asdict(config), resume=resume))
        res = dict(device_kind="cpu", n_devices=1, versions={}, repeats=config.repeats,
                   duration_s=config.duration_s, raw=[], closed_loop=[], stages=[],
                   total_wall_s=0.0, complete=True)
        (tmp_path / "b.json").write_text(json.dumps(res))
        return res

    monkeypatch.setattr(runner, "run_bench", fake_run_bench)
    out = str(tmp_path / "b.json")
    assert main(["--out", out]) == 0
    assert main(["--out", out, "--full", "--repeats", "5"]) == 0
    assert main(["--out", out, "--stages", "profile", "--variant", "profile_batches=2,4",
                 "--variant", "profile_variants=no_noise;raw", "--variant", "trace_dir=tr"]) == 0
    assert main(["--out", out, "--stages", "gradient_compile", "--variant",
                 "grad_variants=remat=tick_nocse", "--variant", "grad_cached=0",
                 "--budget-s", "300"]) == 0
    assert main(["--out", out, "--variant", "unroll_substeps=1,15"]) == 0
    assert main(["--out", out, "--full", "--resume"]) == 0
    assert calls.pop()["resume"] is True
    default, full, prof, grad, unroll = calls
    assert default["unroll_substeps"] is None and unroll["unroll_substeps"] == (1, 15)
    assert default["batches"] == MODES["default"]["batches"] == (1024, 65536)
    assert default["grad_batch"] is None and default["grad_compile_batch"] == 0
    assert default["stages"] is None and default["profile_batches"] == ()
    assert default["resume"] is False
    assert full["batches"] == (1024, 4096, 16384, 65536) and full["repeats"] == 5
    assert full["grad_batch"] == 1024 and full["mode"] == "full"
    assert prof["stages"] == ("profile",) and prof["profile_batches"] == (2, 4)
    assert prof["profile_variants"] == ("no_noise", "raw") and prof["trace_dir"] == "tr"
    assert grad["grad_variants"] == [{"remat": "tick_nocse"}] and grad["grad_cached"] is False
    assert grad["grad_compile_batch"] == MODES["full"]["grad_compile_batch"]
    assert grad["budget_s"] == 300
    assert main(["--out", out, "--stages", "gradient_step,gradient_compile"]) == 0
    assert calls[-1]["grad_batch"] == 1024 and calls[-1]["grad_compile_batch"] == 256
    assert calls[-1]["grad_variants"] is None
    assert main(["--out", out, "--profile"]) == 0
    assert calls[-1]["profile_batches"] == (1024, 65536)


@pytest.mark.slow
def test_profile_on_cpu(tmp_path):
    """The profile's table at batch 2 (3 ticks): the full loop and one ablation, plus the
    controller's parts and a jax.profiler trace (each variant alone:
    test_profile_variants_step_every_robot)."""
    out = tmp_path / "p.json"
    run_bench(out, stages=("profile",), profile_batches=(2,), profile_duration_s=0.09,
              profile_variants=("no_records",), compile_workers=2,
              trace_dir=tmp_path / "trace", quiet=True)
    on_disk = json.loads(out.read_text())
    assert [s["status"] for s in on_disk["stages"]] == ["done"]
    (p,) = on_disk["profile"]
    assert p["batch"] == 2 and p["n_ticks"] == 3
    rows = {r["variant"]: r for r in p["rows"]}
    assert set(rows) == {"full", "no_records"}
    assert rows["full"]["cost_ms_per_tick"] == 0.0 and rows["full"]["share_of_full"] == 0.0
    assert all(r["ms_per_tick"] > 0 for r in rows.values())
    parts = {c["part"] for c in p["controller_parts"]}
    assert {"kalman", "detection", "cpg", "ik", "controller_step"} <= parts
    assert any((tmp_path / "trace").rglob("*.xplane.pb"))
    md = out.with_suffix(".md").read_text()
    assert "Closed-loop profile at batch 2" in md and "| no_records |" in md


def test_gradient_bench_spec_parses():
    """The gradient benchmarks' tune spec is accepted (TUNABLE's recovery extensions start on
    their range bounds, which a spec refuses: the paper's 8 are benchmarked), and the rollout
    options reach the TuneProblem's RolloutConfig."""
    from tkujax.studies.tune.benchmark import bench_spec
    from tkujax.studies.tune.problem import TuneProblem
    from tkujax.studies.tune.reparam import PAPER_TUNABLE

    for jitter in (False, True):
        spec = bench_spec(8, 0.45, "tick_nocse", jitter=jitter)
        assert spec.reparam().size == len(PAPER_TUNABLE) == 8
    problem = TuneProblem(spec.reparam(), spec.base_params(), spec.loss, 0.45, "tick_nocse",
                          rollout_options=dict(unroll_substeps=3))
    assert problem.config.program.remat == "tick_nocse"
    assert problem.config.program.unroll_substeps == 3


@pytest.mark.parametrize("variant", ["raw", "physics_only", "shared_model", "no_controller"])
def test_profile_variants_step_every_robot(variant):
    """Under vmap a variant whose output does not depend on the record would step one robot
    and broadcast it: every variant's physics carries the batch axis."""
    import jax

    from tkujax.bench import push_batch, traced_paper_params
    from tkujax.bench.profile import variant_loop_fn
    from tkujax.sim import physics

    batch, nq = 3, physics.host_model().nq
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    # .trace, not make_jaxpr: the loop is a jit with compiler options, which JAX refuses to nest
    text = str(variant_loop_fn(variant, 0.06).trace(recs, keys, traced_paper_params()).jaxpr)
    assert f"f32[{batch},{nq}]" in text


def test_profile_rows_written_as_measured(tmp_path, monkeypatch):
    """The profile stage's JSON holds each row as soon as it is measured (fakes: no compile)."""
    from tkujax.bench import profile

    out = tmp_path / "p.json"
    seen = []

    def fake_profile(batch, duration_s, repeats, variants, workers, trace_dir, log, into,
                     on_update):
        into.update(batch=batch, duration_s=duration_s, n_ticks=10, substeps=15,
                    repeats=repeats, rows=[])
        for i, v in enumerate(("full", "raw")):
            into["rows"].append(dict(variant=v, seconds=1.0 - 0.5 * i, ms_per_tick=100 - 50 * i,
                                     cost_ms_per_tick=50.0 * i, share_of_full=0.5 * i))
            on_update()
            seen.append([r["variant"] for r in json.loads(out.read_text())["profile"][0]["rows"]])
        raise RuntimeError("cut short")

    monkeypatch.setattr(profile, "profile_closed_loop", fake_profile)
    run_bench(out, stages=("profile",), profile_batches=(8,), quiet=True)
    assert seen == [["full"], ["full", "raw"]]
    on_disk = json.loads(out.read_text())
    assert on_disk["stages"][0]["status"] == "failed"
    assert "| raw | 50.000 | +50.000 | +50.0 % |" in out.with_suffix(".md").read_text()
