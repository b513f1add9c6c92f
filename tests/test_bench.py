"""`tkujax bench` runs end to end on a CPU with tiny sizes and writes valid JSON (speeds are
reported, never asserted). Batch 4 x 1.5 s matches tests/test_sweep.py's tiny sweep, so the
closed-loop program compiled there is reused through make_chunk_fn's cache."""

import json

import pytest

from tkujax.bench import run_bench


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
    md = out.with_suffix(".md").read_text()
    assert "| 4 |" in md and "CPU peer" in md
