"""Where the tuning gradient's cold compile goes: XLA's own passes and code generation, from a
jax.profiler trace of the compile (XLA annotates each HLO pass, LLVM and ptxas step), per
variant of the program (results/bench/h100_compile_profile_*.json; after its runs, thread lines are keyed by index as well
as name: two threads were both "python3" and one hid the other in serial_threads_top):

    python scripts/bench_compile_profile.py BATCH 'grad;grad:loop=flat;split;split@autotune=0'

A variant is PROGRAM[:ROLLOUT_KEY=VALUE,...][@XLA_OPTION=VALUE,...]. PROGRAM "grad" is the
tuner's value_and_grad (tkujax.studies.tune.benchmark.bench_spec at BATCH pushes x 1.5 s);
"split" the same gradient as two programs, the forward pass keeping its residuals (jax.vjp)
and the backward pass, the backward traced and compiled while the forward compiles in a
thread ("split_seq": one after the other); the profiler is on during their tracing too, which
slows the Python part;
rollout keys go to RolloutConfig (loop, remat, unroll_substeps); XLA options (short names in
SHORT, or full xla_* names) go to jax.jit's compiler_options. Each variant: an empty persistent
cache, cleared in-process caches, trace, lower and compile timed apart, the compile profiled.
Per variant it writes the self time (wall time on a thread, minus nested events) per event
name, summed over threads, and the busy time per thread: $OUT/compile_profile_BATCH.json.
"""
# ruff: noqa: E501   (research script)

import collections
import concurrent.futures
import glob
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import jax
from jax.profiler import ProfileData

from tkujax.sweeps.compile_cache import fresh_compilation_cache
from tkujax.studies.tune.benchmark import bench_spec
from tkujax.studies.tune.problem import TuneProblem
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS, DEG
from tkujax.studies.tune.tune_spec import sample_pushes

OUT = Path(os.environ.get("OUT", "/tmp/out"))
SHORT = {"autotune": "xla_gpu_autotune_level"}


def parse_variant(text):
    prog, _, xla = text.partition("@")
    prog, _, roll = prog.partition(":")

    def kv(s):
        out = {}
        for item in filter(None, s.split(",")):
            k, _, v = item.partition("=")
            out[k] = (
                int(v)
                if v.lstrip("-").isdigit()
                else ({"true": True, "false": False}.get(v.lower(), v))
            )
        return out

    return prog, kv(roll), {SHORT.get(k, k): v for k, v in kv(xla).items()}


def self_times(xplane_path):
    """{name: [self_ms, count]} over every thread line, and [(plane/line, busy_ms)]."""
    pd = ProfileData.from_file(xplane_path)
    by_name = collections.defaultdict(lambda: [0.0, 0])
    lines = []
    per_line = {}
    for plane in pd.planes:
        for i, line in enumerate(plane.lines):
            ev = sorted(
                ((e.start_ns, e.duration_ns, e.name) for e in line.events),
                key=lambda t: (t[0], -t[1]),
            )
            if not ev:
                continue
            stack = []  # [end_ns, name, child_ns]
            busy = 0.0
            mine = collections.defaultdict(float)

            def pop(stack=stack, mine=mine):
                end, name, child, dur = stack.pop()
                by_name[name][0] += (dur - child) / 1e6
                by_name[name][1] += 1
                mine[name] += (dur - child) / 1e6

            for start, dur, name in ev:
                while stack and stack[-1][0] <= start:
                    pop()
                if stack:
                    stack[-1][2] += dur
                else:
                    busy += dur / 1e6
                stack.append([start + dur, name, 0, dur])
            while stack:
                pop()
            key = f"{plane.name}/{line.name}#{i}"  # threads may share a name
            lines.append((key, round(busy, 1)))
            per_line[key] = sorted(
                ((n[:100], round(ms, 1)) for n, ms in mine.items() if not n.startswith("$")),
                key=lambda x: -x[1],
            )[:25]
    return by_name, lines, per_line


def run_variant(batch, text):
    prog, roll, xla = parse_variant(text)
    assert prog in ("grad", "split", "split_seq"), prog
    remat = roll.pop("remat", True)
    spec = bench_spec(batch, 1.5, remat)
    reparam, base = spec.reparam(), spec.base_params()
    recs = sample_pushes(spec, batch, 0)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    z = reparam.latent_of(base)
    row = dict(variant=text, rollout_options=roll, compiler_options=xla)
    with fresh_compilation_cache():
        jax.clear_caches()
        problem = TuneProblem(
            reparam,
            base,
            spec.loss,
            1.5,
            remat,
            False,
            compiler_options=xla or None,
            rollout_options=roll,
        )
        # The problem's value_and_grad program (no RobotSet: the loss takes no robot values),
        # with the compiler options TuneProblem gives it.
        vg = jax.jit(jax.value_and_grad(problem.loss, has_aux=True),
                     compiler_options=xla or (CPU_COMPILER_OPTIONS
                                          if jax.default_backend() == "cpu" else None))
        args = problem.cast_args(z, DEG, recs, keys)
        tdir = tempfile.mkdtemp()
        if prog == "grad":
            t0 = time.perf_counter()
            traced = vg.trace(*args)
            t1 = time.perf_counter()
            lowered = traced.lower()
            t2 = time.perf_counter()
            with jax.profiler.trace(tdir):
                exe = lowered.compile()
            t3 = time.perf_counter()
            row.update(
                trace_s=round(t1 - t0, 2),
                lower_s=round(t2 - t1, 2),
                compile_s=round(t3 - t2, 2),
                stablehlo_chars=len(lowered.as_text()),
            )
            call = lambda: exe(*args)  # noqa: E731
        else:
            # "split": the forward pass that keeps the residuals (jax.vjp) and the backward
            # pass as two programs; the backward is traced and compiled while the forward
            # compiles in another thread (XLA's compile releases the GIL).
            opts = xla or None

            def fwd(z, *rest):
                loss, vjp, aux = jax.vjp(lambda z: problem.loss(z, *rest), z, has_aux=True)
                return (loss, aux), vjp

            fj = jax.jit(fwd, compiler_options=opts)
            bj = jax.jit(lambda vjp, ct: vjp(ct)[0], compiler_options=opts)
            t0 = time.perf_counter()
            with jax.profiler.trace(tdir):
                tf = fj.trace(*args)
                lf = tf.lower()
                t1 = time.perf_counter()
                with concurrent.futures.ThreadPoolExecutor(1) as pool:
                    done = {}

                    def compile_fwd():
                        exe = lf.compile()
                        done["fwd"] = time.perf_counter()
                        return exe

                    fut = pool.submit(compile_fwd) if prog == "split" else None
                    (loss_i, _), vjp_i = tf.out_info
                    lb = bj.trace(vjp_i, jax.ShapeDtypeStruct(loss_i.shape, loss_i.dtype)).lower()
                    t2 = time.perf_counter()
                    if fut is None:  # "split_seq": one after the other
                        ef = compile_fwd()
                    eb = lb.compile()
                    done["bwd"] = time.perf_counter()
                    if fut is not None:
                        ef = fut.result()
                t3 = time.perf_counter()
            row.update(
                fwd_trace_lower_s=round(t1 - t0, 2),
                bwd_trace_lower_s=round(t2 - t1, 2),
                fwd_done_s=round(done["fwd"] - t0, 2),
                bwd_done_s=round(done["bwd"] - t0, 2),
                total_s=round(t3 - t0, 2),  # without writing the profile
                stablehlo_chars=[len(lf.as_text()), len(lb.as_text())],
            )

            def call():
                (loss, aux), vjp = ef(*args)
                return eb(vjp, jax.numpy.ones_like(loss))

            exe = eb
            g_split = call()
            g_ref = vg(*args)[1]
            row["max_abs_grad_diff_vs_single"] = float(
                jax.numpy.max(jax.numpy.abs(g_split - g_ref))
            )
    hlo = exe.as_text()
    row["optimized_hlo_chars"] = len(hlo)
    row["fusion_instructions"] = len(re.findall(r" fusion\(", hlo))
    row["while_loops"] = len(re.findall(r" while\(", hlo))
    by_name, lines, per_line = self_times(glob.glob(tdir + "/**/*.xplane.pb", recursive=True)[0])
    # Python frames ("$file:line fn") sit on the calling thread, XLA's events on others
    top = sorted(
        ((n, v) for n, v in by_name.items() if not n.startswith("$")), key=lambda kv: -kv[1][0]
    )
    row["self_ms_top"] = [(n[:120], round(ms, 1), c) for n, (ms, c) in top[:60]]
    row["threads_busy_ms"] = sorted((x for x in lines if x[1] > 500), key=lambda x: -x[1])
    # the threads that are not XLA's compile pool: where the serial passes run
    row["serial_threads_top"] = {
        k: v for k, v in per_line.items() if "compile_thread_pool" not in k and v and v[0][1] > 500
    }
    # one step of the compiled gradient, to see what an option costs at run time
    jax.block_until_ready(call())
    t0 = time.perf_counter()
    jax.block_until_ready(call())
    row["step_s"] = round(time.perf_counter() - t0, 3)
    print(
        json.dumps(
            {
                k: row[k]
                for k in row
                if k not in ("self_ms_top", "threads_busy_ms", "serial_threads_top")
            }
        ),
        flush=True,
    )
    for n, ms, c in row["self_ms_top"][:25]:
        print(f"  {ms:10.1f} ms {c:7d}  {n}", flush=True)
    return row


if __name__ == "__main__":
    batch = int(sys.argv[1])
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"compile_profile_{batch}.json"
    rows = []
    for v in filter(None, sys.argv[2].split(";")):
        rows.append(run_variant(batch, v))
        path.write_text(
            json.dumps(
                dict(device=str(jax.devices()[0].device_kind), jax=jax.__version__, rows=rows),
                indent=1,
            )
        )
