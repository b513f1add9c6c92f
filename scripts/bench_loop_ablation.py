"""The closed loop's variants (tkujax.bench.profile's names) and raw MJX, compiled one after the
other in one process, each timed as the median of 5 calls: ms per 15 physics steps (one tick).

    python scripts/bench_loop_ablation.py BATCH 'NAME@SECONDS;...'   (writes $OUT/seqab_BATCH.json)

NAME: a tkujax.bench.profile variant ("full", "physics_only", "no_records", "raw",
"unroll_substeps=5", ...) or "benchraw" (the bench's raw-MJX row: the keyframe state passed
as an argument).
Why not `tkujax bench --profile`: it compiles its variants in parallel threads, and on an H100
its raw loop then ran 13.6-13.7 ms per tick against 11.9 compiled alone (batch 1,024). The cause
is not pinned down: a flat raw loop compiled after the closed loop in the same process was as
slow (13.5), with GEMM autotuning off too, while the bench's own raw row stayed at 12.0.
"""

import json
import os
import sys
import time
from pathlib import Path

import jax

from tkujax.bench import push_batch, raw_program, timed, traced_paper_params, variant_loop_fn
from tkujax.sim import physics


def main() -> None:
    OUT = Path(os.environ.get("OUT", "/tmp/out"))
    batch, names = int(sys.argv[1]), sys.argv[2].split(";")
    params = traced_paper_params()
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    rows = []
    for name in names:
        variant, seconds = name.split("@")
        n_steps = int(round(float(seconds) / physics.host_model().opt.timestep))
        if variant == "benchraw":
            fn, state = raw_program(batch, n_steps)
            args = (state,)
        else:
            fn, args = variant_loop_fn(variant, float(seconds)), (recs, keys, params)
        t0 = time.time()
        exe = fn.lower(*args).compile()
        compile_s = time.time() - t0
        sec = timed(lambda exe=exe, args=args: exe(*args), 5)
        rows.append(
            dict(
                name=name,
                batch=batch,
                compile_s=round(compile_s, 1),
                seconds=sec,
                ms_per_15_steps=1e3 * sec / n_steps * 15,
            )
        )
        print(json.dumps(rows[-1]), flush=True)
        (OUT / f"seqab_{batch}.json").write_text(
            json.dumps(dict(device=jax.devices()[0].device_kind, rows=rows), indent=1)
        )


if __name__ == "__main__":
    main()
