"""Where the closed loop's time goes, per kernel (results/bench/h100_loop_trace.json).

    TNAMES=raw,physics_only,full python scripts/bench_trace_loops.py trace   -> $OUT/prof.json

`trace`: each tkujax.bench.profile variant at batch 1,024 (TBATCHES) x 0.3 s, compiled alone, traced
with jax.profiler; per GPU: kernels per tick, busy ms per tick, gaps > 3 us between kernels,
the top kernels, and kernel-launching ops per while-loop body of the optimised HLO.
`ablate` / `rawsens`: tkujax.bench.profile's ablation; raw MJX reading qpos vs sensordata.
"""
# ruff: noqa: E501   (research script)


import collections
import gzip
import json
import os
import re
import sys
import time
from pathlib import Path
import jax
import jax.numpy as jnp


def main() -> None:
    OUT = Path(os.environ.get("OUT", "/tmp/out"))
    from tkujax.bench import per_robot, push_batch, traced_paper_params, variant_loop_fn
    from tkujax.bench.profile import NO_KERNEL_OPS, profile_closed_loop


    def log(m):
        print(time.strftime("%H:%M:%S"), m, flush=True)


    def hlo_bodies(text):
        """kernel-launching instruction counts per while body."""
        comps, cur = {}, None
        for line in text.splitlines():
            m = re.match(r"^(?:ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$", line)
            if m and not line.startswith(" "):
                cur = m.group(1)
                comps[cur] = collections.Counter()
                continue
            if cur is None:
                continue
            m = re.match(r"^\s*(?:ROOT\s+)?%?[\w.\-]+\s*=\s*\S.*?\s([a-z][\w\-]*)\(", line)
            if m:
                comps[cur][m.group(1)] += 1
        bodies = {}
        for line in text.splitlines():
            m = re.search(r"while\(.*body=%?([\w.\-]+)", line)
            if m:
                b = m.group(1)
                c = comps.get(b, {})
                bodies[b] = {k: v for k, v in c.items() if k not in NO_KERNEL_OPS}
        return bodies


    def src_map(text):
        out = {}
        for line in text.splitlines():
            m = re.match(r'^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=.*op_name="([^"]*)"', line)
            if not m:
                continue
            o = m.group(2)
            for junk in (
                "jit(one)/",
                "jit(flat)/",
                "vmap()/",
                "while/body/",
                "closed_call/",
                "jit(chunk)/",
            ):
                o = o.replace(junk, "")
            out[m.group(1)] = "/".join(o.split("/")[:4])
        return out


    SRC = {}


    def analyse(trace_dir, n_ticks):
        files = sorted(Path(trace_dir).rglob("*.trace.json.gz"))
        if not files:
            return dict(error="no trace.json.gz", files=[str(p) for p in Path(trace_dir).rglob("*")])
        ev = json.loads(gzip.decompress(files[-1].read_bytes()))
        ev = ev.get("traceEvents", ev) if isinstance(ev, dict) else ev
        pname = {
            e["pid"]: e["args"]["name"]
            for e in ev
            if e.get("ph") == "M" and e.get("name") == "process_name"
        }
        gpu = [p for p, n in pname.items() if "GPU" in n or "gpu" in n] or list(pname)
        out = dict(processes=pname)
        for p in gpu:
            ks = [e for e in ev if e.get("pid") == p and e.get("ph") == "X"]
            if not ks:
                continue
            t0 = min(e["ts"] for e in ks)
            t1 = max(e["ts"] + e.get("dur", 0) for e in ks)
            busy = sum(e.get("dur", 0) for e in ks)
            by = collections.defaultdict(lambda: [0, 0.0])
            for e in ks:
                n = re.sub(r"[._]\d+$", "", e["name"])
                by[n][0] += 1
                by[n][1] += e.get("dur", 0)
            top = sorted(by.items(), key=lambda kv: -kv[1][1])[:40]
            bysrc = collections.defaultdict(lambda: [0, 0.0])
            for e in ks:
                a = e.get("args") or {}
                key = next(
                    (
                        SRC[k]
                        for k in (e["name"], a.get("hlo_op"), a.get("long_name"))
                        if isinstance(k, str) and k in SRC
                    ),
                    "unmatched",
                )
                bysrc[key][0] += 1
                bysrc[key][1] += e.get("dur", 0)
            ks.sort(key=lambda e: e["ts"])
            end = ks[0]["ts"]
            gaps = collections.defaultdict(lambda: [0, 0.0])
            gap_total = 0.0
            for prev, e in zip(ks, ks[1:]):
                end = max(end, prev["ts"] + prev.get("dur", 0))
                g = e["ts"] - end
                if g > 3.0:
                    key = (
                        re.sub(r"[._]\d+$", "", prev["name"])[:60]
                        + " -> "
                        + re.sub(r"[._]\d+$", "", e["name"])[:60]
                    )
                    gaps[key][0] += 1
                    gaps[key][1] += g
                    gap_total += g
            gtop = sorted(gaps.items(), key=lambda kv: -kv[1][1])[:25]
            out[pname[p]] = dict(
                n_events=len(ks),
                events_per_tick=len(ks) / n_ticks,
                span_ms=(t1 - t0) / 1e3,
                busy_ms=busy / 1e3,
                busy_ms_per_tick=busy / 1e3 / n_ticks,
                top=[(k, v[0], round(v[1] / 1e3, 3)) for k, v in top],
                src=[
                    (k, v[0], round(v[1] / 1e3, 3))
                    for k, v in sorted(bysrc.items(), key=lambda kv: -kv[1][1])[:80]
                ],
                gaps_over_3us_ms_per_tick=gap_total / 1e3 / n_ticks,
                gaps=[(k, v[0], round(v[1] / 1e3, 3)) for k, v in gtop],
            )
        return out


    res = {}


    def save():
        (OUT / "prof.json").write_text(json.dumps(res, indent=1, default=str))


    params = traced_paper_params()
    mode = sys.argv[1]
    if mode in ("ablate", "all"):
        for batch in [int(b) for b in os.environ.get("BATCHES", "65536").split(",")]:
            res[f"ablate_{batch}"] = {}
            profile_closed_loop(
                batch,
                float(os.environ.get("DUR", "0.6")),
                1,
                variants=tuple(
                    os.environ.get(
                        "VARIANTS",
                        "full;no_controller;no_wrench;no_records;shared_model;physics_only;raw",
                    ).split(";")
                ),
                log=log,
                into=res[f"ablate_{batch}"],
                on_update=save,
            )
            save()
    if mode in ("trace", "all"):
        for batch in [int(b) for b in os.environ.get("TBATCHES", "1024").split(",")]:
            recs = push_batch(batch)
            recs["onset_s"] = jnp.full_like(recs["onset_s"], 0.1)
            keys = jax.random.split(jax.random.PRNGKey(0), batch)
            for name in os.environ.get("TNAMES", "full,raw").split(","):
                fn = variant_loop_fn(name, 0.3)
                exe = fn.lower(recs, keys, params).compile()
                res[f"hlo_{name}"] = hlo_bodies(exe.as_text())
                SRC.clear()
                SRC.update(src_map(exe.as_text()))
                for _ in range(2):
                    jax.block_until_ready(exe(recs, keys, params))
                d = OUT / f"trace_{name}_{batch}"
                with jax.profiler.trace(str(d), create_perfetto_trace=True):
                    jax.block_until_ready(exe(recs, keys, params))
                res[f"trace_{name}_{batch}"] = analyse(d, 10)
                save()
                log(f"traced {name} {batch}")
    if mode in ("rawsens", "all"):
        from tkujax.sim.setup import init
        from tkujax.sim.mjx_import import mjx
        import statistics

        host, model, index, state = init()
        ctrl = jnp.asarray(index.stand_ctrl, jnp.float32)
        for batch in [int(b) for b in os.environ.get("RBATCHES", "1024,65536").split(",")]:
            recs = push_batch(batch)
            for kind in ("qpos", "sens"):

                def one(rec, kind=kind):
                    d = per_robot(state, rec).replace(ctrl=ctrl)

                    def body(c, _):
                        d, acc = c
                        d = mjx.step(model, d)
                        if kind == "sens":
                            acc = acc + d.sensordata.sum()
                        return (d, acc), None

                    (d, acc), _ = jax.lax.scan(body, (d, jnp.float32(0)), None, length=300)
                    return d.qpos[2] + acc

                fn = jax.jit(jax.vmap(one))
                exe = fn.lower(recs).compile()
                res[f"hlo_raw300_{kind}"] = hlo_bodies(exe.as_text())
                jax.block_until_ready(exe(recs))
                ts = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    jax.block_until_ready(exe(recs))
                    ts.append(time.perf_counter() - t0)
                sec = statistics.median(ts)
                res[f"raw300_{kind}_{batch}"] = dict(seconds=sec, steps_per_s=batch * 300 / sec)
                save()
                log(f"raw300 {kind} {batch}: {batch * 300 / sec / 1e6:.3f} M steps/s")
    save()
    log("done")


if __name__ == "__main__":
    main()
