"""MJX's tree passes against tkujax.sim.tree_passes (RolloutConfig.tree_passes), in the tuner's
gradient and in the sweeps' closed loop (results/bench/h200_tree_passes_compact.jsonl).

  python scripts/bench_tree_passes.py grad PASSES BATCH DURATION OUT.jsonl
  python scripts/bench_tree_passes.py fwd PASSES BATCHES DURATION OUT.jsonl

PASSES: mjx or compact. One program per process, into an empty persistent cache.
  grad: the tuning gradient's cold compile (trace + lower, and XLA), its StableHLO size, and
        the compiled gradient's median step time (3 calls).
  fwd:  the sweeps' closed-loop chunk (the paper's controller) at each batch of BATCHES
        (comma list): cold compile and the median of 2 timed runs, and raw MJX steps holding
        the stand targets (mjx.step, MJX's own passes) beside it.

The committed rows were run as the module grew (the `kinematics` key of each row names the
RolloutConfig field then, `tree_passes` now):
  h200_kinematics_loop.jsonl: the first design, kinematics alone in a loop over the tree's
      depth ("level");
  h200_tree_passes_compact.jsonl: kinematics alone by doubling ("compact": the gradient row
      and the next two), MJX's passes on the same machine (the two "mjx" rows), then
      kinematics, com_vel and rne with the tree's sums as 0/1 matrix products (the next two
      rows: fwd at 1,024, and at 65,536 on another start), then as gathers and sums (the last
      two rows, the code now, a third start).
"""

import dataclasses
import json
import sys
import time

import jax

from tkujax import bench
from tkujax.sim import physics, rollout_mjx
from tkujax.sweeps import sweep
from tkujax.sweeps.compile_cache import fresh_compilation_cache


def grad(kin: str, batch: int, duration_s: float) -> list[dict]:
    from tkujax.studies.tune.benchmark import gradient_compile_times

    row = gradient_compile_times(
        batch, duration_s, rollout_options=dict(tree_passes=kin), cached=False, step_repeats=3
    )
    return [row]


def fwd(kin: str, batches: list[int], duration_s: float) -> list[dict]:
    # The sweeps build RolloutConfig(...) with the fields they set; the passes ride in as this
    # class's default for the run.
    base = rollout_mjx.RolloutConfig

    @dataclasses.dataclass(frozen=True)
    class Config(base):
        tree_passes: str = kin

    sweep.RolloutConfig = Config
    rows = []
    for b in batches:
        with fresh_compilation_cache():
            c = bench.compile_times(b, duration_s, keep=(keep := {}))
        run = bench.closed_loop(b, duration_s, 2, compiled=next(iter(keep.values())))
        steps = int(round(duration_s / physics.host_model().opt.timestep))
        raw = bench.raw_stepping(b, steps, 2)
        rows.append(
            dict(
                batch=b,
                compile_cold_s=round(c["cold_s"], 2),
                pushes_per_s=round(run["pushes_per_s"], 1),
                closed_steps_per_s=run["physics_steps_per_s"],
                raw_steps_per_s=raw["physics_steps_per_s"],
                closed_over_raw=round(run["physics_steps_per_s"] / raw["physics_steps_per_s"], 3),
            )
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    what, kin, sizes, duration_s, out = sys.argv[1:6]
    t0 = time.perf_counter()
    if what == "grad":
        rows = grad(kin, int(sizes), float(duration_s))
    elif what == "fwd":
        rows = fwd(kin, [int(b) for b in sizes.split(",")], float(duration_s))
    else:
        raise SystemExit(f"grad or fwd, got {what!r}")
    with open(out, "a") as f:
        for r in rows:
            r = dict(
                r,
                what=what,
                tree_passes=kin,
                device=str(jax.devices()[0].device_kind),
                wall_s=round(time.perf_counter() - t0, 1),
            )
            print(json.dumps(r), flush=True)
            f.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
