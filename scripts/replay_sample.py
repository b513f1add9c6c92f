"""Do a GPU sweep's stored outcomes still hold on the current code? (results/sweeps/README.md)

Replays N random records of a committed sweep folder with `tkujax.sweeps.replay.replay` (the
sweeps' own program, `make_chunk_fn`, one push at a time on this machine) and counts the records
whose fall outcome (fell, diverged) equals the stored one; OUT.json keeps the counts and the
records that differ.

    python scripts/replay_sample.py RUN_DIR N SEED OUT.json
"""

import json
import subprocess
import sys
import time

import jax
import numpy as np

from tkujax.sweeps.replay import replay


def main(run_dir: str, n: int, seed: int, out: str) -> None:
    # The code replayed: HEAD when the run starts, and whether the tree had changes beside it.
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout
    dirty = bool(
        subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True
        ).stdout.strip()
    )
    manifest = json.load(open(f"{run_dir}/manifest.json"))
    picks = np.random.default_rng(seed).choice(manifest["n_pushes"], n, replace=False)
    rows, t0 = [], time.perf_counter()
    for k, i in enumerate(sorted(int(i) for i in picks)):
        r = replay(run_dir, i)
        rows.append(
            dict(
                index=i,
                same_outcome=bool(r["same_outcome"]),
                stored_fell=bool(r["stored"]["fell"]),
                replayed_fell=bool(r["replayed"]["fell"]),
                control=bool(r["stored"].get("control", True)),
                impulse_ns=float(r["stored"].get("impulse_ns", np.nan)),
                differences=sorted(r["differences"]),
            )
        )
        if (k + 1) % 100 == 0:
            print(
                f"{k + 1}/{n}: {sum(x['same_outcome'] for x in rows)} same, "
                f"{time.perf_counter() - t0:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    doc = dict(
        run_dir=run_dir,
        sweep_commit=manifest.get("git_commit"),
        sweep_devices=manifest.get("devices"),
        replay_commit=head.strip(),
        replay_tree_dirty=dirty,
        replay_device=str(jax.devices()[0]),
        n=n,
        seed=seed,
        same_outcome=sum(x["same_outcome"] for x in rows),
        stored_falls=sum(x["stored_fell"] for x in rows),
        replayed_falls=sum(x["replayed_fell"] for x in rows),
        wall_s=round(time.perf_counter() - t0, 1),
        mismatches=[x for x in rows if not x["same_outcome"]],
    )
    with open(out, "w") as f:
        json.dump(doc, f, indent=1)
    print(
        f"{run_dir}: {doc['same_outcome']}/{n} records replay to the stored fall outcome "
        f"(stored falls {doc['stored_falls']}, replayed {doc['replayed_falls']})"
    )


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])
