"""`tkujax bench --profile`: what each part of the closed loop costs per control tick.

By ablation: the closed loop of the sweeps (`tkujax.studies.sweep.make_chunk_fn`: per-push
model fields, sensor noise, controller, push wrench, Series records and outcomes) is timed
whole, then with one part replaced by a trivial stand-in (`RolloutConfig.ablate`, a Python
branch at trace time, so the other parts' program is unchanged), at one batch and duration:

  full            the closed loop as the sweeps run it
  no_noise        no sensor-noise draws (the bench's pushes have zero noise: same results)
  no_controller   no controller: the legs hold the stand targets
  no_wrench       no push wrench computed per substep (xfrc_applied stays 0)
  no_records      no Series and no outcomes: the pelvis height per tick is the only output
  shared_model    one model for the batch (no per-push model fields: randomize_model)
  physics_only    all of the above at once: the loop around the physics step
  raw             one flat scan of mjx.step holding the stand targets, as many steps, from the
                  same settled state (the bench's raw-MJX figure, in this loop's units)

Each row gives ms per control tick and `cost_ms_per_tick` = full - row: what the replaced part
costs (no_push: what the pushed state costs the physics; negative when the stand-in is slower).
`controller_parts` times the controller's pieces alone (vmapped over the batch in a scan over
the ticks, synthetic IMU readings): Kalman, detection, CPG (the paper's, the lateral one and
later steps), IK, stance feedback, quantisation, and the whole `controller_step`. Alone, a
piece cannot fuse with its neighbours: an upper bound of its share in the closed loop.

Extra variants (`variants=`): "no_push" (the full program, every impulse 0: what the pushed,
falling states cost the physics, expected ~0), "unroll_substeps=K" / "unroll_ticks=K" (scan
unrolling), "loop=nested" / "loop=flat" (`RolloutConfig.loop`; the sweeps' SWEEP_LOOP
otherwise), and "A+B" (both: "physics_only+loop=nested"), measured the same way. Every variant
is compiled with the sweeps' XLA options (SWEEP_COMPILER_OPTIONS). The variants are lowered one
after the other and compiled in parallel threads (compile time is not what this measures;
default up to 8 threads). Compiled so, on an H100 at batch 1,024, the raw loop ran 13.6 ms per
tick against 11.9 ms compiled alone: compare rows within one profile, and take absolute figures
from `results/bench/loop_ablation.py`, which compiles one variant after the other.
`trace_dir`: a `jax.profiler` trace of one run of the full loop, whose op names carry the
rollout's named scopes (sensors, controller, physics/push_wrench, physics/mjx_step,
records), summed by scope in `trace_scopes` (best effort: events matched by name).
Speeds are reported, never asserted.
"""

from __future__ import annotations

import concurrent.futures
import gzip
import json
import os
import re
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.bench import _timed as _time_calls   # results/bench scripts use this name
from tkujax.sim import physics

# no_push is left out by default: MJX's cost does not depend on the state (static contact
# count; one Newton iteration; a line search of fixed length, its cond a select under vmap).
DEFAULT_VARIANTS = ("full", "no_noise", "no_controller", "no_wrench", "no_records",
                    "shared_model", "physics_only", "raw")
DEFAULT_COMPILE_WORKERS = max(1, min(8, os.cpu_count() or 1))
_ABLATE = {"no_noise": ("noise",), "no_controller": ("controller",), "no_wrench": ("wrench",),
           "no_records": ("records",),
           "physics_only": ("noise", "controller", "wrench", "records")}
_SHARED_MODEL = ("shared_model", "physics_only")


def _variant_config(name: str) -> dict:
    """RolloutConfig fields of a variant name (see the module docstring); "A+B" combines the
    fields of A and B (e.g. "physics_only+loop=flat")."""
    from tkujax.sim.rollout_mjx import LOOPS

    if "+" in name:
        fields: dict = {}
        for part in name.split("+"):
            fields.update(_variant_config(part))
        return fields
    if name in ("full", "no_push", "shared_model", "raw"):
        return {}
    if name in _ABLATE:
        return {"ablate": _ABLATE[name]}
    key, _, val = name.partition("=")
    if key in ("unroll_substeps", "unroll_ticks") and val.isdigit() and int(val) >= 1:
        return {key: int(val)}
    if key == "loop" and val in LOOPS:
        return {"loop": val}
    raise ValueError(f"unknown profile variant {name!r}; known: {DEFAULT_VARIANTS}, "
                     f"unroll_substeps=K, unroll_ticks=K, loop=L (L in {LOOPS}), and A+B")


def _loop_fn(name: str, duration_s: float):
    """jit(vmap) of (records, keys, params) -> outputs for a variant name."""
    parts = name.split("+")
    return loop_fn(duration_s, _variant_config(name),
                   shared_model=any(p in _SHARED_MODEL for p in parts), raw=name == "raw")


def loop_fn(duration_s: float, config_fields: dict | None = None, shared_model: bool = False,
            raw: bool = False):
    """jit(vmap) of (records, keys, params) -> outputs, built as make_chunk_fn builds the
    sweeps' chunk (with no fields and no flags it is that program: the outcomes of
    OUTCOME_KEYS), with further RolloutConfig fields; shared_model: no per-push model fields;
    raw: a flat scan of mjx.step holding the stand targets for as many steps instead."""
    from tkujax.sim.metrics import outcomes as rollout_outcomes
    from tkujax.sim.push import Push
    from tkujax.sim.randomize import randomize_model
    from tkujax.sim.rollout_mjx import RolloutConfig, rollout
    from tkujax.sim.setup import init
    from tkujax.studies.sweep import OUTCOME_KEYS, SWEEP_COMPILER_OPTIONS, SWEEP_LOOP

    host, model, index, state = init()
    if raw:
        n_steps = _n_ticks(duration_s) * _substeps()
        ctrl = jnp.asarray(index.stand_ctrl, state.qpos.dtype)

        def flat(rec, key, params):
            return physics.step_holding(model, _per_robot(state, rec), ctrl, n_steps)[0].qpos[2]

        return jax.jit(jax.vmap(flat, in_axes=(0, 0, None)),
                       compiler_options=SWEEP_COMPILER_OPTIONS)
    fields = {"loop": SWEEP_LOOP} | (config_fields or {})   # the sweeps' loop unless overridden
    config = RolloutConfig(duration_s=duration_s, **fields)

    def one(rec, key, params):
        push = Push(rec["impulse_ns"], jnp.radians(rec["azimuth_deg"]), rec["height_m"],
                    rec["duration_s"], rec["onset_s"])
        m = model if shared_model else randomize_model(
            model, index.chest_body, mass_scale=rec["link_mass_scale"],
            torso_com_dx_m=rec["torso_com_offset_x_m"], friction=rec["floor_friction"],
            kp_scale=rec["servo_kp_scale"])
        # With noise, controller and wrench all stood in for, nothing depends on the record:
        # vmap would step one robot and broadcast it. The state is made per robot instead.
        alone = {"noise", "controller", "wrench"} <= set(config.ablate)
        series = rollout(m, _per_robot(state, rec) if alone else state, push, params,
                         rec["control"], key, rec["gyro_noise_std"], rec["accel_noise_std"],
                         config, index)
        if "records" in config.ablate:
            return series[-1]
        out = rollout_outcomes(series, push.onset_s)
        return {k: out[k] for k in OUTCOME_KEYS}

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None)), compiler_options=SWEEP_COMPILER_OPTIONS)


def _per_robot(state, rec):
    """The state made to depend on the record (qpos + 0 * impulse: the same values; XLA keeps
    floating-point x * 0), so that under vmap the physics runs once per robot."""
    return state.replace(qpos=state.qpos + 0.0 * rec["impulse_ns"].astype(state.qpos.dtype))


def _substeps() -> int:
    from tkujax.sim.push import CONTROL_PERIOD_S

    return int(round(CONTROL_PERIOD_S / physics.host_model().opt.timestep))


def _n_ticks(duration_s: float) -> int:
    from tkujax.sim.push import CONTROL_PERIOD_S

    return int(round(duration_s / CONTROL_PERIOD_S))


def profile_closed_loop(batch: int, duration_s: float = 0.3, repeats: int = 1,
                        variants=DEFAULT_VARIANTS, compile_workers: int = DEFAULT_COMPILE_WORKERS,
                        trace_dir: str | Path | None = None, log=None, into: dict | None = None,
                        on_update=None) -> dict:
    """The ablation table at one batch (see the module docstring). `into`: the dict to fill
    (returned), `on_update()`: called after each timed variant (the bench rewrites its JSON:
    a run cut short keeps the rows measured so far)."""
    from tkujax.bench import _push_batch, traced_paper_params

    log = log or (lambda msg: None)
    on_update = on_update or (lambda: None)
    variants = ("full",) + tuple(v for v in variants if v != "full")
    for v in variants:
        if v != "no_push":
            _variant_config(v)           # unknown names fail before any compile
    params = traced_paper_params()
    recs = _push_batch(batch)
    # The push inside the (short) rollout: the controller detects it and steps.
    recs["onset_s"] = jnp.full_like(recs["onset_s"], min(0.3, duration_s / 3))
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    n_ticks = _n_ticks(duration_s)
    result = into if into is not None else {}
    result.update(batch=batch, duration_s=duration_s, n_ticks=n_ticks, substeps=_substeps(),
                  repeats=repeats, compile_workers=compile_workers, rows=[])
    programs = [v for v in variants if v != "no_push"]
    t0 = time.perf_counter()
    lowered = {}
    for v in programs:
        lowered[v] = _loop_fn(v, duration_s).lower(recs, keys, params)
    result["lower_s"] = round(time.perf_counter() - t0, 2)
    log(f"profile {batch}: lowered {len(programs)} programs in {result['lower_s']:.1f} s; "
        f"compiling")
    t0 = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(max(1, compile_workers)) as pool:
        compiled = dict(zip(programs, pool.map(lambda v: lowered[v].compile(), programs)))
    result["compile_parallel_s"] = round(time.perf_counter() - t0, 2)
    log(f"profile {batch}: compiled in {result['compile_parallel_s']:.1f} s")
    on_update()
    no_push = dict(recs, impulse_ns=jnp.zeros_like(recs["impulse_ns"]))
    full = None
    for v in variants:         # "full" first: every row's cost is relative to it
        exe = compiled["full" if v == "no_push" else v]
        r = no_push if v == "no_push" else recs
        sec = _time_calls(lambda exe=exe, r=r: exe(r, keys, params), repeats)
        full = sec if full is None else full
        result["rows"].append(dict(variant=v, seconds=sec, ms_per_tick=1e3 * sec / n_ticks,
                                   cost_ms_per_tick=1e3 * (full - sec) / n_ticks,
                                   share_of_full=(full - sec) / full))
        log(f"profile {batch}: {v} {1e3 * sec / n_ticks:.3f} ms/tick")
        on_update()
    if trace_dir:
        trace = Path(trace_dir) / f"batch{batch}"
        try:     # best effort: a profiler that cannot start must not lose the table
            trace.mkdir(parents=True, exist_ok=True)
            exe = compiled["full"]
            with jax.profiler.trace(str(trace)):
                jax.block_until_ready(exe(recs, keys, params))
            result["trace_dir"] = str(trace)
            result["trace_scopes"] = trace_scopes(trace, exe.as_text(), n_ticks)
        except Exception as err:  # noqa: BLE001
            result["trace_scopes"] = dict(error=f"{type(err).__name__}: {err}"[:500])
            log(f"profile {batch}: trace failed: {result['trace_scopes']['error']}")
    return result


SCOPES = ("push_wrench", "mjx_step", "sensors", "controller", "records", "physics")
_NO_KERNEL = ("while", "call", "conditional", "tuple", "get-tuple-element", "parameter",
              "constant", "bitcast")


def _instruction_scopes(hlo_text: str) -> dict[str, str]:
    """{HLO instruction name: the innermost named scope of the rollout in its op_name} for the
    instructions of the optimised module that can run as kernels (not loops or calls)."""
    pat = re.compile(r'^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*\S.*?\s([a-z][\w\-]*)\(.*'
                     r'op_name="([^"]*)"')
    out = {}
    for line in hlo_text.splitlines():
        m = pat.match(line)
        if not m or m.group(2) in _NO_KERNEL:
            continue
        tokens = set(re.findall(r"[A-Za-z_]+", m.group(3)))
        out[m.group(1)] = next((sc for sc in SCOPES if sc in tokens), "other")
    return out


def trace_scopes(trace_dir: Path, hlo_text: str, n_ticks: int) -> dict:
    """Best-effort reading of a jax.profiler trace: the time of the trace's events whose name
    is an instruction of the optimised program, summed by the rollout's named scope (`other`:
    outside them: outcomes, loop plumbing). Events are matched by name only (CPU: the HLO
    instruction; GPU: the kernel, named after its fusion where XLA keeps the name); unmatched
    ones are counted apart. Durations overlap where kernels run concurrently."""
    files = sorted(Path(trace_dir).rglob("*.trace.json.gz"), key=lambda f: f.stat().st_mtime)
    if not files:
        return dict(error="no *.trace.json.gz in the trace folder")
    events = json.loads(gzip.decompress(files[-1].read_bytes())).get("traceEvents", [])
    names = _instruction_scopes(hlo_text)
    us = dict.fromkeys(SCOPES + ("other",), 0.0)
    matched = unmatched = 0
    for e in events:
        if e.get("ph") != "X":
            continue
        args = e.get("args") or {}
        key = next((k for k in (e.get("name"), args.get("hlo_op"), args.get("long_name"))
                    if isinstance(k, str) and k in names), None)
        if key is None:
            unmatched += 1
            continue
        matched += 1
        us[names[key]] += float(e.get("dur", 0.0))
    total = sum(us.values())
    return dict(file=str(files[-1]), events_matched=matched, events_unmatched=unmatched,
                scopes={k: dict(ms_per_tick=v / 1e3 / n_ticks,
                                share=v / total if total else None) for k, v in us.items()})


def _parts(params, batch: int, dtype):
    """{name: (init carry, step(carry, (gyro, accel)) -> carry)} of the controller's pieces, each
    vmapped over the batch; the carry folds in every output so nothing is dead code."""
    from tkujax.control.controller import (_detect, _later_step_feet, controller_init,
                                          controller_step, Sensors, StepsState, stance_offsets)
    from tkujax.control.cpg import cpg_feet, cpg_feet_lateral
    from tkujax.control.kalman import (accel_to_angle, accel_variance, gyro_to_rates,
                                       kalman_init, kalman_step)
    from tkujax.control.solve import solve_legs
    from tkujax.sim.tick import quantise_targets

    zero = jnp.zeros((batch,), dtype)

    def fold(acc, *outs):
        return acc + sum(jnp.sum(jnp.asarray(o, dtype).reshape(batch, -1), -1)
                         for o in jax.tree_util.tree_leaves(outs))

    def vm(f):
        return jax.vmap(f)

    k0 = jax.vmap(lambda _: kalman_init(jnp.stack([jnp.asarray(params.standing_lean, dtype),
                                                   jnp.zeros((), dtype)]), params))(zero)
    s0 = jax.vmap(lambda _: controller_init(params, dtype))(zero)

    def kalman(c, x):
        k, acc = c
        k = vm(lambda k, g, a: kalman_step(k, gyro_to_rates(g), accel_to_angle(a), params,
                                           accel_variance(a, params)))(k, *x)
        return (k, fold(acc, k.phi))

    def detection(acc, x):
        g, a = x
        det = vm(lambda g, a: _detect(accel_to_angle(a)[0], -accel_to_angle(a)[1],
                                      gyro_to_rates(g)[0], -gyro_to_rates(g)[1], params))(g, a)
        return fold(acc, det)

    def cpg(acc, x):
        g, _ = x
        t = g[:, 0]
        steps = jax.vmap(lambda _: StepsState.init(dtype))(zero)
        x_sup, y_sup = jnp.full_like(t, 0.03), jnp.full_like(t, 0.01)
        return fold(acc, vm(lambda t, x: cpg_feet(t, x, params))(t, x_sup),
                    vm(lambda t, x, y: cpg_feet_lateral(t, x, y, params))(t, x_sup, y_sup),
                    vm(lambda t, s: _later_step_feet(t, s, params))(t, steps))

    def ik(acc, x):
        g, _ = x
        p_r = jnp.stack([0.01 * g[:, 0], -params.hip_offset_y + 0.0 * g[:, 1],
                         -params.hip_to_ankle_z + 0.0 * g[:, 2]], -1)
        p_l = p_r * jnp.asarray([1.0, -1.0, 1.0], dtype)
        return fold(acc, vm(lambda a, b: solve_legs(a, b, params))(p_r, p_l))

    def stance(acc, x):
        g, a = x
        return fold(acc, vm(lambda g, a: stance_offsets(a[0], g[0], a[1], g[1], params))(g, a))

    def quantise(acc, x):
        g, _ = x
        return fold(acc, quantise_targets(jnp.tile(g, (1, 4))))

    def whole(c, x):
        s, acc = c
        s, out = vm(lambda s, g, a: controller_step(s, Sensors(g, a), params, 1.0))(s, *x)
        return (s, fold(acc, out))

    return {"kalman": ((k0, zero), kalman), "detection": (zero, detection), "cpg": (zero, cpg),
            "ik": (zero, ik), "stance": (zero, stance), "quantise": (zero, quantise),
            "controller_step": ((s0, zero), whole)}


def profile_controller_parts(batch: int, duration_s: float = 0.3,
                             repeats: int = 1) -> list:
    """ms per tick of each controller piece alone at `batch` (see the module docstring)."""
    from tkujax.bench import traced_paper_params

    params = traced_paper_params()
    n_ticks = _n_ticks(duration_s)
    rng = np.random.default_rng(0)
    gyro = jnp.asarray(rng.normal(0.0, 0.5, (n_ticks, batch, 3)), jnp.float32)
    accel = jnp.asarray(rng.normal(0.0, 0.5, (n_ticks, batch, 3)) + [0.0, 0.0, 9.81],
                        jnp.float32)
    rows = []
    for name, (init, step) in _parts(params, batch, jnp.float32).items():
        def run(init=init, step=step):
            return jax.lax.scan(lambda c, x: (step(c, x), None), init, (gyro, accel))[0]

        fn = jax.jit(run)
        sec = _time_calls(fn, repeats)
        rows.append(dict(part=name, seconds=sec, ms_per_tick=1e3 * sec / n_ticks))
    return rows


def profile_markdown(p: dict) -> list[str]:
    """Markdown lines of one batch's profile (ablation table, then the controller's parts)."""
    if "n_ticks" not in p:
        return []                     # started, nothing measured yet
    lines = [f"### Closed-loop profile at batch {p['batch']} ({p['n_ticks']} ticks of "
             f"{p['substeps']} substeps, median of {p['repeats']})", "",
             "| variant | ms per tick | cost of the replaced part, ms per tick | share of full |",
             "|---|---|---|---|"]
    for r in p["rows"]:
        lines.append(f"| {r['variant']} | {r['ms_per_tick']:.3f} | {r['cost_ms_per_tick']:+.3f} "
                     f"| {100 * r['share_of_full']:+.1f} % |")
    if p.get("controller_parts") and p["rows"]:
        full = p["rows"][0]["ms_per_tick"]      # the full loop's row comes first
        lines += ["", "| controller part (alone) | ms per tick | share of full loop |",
                  "|---|---|---|"]
        lines += [f"| {c['part']} | {c['ms_per_tick']:.4f} | "
                  f"{100 * c['ms_per_tick'] / full:.1f} % |" for c in p["controller_parts"]]
    if p.get("trace_dir"):
        lines += ["", f"jax.profiler trace of the full loop: `{p['trace_dir']}`."]
    ts = p.get("trace_scopes") or {}
    if ts.get("scopes"):
        lines += ["", f"Trace events by named scope ({ts['events_matched']} events matched to "
                  f"the program's instructions, {ts['events_unmatched']} not):", "",
                  "| scope | ms per tick | share of matched |", "|---|---|---|"]
        lines += [f"| {k} | {v['ms_per_tick']:.4f} | "
                  + (f"{100 * v['share']:.1f} %" if v["share"] is not None else "-") + " |"
                  for k, v in ts["scopes"].items()]
    elif ts.get("error"):
        lines += ["", f"Trace by scope: {ts['error']}"]
    return lines
