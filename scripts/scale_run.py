"""The scale run (results/scale/README.md): a sweep of >= 1,000,000 rollouts with early
decisions on one GPU, shared by worker processes that are killed (SIGKILL) at random and
restarted, one of them lost for good, while writers of another spec (the same with another
seed) try to write into the same folder and must be refused; two uninterrupted runs of the same
spec (the second sharing the GPU with the killed workers, the first alone and timed), every
column of all three compared bit for bit; and a full-horizon baseline on a subset of the same
pushes. Writes OUT/summary.json (and nothing big outside --work).

    python scripts/scale_run.py --out $OUT --work /tmp/scale --rollouts 1048576 --batch 65536
    python scripts/scale_run.py --out $OUT --work /tmp/scale --no-repeat --no-baseline
    python scripts/scale_run.py --smoke --out /tmp/smoke --work /tmp/smoke   # a CPU check

--no-repeat skips the second uninterrupted run and --no-baseline the full-horizon baseline
(to fit a device's call limit; --baseline-only adds the baseline later).

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
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "specs" / "sweep" / "scale.toml"
CLAIMS_DIR = ".claims"        # tkujax.sweeps.chunks.CLAIMS


def spec_text(base: str, rollouts: int, batch: int, chunk: int, duration_s: float | None,
              seed: int | None = None) -> str:
    """The spec of this run: scale.toml with n, lanes, chunk_size (and duration, seed)
    replaced."""
    out = []
    for line in base.splitlines():
        key = line.split("=")[0].strip()
        value = {"n": rollouts, "lanes": batch, "chunk_size": chunk,
                 "duration_s": duration_s, "seed": seed}.get(key)
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
    for path in (out / CLAIMS_DIR).glob("*.claim"):
        try:
            pids.add(int(json.loads(path.read_text())["pid"]))
        except (OSError, ValueError, KeyError):
            pass
    return pids


INTRUDER_MEM = 0.05        # an intruder's share of the GPU's memory
REFUSALS = ("holds another spec's sweep", "holds another sweep")   # sweep_folder's, chunks'


class Intruders(threading.Thread):
    """Writers of another spec (`spec`) started into the killed run's folder `out`: the first
    shortly after its manifest exists, the others `gap_s` apart (seeded draws). `records`: per
    intruder, when it started, the chunks done then, its pid, exit code and last stderr line."""

    def __init__(self, spec: Path, out: Path, n: int, gap_s: tuple[float, float], seed: int,
                 t0: float):
        super().__init__(daemon=True)
        self.spec, self.out, self.n, self.gap_s, self.t0 = spec, out, n, gap_s, t0
        self.rng, self.records = random.Random(seed), []

    def run(self) -> None:
        from tkujax.sweeps import chunks
        while not (self.out / chunks.MANIFEST).exists():
            time.sleep(0.1)
        delay, procs = self.rng.uniform(0.5, 2.0), []
        for k in range(self.n):
            time.sleep(delay)
            done, n = done_count(self.out)
            err = self.out.parent / f"intruder_{k}.err"
            with open(err, "w") as f:
                p = subprocess.Popen(sweep_cmd(self.spec, self.out), env=env_for(INTRUDER_MEM),
                                     stdout=subprocess.DEVNULL, stderr=f)
            procs.append((p, err, dict(started_s=round(time.perf_counter() - self.t0, 2),
                                       chunks_done=done, n_chunks=n, pid=p.pid)))
            delay = self.rng.uniform(*self.gap_s)
        for p, err, rec in procs:
            code = p.wait()                 # its stderr is complete once it has exited
            lines = [x for x in err.read_text(errors="replace").splitlines() if x.strip()]
            self.records.append(rec | dict(exit_code=code, message=lines[-1] if lines else ""))

    def summary(self) -> dict:
        recs = self.records
        refused = len(recs) == self.n and all(
            r["exit_code"] == 2 and any(m in r["message"] for m in REFUSALS) for r in recs)
        return dict(intruders=recs, intruders_refused=refused,
                    intruders_during_run=sum(r["chunks_done"] < (r["n_chunks"] or 0)
                                             for r in recs))


def one_spec(out: Path, spec_hash: str, pids: set[int]) -> dict:
    """Whether folder `out` holds one sweep only: its manifest's spec hash is `spec_hash`,
    every chunk file in it is in the manifest, no run of the manifest and no claim or
    temporary file is an intruder's (`pids`: theirs). Also the files it holds besides."""
    from tkujax.sweeps import chunks
    manifest = chunks.read_manifest(out)
    listed = set(manifest.get("chunks", {}))
    names = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    unlisted = [x for x in names if Path(x).name.startswith("chunk_") and x.endswith(".npz")
                and x not in listed]
    theirs = [x for x in names if any(f".{pid}." in x for pid in pids)]   # temporaries
    theirs += [f"{CLAIMS_DIR}/ claim of pid {pid}" for pid in sorted(claim_pids(out) & pids)]
    runs = [r.get("run_id", "") for r in manifest.get("runs", [])]
    their_runs = [r for r in runs if any(f"-{pid}-" in r for pid in pids)]
    others = [x for x in names if x not in listed and x not in (chunks.MANIFEST, ".lock")]
    return dict(killed_folder_one_spec=manifest.get("spec_hash") == spec_hash and not unlisted
                and not theirs and not their_runs,
                killed_folder_spec_hash=manifest.get("spec_hash"), unlisted_chunks=unlisted,
                intruder_files=theirs, intruder_runs=their_runs,
                killed_folder_other_files=others)


def killed_run(spec: Path, out: Path, workers: int, kills: int, lose_at: int,
               interval_s: tuple[float, float], log, seed: int = 0, mem: float = 0.45,
               intruders: Intruders | None = None) -> dict:
    """Workers on one folder, SIGKILLed at random while they hold a claim, restarted (but the
    lose_at-th kill's worker, which is lost for good); `intruders` started beside them. mem:
    each worker's share of the GPU's memory. Returns the counts and wall time."""
    rng, t0 = random.Random(seed), time.perf_counter()
    if intruders is not None:
        intruders.t0 = t0
        intruders.start()
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
    if intruders is not None:
        intruders.join()
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
             interval_s=(1.0, 4.0), baseline_pushes=16, intruders=3)


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
    ap.add_argument("--intruders", type=int, default=3,
                    help="writers of another spec (seed + 1) started into the killed run's "
                         "folder, each to be refused")
    ap.add_argument("--no-repeat", action="store_true",
                    help="skip the second uninterrupted run (the one beside the killed workers)")
    ap.add_argument("--no-baseline", action="store_true",
                    help="skip the full-horizon baseline (--baseline-only adds it later)")
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
    if args.intruders < 0:
        ap.error("--intruders must be >= 0")
    return args


def spec_seed(text: str) -> int:
    """The spec's `seed` (0 where it sets none)."""
    for line in text.splitlines():
        if line.split("=")[0].strip() == "seed":
            return int(line.split("=", 1)[1].split("#")[0])
    return 0


def main(argv=None) -> None:
    args = parse(argv)
    t_start = time.perf_counter()
    out = Path(args.out).resolve()
    work = Path(args.work).resolve() if args.work else out / "work"
    work.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    base = SPEC.read_text()
    spec, intruder = work / "scale.toml", work / "intruder.toml"
    chunk = min(args.chunk, args.rollouts)
    spec.write_text(spec_text(base, args.rollouts, args.batch, chunk, args.duration_s))
    # The intruders' spec: the same sweep with another seed, so another spec hash.
    intruder.write_text(spec_text(base, args.rollouts, args.batch, chunk, args.duration_s,
                                  seed=spec_seed(base) + 1))
    # The warm-up: the same programs (the lanes' shape does not depend on the number of
    # pushes) compiled once by one process on one chunk of `batch` pushes, so that every later
    # process loads them from the persistent cache.
    warm = work / "warmup.toml"
    warm.write_text(spec_text(base, args.batch, args.batch, args.batch, args.duration_s))
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
    summary |= shared_runs(spec, intruder, work, args, log)
    summary["run1_wall_s"] = plain_run(spec, work / "run1", log)
    summary["pushes_per_s"] = chunk_rate(work / "run1")
    summary["run1_pushes_per_s_with_start_up"] = args.rollouts / summary["run1_wall_s"]
    save()
    compare_runs(summary, work, args)
    save()
    finish(summary, spec, args, log, out, t_start)


def shared_runs(spec: Path, intruder: Path, work: Path, args, log) -> dict:
    """The killed run with its intruders and, unless --no-repeat, the second uninterrupted run
    beside them on the same GPU (its records must not depend on what else runs)."""
    repeat = not args.no_repeat
    # Memory: the workers (and the second run) share 0.9 of the GPU's, less the intruders'.
    share = (0.9 - INTRUDER_MEM * min(args.intruders, 3)) / (args.workers + repeat)
    t2 = time.perf_counter()
    run2 = subprocess.Popen(sweep_cmd(spec, work / "run2"), env=env_for(share), stdout=log,
                            stderr=log) if repeat else None
    intruders = (Intruders(intruder, work / "killed", args.intruders,
                           tuple(args.kill_interval_s), seed=1, t0=t2)
                 if args.intruders else None)
    res = killed_run(spec, work / "killed", args.workers, args.kills, args.lose_at,
                     tuple(args.kill_interval_s), log, mem=share, intruders=intruders)
    if intruders is not None:
        res |= intruders.summary()
    if run2 is None:
        return res | dict(repeat_run="skipped (--no-repeat)")
    if run2.wait() != 0:
        raise SystemExit(f"the second uninterrupted run failed (exit {run2.returncode})")
    return res | dict(run2_wall_s=time.perf_counter() - t2)


def compare_runs(summary: dict, work: Path, args) -> None:
    """The killed run against the first uninterrupted run (and the first against the second),
    every column bit for bit; whether the killed folder holds the run's spec only."""
    from tkujax.sweeps import chunks
    first = compare(work / "killed", work / "run1")
    summary |= dict(bit_identical=first["bit_identical"], compared_rollouts=first["rows"],
                    columns=first["columns"], differing=first["differing"])
    if args.intruders:
        pids = {r["pid"] for r in summary.get("intruders", [])}
        summary |= one_spec(work / "killed", chunks.read_manifest(work / "run1")["spec_hash"],
                            pids)
    if not args.no_repeat:
        second = compare(work / "run1", work / "run2")
        summary |= dict(repeat_bit_identical=second["bit_identical"],
                        repeat_compared_rollouts=second["rows"],
                        repeat_differing=second["differing"])


def write_summary(out: Path, summary: dict) -> None:
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")


def finish(summary: dict, spec: Path, args, log, out: Path, t_start: float) -> None:
    """The full-horizon baseline and the speed-up (unless --no-baseline), into the summary;
    prints the headline."""
    if args.no_baseline and not args.baseline_only:
        summary["baseline"] = "skipped (--no-baseline)"
    else:
        base = baseline(spec, min(args.baseline_pushes, args.rollouts), args.batch, log)
        summary |= dict(baseline_pushes_per_s=base["baseline_pushes_per_s"],
                        fell_agreement=base["fell_agreement"], device=base["device"],
                        speedup=(summary.get("pushes_per_s") or 0.0)
                        / base["baseline_pushes_per_s"], baseline=base,
                        baseline_wall_s=time.perf_counter() - t_start)
    write_summary(out, summary)
    keys = ("rollouts", "kills", "processes_lost", "intruders_refused",
            "killed_folder_one_spec", "bit_identical", "repeat_bit_identical", "pushes_per_s",
            "baseline_pushes_per_s", "speedup", "fell_agreement", "device")
    print(json.dumps({k: summary[k] for k in keys if k in summary}, indent=1))


if __name__ == "__main__":
    main()
