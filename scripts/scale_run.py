"""The scale run (results/scale/README.md): a sweep of >= 1,000,000 rollouts with early
decisions on one GPU, shared by worker processes that are killed (SIGKILL) at random and
restarted, one of them lost for good; two uninterrupted runs of the same spec (the second
sharing the GPU with the killed workers, the first alone and timed), every column of all three
compared bit for bit; and a full-horizon baseline on a subset of the same pushes. Writes
OUT/summary.json (and nothing big outside --work).

    python scripts/scale_run.py --out $OUT --work /tmp/scale --rollouts 1048576 --batch 65536
    python scripts/scale_run.py --smoke --out /tmp/smoke --work /tmp/smoke   # a CPU check

Workers share one sweep folder through the chunk store's claims (`tkujax.sweeps.chunks`):
each runs `tkujax sweep` on its own (no coordinator), a killed worker's claim is taken over,
and a chunk counts only once its file matches the manifest. Rerunning the script resumes
every folder it finds under --work (a finished run is not recomputed).
"""
from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "specs" / "sweep" / "scale.toml"


def spec_text(base: str, rollouts: int, batch: int, chunk: int, duration_s: float | None) -> str:
    """The spec of this run: scale.toml with n, lanes, chunk_size (and duration) replaced."""
    out = []
    for line in base.splitlines():
        key = line.split("=")[0].strip()
        value = {"n": rollouts, "lanes": batch, "chunk_size": chunk,
                 "duration_s": duration_s}.get(key)
        out.append(f"{key} = {value}" if value is not None else line)
    return "\n".join(out) + "\n"


def sweep_cmd(spec: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "tkujax.cli", "sweep", str(spec), "--out", str(out),
            "--backend", "mjx", *extra]


def env_for(mem_fraction: float | None) -> dict:
    env = dict(os.environ)
    if mem_fraction is not None:            # workers share one GPU's memory
        env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{mem_fraction:.2f}"
    return env


def n_chunks_of(out: Path) -> int | None:
    from tkujax.sweeps import chunks
    return chunks.read_manifest(out).get("n_chunks")


def done_count(out: Path) -> tuple[int, int | None]:
    from tkujax.sweeps import chunks
    n = n_chunks_of(out)
    return (0, None) if n is None else (len(chunks.done_chunks(out, n)), n)


def claim_pids(out: Path) -> set[int]:
    pids = set()
    for path in (out / ".claims").glob("*.claim"):
        try:
            pids.add(int(json.loads(path.read_text())["pid"]))
        except (OSError, ValueError, KeyError):
            pass
    return pids


def killed_run(spec: Path, out: Path, workers: int, kills: int, lose_at: int,
               interval_s: tuple[float, float], log, seed: int = 0, mem: float = 0.45) -> dict:
    """Workers on one folder, SIGKILLed at random while they hold a claim, restarted (but the
    lose_at-th kill's worker, which is lost for good). mem: each worker's share of the GPU's
    memory. Returns the counts and wall time."""
    rng, t0 = random.Random(seed), time.perf_counter()
    procs = {w: subprocess.Popen(sweep_cmd(spec, out), env=env_for(mem),
                                 stdout=subprocess.DEVNULL, stderr=log) for w in range(workers)}
    n_kills, lost = 0, 0
    while True:
        time.sleep(rng.uniform(*interval_s) if n_kills < kills else 1.0)
        done, n = done_count(out)
        if n is not None and done == n:
            break
        busy = [w for w, p in procs.items() if p.poll() is None and p.pid in claim_pids(out)]
        if n_kills < kills and busy:
            w = rng.choice(busy)
            procs[w].send_signal(signal.SIGKILL)
            procs[w].wait()
            n_kills += 1
            print(f"killed worker {w} (pid {procs[w].pid}) with {done}/{n} chunks done",
                  file=log, flush=True)
            if n_kills == lose_at:
                del procs[w]                     # lost for good: the others take its share
                lost += 1
                continue
            procs[w] = subprocess.Popen(sweep_cmd(spec, out), env=env_for(mem),
                                        stdout=subprocess.DEVNULL, stderr=log)
        if all(p.poll() is not None for p in procs.values()):   # none left: restart one
            w = min(procs)
            procs[w] = subprocess.Popen(sweep_cmd(spec, out), env=env_for(mem),
                                        stdout=subprocess.DEVNULL, stderr=log)
    for p in procs.values():
        p.wait()
    return dict(kills=n_kills, processes_lost=lost, killed_run_wall_s=time.perf_counter() - t0)


def plain_run(spec: Path, out: Path, log) -> float:
    t0 = time.perf_counter()
    subprocess.run(sweep_cmd(spec, out), env=env_for(None), stdout=log, stderr=log, check=True)
    return time.perf_counter() - t0


def chunk_rate(out: Path) -> float | None:
    """Pushes per second of a run's steady state: the rows of every chunk but the first over
    the time between the first chunk's file and the last's (the first pays the start-up)."""
    from tkujax.sweeps import chunks
    entries = chunks.read_manifest(out).get("chunks", {})
    times = sorted(((out / name).stat().st_mtime, e["rows"]) for name, e in entries.items())
    if len(times) < 2 or times[-1][0] <= times[0][0]:
        return None
    return sum(r for _, r in times[1:]) / (times[-1][0] - times[0][0])


def compare(a: Path, b: Path, n_chunks: int | None = None) -> dict:
    """Every column of every chunk of a (the first n_chunks) against b's, bit for bit."""
    from tkujax.sweeps import chunks
    parts_a = chunks.read_chunks(a, chunks.read_manifest(a))
    parts_b = chunks.read_chunks(b, chunks.read_manifest(b))
    if n_chunks is not None:
        parts_a, parts_b = parts_a[:n_chunks], parts_b[:n_chunks]
    same = len(parts_a) == len(parts_b)
    differing = []
    for pa, pb in zip(parts_a, parts_b):
        for k in sorted(set(pa) | set(pb)):
            x, y = pa.get(k), pb.get(k)
            if x is None or y is None or x.dtype != y.dtype or x.tobytes() != y.tobytes():
                differing.append(k)
    rows = sum(len(p["push_id"]) for p in parts_a)
    return dict(bit_identical=same and not differing, rows=rows,
                columns=sorted(parts_a[0]) if parts_a else [],
                differing=sorted(set(differing)))


def baseline(spec: Path, pushes: int, lanes: int, log) -> dict:
    """Full horizon and early decisions on the first `pushes` records, in a fresh process
    (scripts/bench_early.py): their pushes per second and fall agreement."""
    code = ("import json, sys, numpy as np\n"
            "sys.path.insert(0, 'scripts')\n"
            "from tkujax.cli.runtime import configure_runtime; configure_runtime()\n"
            "from bench_early import measure\n"
            "from tkujax.dialects.sweep_spec import load_spec\n"
            f"res = measure(load_spec({str(spec)!r}), {pushes}, {lanes})\n"
            "print('RESULT', json.dumps(res))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env_for(None),
                          capture_output=True, text=True, check=True)
    log.write(proc.stderr[-4000:])
    return json.loads(proc.stdout.split("RESULT", 1)[1])


SMOKE = dict(rollouts=64, batch=4, chunk=8, duration_s=1.0, workers=2, kills=5, lose_at=3,
             interval_s=(1.0, 4.0), baseline_pushes=16)


def parse(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="where summary.json (and run.log) go")
    ap.add_argument("--work", default=None, help="the sweep folders (big; default OUT/work)")
    ap.add_argument("--rollouts", type=int, default=1_048_576)
    ap.add_argument("--batch", type=int, default=65536, help="lanes (pushes in flight)")
    ap.add_argument("--chunk", type=int, default=262144, help="pushes per chunk file")
    ap.add_argument("--duration-s", type=float, default=None, help="horizon (default: the spec's)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--kills", type=int, default=5)
    ap.add_argument("--lose-at", type=int, default=3, help="the kill whose worker is lost")
    ap.add_argument("--kill-interval-s", type=float, nargs=2, default=(5.0, 15.0))
    ap.add_argument("--baseline-pushes", type=int, default=65536)
    ap.add_argument("--baseline-only", action="store_true",
                    help="only the full-horizon baseline, merged into OUT/summary.json (for a "
                         "device whose call limit the whole run exceeds)")
    ap.add_argument("--smoke", action="store_true", help="a tiny run (CPU): " + str(SMOKE))
    args = ap.parse_args(argv)
    if args.smoke:
        for k, v in SMOKE.items():
            setattr(args, {"interval_s": "kill_interval_s", "chunk": "chunk"}.get(k, k), v)
    if args.workers < 2 or args.kills < 1 or not 1 <= args.lose_at <= args.kills:
        ap.error("--workers must be >= 2 and --lose-at in [1, --kills]")
    return args


def main(argv=None) -> None:
    args = parse(argv)
    t_start = time.perf_counter()
    out = Path(args.out).resolve()
    work = Path(args.work).resolve() if args.work else out / "work"
    work.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    spec = work / "scale.toml"
    spec.write_text(spec_text(SPEC.read_text(), args.rollouts, args.batch,
                              min(args.chunk, args.rollouts), args.duration_s))
    # The warm-up: the same programs (the lanes' shape does not depend on the number of
    # pushes) compiled once by one process on one chunk of `batch` pushes, so that every later
    # process loads them from the persistent cache.
    warm = work / "warmup.toml"
    warm.write_text(spec_text(SPEC.read_text(), args.batch, args.batch, args.batch,
                              args.duration_s))
    log = open(out / "run.log", "a")
    summary: dict = dict(rollouts=args.rollouts, batch=args.batch, chunk=args.chunk,
                         workers=args.workers, spec=spec.read_text())

    def save():     # after every stage: a call cut short still leaves what it measured
        write_summary(out, summary)

    if args.baseline_only:
        path = out / "summary.json"
        summary = json.loads(path.read_text()) if path.exists() else summary
        return finish(summary, spec, args, log, out, t_start)
    summary["warmup_wall_s"] = plain_run(warm, work / "warmup", log)
    save()
    # The second uninterrupted run shares the GPU with the killed workers (its records must
    # not depend on what else runs); the first runs alone, for the pushes per second.
    share = 0.9 / (args.workers + 1)
    t2 = time.perf_counter()
    run2 = subprocess.Popen(sweep_cmd(spec, work / "run2"), env=env_for(share), stdout=log,
                            stderr=log)
    summary |= killed_run(spec, work / "killed", args.workers, args.kills, args.lose_at,
                          tuple(args.kill_interval_s), log, mem=share)
    if run2.wait() != 0:
        raise SystemExit(f"the second uninterrupted run failed (exit {run2.returncode})")
    summary["run2_wall_s"] = time.perf_counter() - t2
    summary["run1_wall_s"] = plain_run(spec, work / "run1", log)
    summary["pushes_per_s"] = chunk_rate(work / "run1")
    summary["run1_pushes_per_s_with_start_up"] = args.rollouts / summary["run1_wall_s"]
    save()
    first = compare(work / "killed", work / "run1")
    second = compare(work / "run1", work / "run2")
    summary |= dict(bit_identical=first["bit_identical"],
                    repeat_bit_identical=second["bit_identical"],
                    compared_rollouts=first["rows"], repeat_compared_rollouts=second["rows"],
                    columns=first["columns"], differing=first["differing"],
                    repeat_differing=second["differing"])
    save()
    finish(summary, spec, args, log, out, t_start)


def write_summary(out: Path, summary: dict) -> None:
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")


def finish(summary: dict, spec: Path, args, log, out: Path, t_start: float) -> None:
    """The full-horizon baseline and the speed-up, into the summary; prints the headline."""
    base = baseline(spec, min(args.baseline_pushes, args.rollouts), args.batch, log)
    summary |= dict(baseline_pushes_per_s=base["baseline_pushes_per_s"],
                    fell_agreement=base["fell_agreement"], device=base["device"],
                    speedup=(summary.get("pushes_per_s") or 0.0)
                    / base["baseline_pushes_per_s"], baseline=base,
                    baseline_wall_s=time.perf_counter() - t_start)
    write_summary(out, summary)
    print(json.dumps({k: summary.get(k) for k in ("rollouts", "kills", "processes_lost",
                                              "bit_identical", "repeat_bit_identical",
                                              "pushes_per_s", "baseline_pushes_per_s",
                                              "speedup", "fell_agreement", "device")},
                     indent=1))


if __name__ == "__main__":
    main()
