"""Does `tkujax replay --exact` reproduce a GPU sweep's records bit for bit? (results/scale/)

Runs the first chunk of each sweep spec given (MJX), then replays K random records of it twice:
exact (the sweep's own program at its shape, `tkujax.sweeps.replay_exact`) and plain (the
record alone, a batch of one). Counts, for each, the records whose every stored outcome column
equals the replayed one bit for bit, and the plain replays whose fall outcome agrees. Writes
OUT.json.

    python scripts/replay_exact_check.py OUT.json specs/sweep/stability_map.toml ... --k 8
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tkujax.cli.runtime import configure_runtime


def check(spec: str, work: Path, k: int, seed: int) -> dict:
    import jax

    from tkujax.sweeps import chunks
    from tkujax.sweeps.replay import replay
    from tkujax.sweeps.replay_exact import bitwise_differences

    out = work / Path(spec).stem
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "tkujax.cli", "sweep", spec, "--out", str(out),
                    "--backend", "mjx", "--max-chunks", "1"], check=True,
                   stdout=subprocess.DEVNULL)
    sweep_s = time.perf_counter() - t0
    manifest = chunks.read_manifest(out)
    size = min(int(manifest["chunk_size"]), int(manifest["n_pushes"]))
    picks = sorted(int(i) for i in np.random.default_rng(seed).choice(size, k, replace=False))
    rows = []
    for i in picks:
        exact = replay(out, i, exact=True)
        plain = replay(out, i)
        rows.append(dict(index=i, fell=bool(exact["stored"]["fell"]),
                         exact_identical=bool(exact["identical"]),
                         exact_differences={c: list(v) for c, v in exact["differences"].items()},
                         plain_same_outcome=bool(plain["same_outcome"]),
                         plain_bit_identical=not bitwise_differences(plain["stored"],
                                                                     plain["replayed"])))
    return dict(spec=spec, decisions=manifest.get("decisions", "full"),
                chunk_size=int(manifest["chunk_size"]), sweep_s=round(sweep_s, 1),
                replays=len(rows), exact_identical=sum(r["exact_identical"] for r in rows),
                plain_bit_identical=sum(r["plain_bit_identical"] for r in rows),
                plain_same_outcome=sum(r["plain_same_outcome"] for r in rows),
                device=str(jax.devices()[0].device_kind), rows=rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("specs", nargs="+")
    ap.add_argument("--k", type=int, default=8, help="records replayed per spec")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default="/tmp/replay_exact_check")
    args = ap.parse_args(argv)
    configure_runtime()
    res = [check(s, Path(args.work), args.k, args.seed) for s in args.specs]
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps([{k: v for k, v in r.items() if k != "rows"} for r in res], indent=1))


if __name__ == "__main__":
    main()
