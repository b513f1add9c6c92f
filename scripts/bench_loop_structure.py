"""Where the closed loop's time goes at batch 1,024: the physics step's variants in one flat
scan, the closed loop's (tkujax.bench.profile names), and how the optimised HLO splits each
while body (kernels, copies, loops) (it produced results/bench/
h100_loop_structure.json, one process per XLA_FLAGS setting):

    [XLA_FLAGS=...] python scripts/bench_loop_structure.py 1024 'rawstep;rawfwd;rawimu;...'

raw variants (750 physics steps holding the stand targets, 1.5 s): rawstep mjx.step;
rawfwd mjx.forward + mjx.euler with the sensor stage off; rawimu the same plus
physics.imu_reading every step; rawimufilt plus the IMU low-pass; rawsens mjx.step reading the
IMU from sensordata (the whole sensor stage). It was run before the sweeps' loop became flat:
its "full", "physics_only", "no_*" rows were the nested loop then ("loop=nested" today) and
"loop=flat" the flat one, and the XLA option came from XLA_FLAGS, not the program.
Writes $OUT/cbuf_BATCH.json.
"""
# ruff: noqa: B023, BLE001, F841, E501   (research script)

import collections
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
    from tkujax.bench import per_robot, push_batch, timed, traced_paper_params, variant_loop_fn
    from tkujax.sim import physics
    from tkujax.sim.mjx_import import mjx
    from tkujax.sim.setup import init

    batch = int(sys.argv[1])
    names = sys.argv[2].split(";")
    params = traced_paper_params()
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    host, model, index, state = init()
    n_steps = 750
    ctrl = jnp.asarray(index.stand_ctrl, state.qpos.dtype)
    lean = physics.without_sensors(model)


    def raw_variant(kind):
        def one(rec, key, params):
            d = per_robot(state, rec).replace(ctrl=ctrl)
            imu0 = (jnp.zeros(3), jnp.zeros(3))

            def body(carry, _):
                d, imu = carry
                if kind == "rawstep":
                    d = mjx.step(model, d)
                elif kind == "rawfwd":  # forward + euler, sensors off, no imu
                    d = mjx.euler(lean, mjx.forward(lean, d))
                elif kind in ("rawimu", "rawimufilt"):
                    d = mjx.forward(lean, d)
                    r = physics.imu_reading(lean, d, index)
                    d = mjx.euler(lean, d)
                    if kind == "rawimufilt":
                        imu = tuple(
                            y + jnp.asarray(a, y.dtype) * (x - y)
                            for y, x, a in zip(imu, r, index.imu_gains)
                        )
                    else:
                        imu = r
                elif kind == "rawsens":  # full mjx.step, reading the IMU from sensordata
                    d = mjx.step(model, d)
                    imu = (
                        d.sensordata[index.gyro_adr : index.gyro_adr + 3],
                        d.sensordata[index.accel_adr : index.accel_adr + 3],
                    )
                return (d, imu), None

            (d, imu), _ = jax.lax.scan(body, (d, imu0), None, length=n_steps)
            return d.qpos[2] + imu[0][0] + imu[1][0]

        return jax.jit(jax.vmap(one, in_axes=(0, 0, None)))


    def cb_summary(text):
        comps, cur, order = {}, None, {}
        lines = {}
        for line in text.splitlines():
            m = re.match(r"^(?:ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$", line)
            if m and not line.startswith(" "):
                cur = m.group(1)
                comps[cur] = []
                continue
            if cur is None:
                continue
            m = re.match(r"^\s*(?:ROOT\s+)?%?[\w.\-]+\s*=\s*\S.*?\s([a-z][\w\-]*)\((.*)$", line)
            if not m:
                continue
            op, rest = m.group(1), m.group(2)
            if op in ("copy", "while") and len(lines.setdefault(cur, [])) < 12:
                lines[cur].append(line.strip()[:400])
            if op == "call" and "command_buffer" in rest:
                comps[cur].append("CB")
            elif op in ("while",):
                comps[cur].append("W")
            elif op in ("conditional",):
                comps[cur].append("C")
            elif op in (
                "fusion",
                "custom-call",
                "copy",
                "copy-start",
                "fusion-start",
                "dynamic-update-slice",
                "scatter",
                "gather",
                "sort",
            ):
                comps[cur].append(op[:2].upper())
        out = {}
        for line in text.splitlines():
            m = re.search(r"while\(.*condition=%?([\w.\-]+), body=%?([\w.\-]+)", line)
            if m:
                b = m.group(2)
                seq = comps.get(b, [])
                cnt = collections.Counter(seq)
                out[b] = dict(counts=dict(cnt), seq=" ".join(seq)[:600], lines=lines.get(b, []))
        entry = [k for k in comps if k.startswith("main") or "ENTRY" in k]
        return out


    rows = []
    for name in names:
        t0 = time.time()
        fn = raw_variant(name) if name.startswith("raw") else variant_loop_fn(name, 1.5)
        exe = fn.lower(recs, keys, params).compile()
        cs = time.time() - t0
        sec = timed(lambda: exe(recs, keys, params), 5)
        row = dict(name=name, batch=batch, compile_s=round(cs, 1), ms_per_tick=1e3 * sec / n_steps * 15)
        try:
            row["while_bodies"] = cb_summary(exe.as_text())
        except Exception as e:
            row["hlo_error"] = repr(e)
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "while_bodies"}), flush=True)
        (OUT / f"cbuf_{batch}.json").write_text(
            json.dumps(dict(device=jax.devices()[0].device_kind, rows=rows), indent=1)
        )


if __name__ == "__main__":
    main()
