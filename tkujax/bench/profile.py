"""`tkujax bench --profile`: what each part of the closed loop costs per control tick.

By ablation: the closed loop of the sweeps (`tkujax.sweeps.sweep.make_chunk_fn`: per-push
model fields, sensor noise, controller, push wrench, Series records and outcomes) is timed
whole, then with one part replaced by a trivial stand-in (`tkujax.bench.ablation`, a Python
choice at trace time, so the other parts' program is unchanged), at one batch and duration:

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
`tkujax.bench.controller_parts` times the controller's pieces alone.

Extra variants (`variants=`): "no_push" (the full program, every impulse 0: what the pushed,
falling states cost the physics, expected ~0), "unroll_substeps=K" / "unroll_ticks=K" (scan
unrolling), "loop=nested" / "loop=flat" (`ProgramOptions.loop`; the sweeps' SWEEP_LOOP
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

from tkujax.bench.ablation import ablated_rollout
from tkujax.bench.common import n_ticks, push_batch, substeps, timed, traced_paper_params
from tkujax.sim import physics
from tkujax.sim.options import LOOPS, Episode, ProgramOptions, RolloutConfig

# no_push is left out by default: MJX's cost does not depend on the state (static contact
# count; one Newton iteration; a line search of fixed length, its cond a select under vmap).
DEFAULT_VARIANTS = ("full", "no_noise", "no_controller", "no_wrench", "no_records",
                    "shared_model", "physics_only", "raw")
DEFAULT_COMPILE_WORKERS = max(1, min(8, os.cpu_count() or 1))
_ABLATE = {"no_noise": ("noise",), "no_controller": ("controller",), "no_wrench": ("wrench",),
           "no_records": ("records",),
           "physics_only": ("noise", "controller", "wrench", "records")}
_SHARED_MODEL = ("shared_model", "physics_only")


def variant_config(name: str) -> dict:
    """ProgramOptions fields (and "ablate": the ablated parts) of a variant name (see the
    module docstring); "A+B" combines the fields of A and B (e.g. "physics_only+loop=flat")."""
    if "+" in name:
        fields: dict = {}
        for part in name.split("+"):
            fields.update(variant_config(part))
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


def variant_loop_fn(name: str, duration_s: float):
    """jit(vmap) of (records, keys, params) -> outputs for a variant name."""
    parts = name.split("+")
    return loop_fn(duration_s, variant_config(name),
                   shared_model=any(p in _SHARED_MODEL for p in parts), raw=name == "raw")


def _raw_loop_fn(model, index, state, duration_s: float):
    """A flat scan of mjx.step holding the stand targets (the "raw" variant)."""
    from tkujax.sweeps.sweep import SWEEP_COMPILER_OPTIONS

    n_steps = n_ticks(duration_s) * substeps()
    ctrl = jnp.asarray(index.stand_ctrl, state.qpos.dtype)

    def flat(rec, key, params):
        return physics.step_holding(model, per_robot(state, rec), ctrl, n_steps)[0].qpos[2]

    return jax.jit(jax.vmap(flat, in_axes=(0, 0, None)), compiler_options=SWEEP_COMPILER_OPTIONS)


def loop_fn(duration_s: float, config_fields: dict | None = None, shared_model: bool = False,
            raw: bool = False):
    """jit(vmap) of (records, keys, params) -> outputs, built as make_chunk_fn builds the
    sweeps' chunk (with no fields and no flags it is that program: the outcomes of
    OUTCOME_KEYS), with ProgramOptions fields and "ablate" (tkujax.bench.ablation.ABLATIONS)
    in `config_fields`; shared_model: no per-push model fields; raw: a flat scan of mjx.step
    holding the stand targets for as many steps instead."""
    from tkujax.sim.metrics import outcomes as rollout_outcomes
    from tkujax.sim.push import Push
    from tkujax.sim.randomize import randomize_model
    from tkujax.sim.setup import init
    from tkujax.dialects.sweep_spec import SWEEP_TREE_PASSES
    from tkujax.sweeps.sweep import OUTCOME_KEYS, SWEEP_COMPILER_OPTIONS, SWEEP_LOOP

    host, model, index, state = init()
    if raw:
        return _raw_loop_fn(model, index, state, duration_s)
    # The sweeps' loop and tree passes unless overridden.
    fields = {"loop": SWEEP_LOOP, "tree_passes": SWEEP_TREE_PASSES[0]} | (config_fields or {})
    ablate = tuple(fields.pop("ablate", ()))
    config = RolloutConfig(duration_s=duration_s, program=ProgramOptions(**fields))
    # With noise, controller and wrench all stood in for, nothing depends on the record:
    # vmap would step one robot and broadcast it. The state is made per robot instead.
    alone = {"noise", "controller", "wrench"} <= set(ablate)

    def one(rec, key, params):
        push = Push(rec["impulse_ns"], jnp.radians(rec["azimuth_deg"]), rec["height_m"],
                    rec["duration_s"], rec["onset_s"])
        m = model if shared_model else randomize_model(
            model, index.chest_body, mass_scale=rec["link_mass_scale"],
            torso_com_dx_m=rec["torso_com_offset_x_m"], friction=rec["floor_friction"],
            kp_scale=rec["servo_kp_scale"])
        episode = Episode(push, rec["control"], key, rec["gyro_noise_std"],
                          rec["accel_noise_std"])
        series = ablated_rollout(m, per_robot(state, rec) if alone else state, episode, params,
                                 config, index, ablate)
        if "records" in ablate:
            return series[-1]
        out = rollout_outcomes(series, push.onset_s)
        return {k: out[k] for k in OUTCOME_KEYS}

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None)), compiler_options=SWEEP_COMPILER_OPTIONS)


def per_robot(state, rec):
    """The state made to depend on the record (qpos + 0 * impulse: the same values; XLA keeps
    floating-point x * 0), so that under vmap the physics runs once per robot."""
    return state.replace(qpos=state.qpos + 0.0 * rec["impulse_ns"].astype(state.qpos.dtype))


def profile_closed_loop(batch: int, duration_s: float = 0.3, repeats: int = 1,
                        variants=DEFAULT_VARIANTS, compile_workers: int = DEFAULT_COMPILE_WORKERS,
                        trace_dir: str | Path | None = None, log=None, into: dict | None = None,
                        on_update=None) -> dict:
    """The ablation table at one batch (see the module docstring). `into`: the dict to fill
    (returned), `on_update()`: called after each timed variant (the bench rewrites its JSON:
    a run cut short keeps the rows measured so far)."""
    log = log or (lambda msg: None)
    on_update = on_update or (lambda: None)
    variants = ("full",) + tuple(v for v in variants if v != "full")
    for v in variants:
        if v != "no_push":
            variant_config(v)           # unknown names fail before any compile
    params = traced_paper_params()
    recs = push_batch(batch)
    # The push inside the (short) rollout: the controller detects it and steps.
    recs["onset_s"] = jnp.full_like(recs["onset_s"], min(0.3, duration_s / 3))
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    ticks = n_ticks(duration_s)
    result = into if into is not None else {}
    result.update(batch=batch, duration_s=duration_s, n_ticks=ticks, substeps=substeps(),
                  repeats=repeats, compile_workers=compile_workers, rows=[])
    programs = [v for v in variants if v != "no_push"]
    t0 = time.perf_counter()
    lowered = {}
    for v in programs:
        lowered[v] = variant_loop_fn(v, duration_s).lower(recs, keys, params)
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
        sec = timed(lambda exe=exe, r=r: exe(r, keys, params), repeats)
        full = sec if full is None else full
        result["rows"].append(dict(variant=v, seconds=sec, ms_per_tick=1e3 * sec / ticks,
                                   cost_ms_per_tick=1e3 * (full - sec) / ticks,
                                   share_of_full=(full - sec) / full))
        log(f"profile {batch}: {v} {1e3 * sec / ticks:.3f} ms/tick")
        on_update()
    if trace_dir:
        trace = Path(trace_dir) / f"batch{batch}"
        try:     # best effort: a profiler that cannot start must not lose the table
            trace.mkdir(parents=True, exist_ok=True)
            exe = compiled["full"]
            with jax.profiler.trace(str(trace)):
                jax.block_until_ready(exe(recs, keys, params))
            result["trace_dir"] = str(trace)
            result["trace_scopes"] = trace_scopes(trace, exe.as_text(), ticks)
        except Exception as err:  # noqa: BLE001
            result["trace_scopes"] = dict(error=f"{type(err).__name__}: {err}"[:500])
            log(f"profile {batch}: trace failed: {result['trace_scopes']['error']}")
    return result


SCOPES = ("push_wrench", "mjx_step", "sensors", "controller", "records", "physics")
NO_KERNEL_OPS = ("while", "call", "conditional", "tuple", "get-tuple-element", "parameter",
                 "constant", "bitcast")


def _instruction_scopes(hlo_text: str) -> dict[str, str]:
    """{HLO instruction name: the innermost named scope of the rollout in its op_name} for the
    instructions of the optimised module that can run as kernels (not loops or calls)."""
    pat = re.compile(r'^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*\S.*?\s([a-z][\w\-]*)\(.*'
                     r'op_name="([^"]*)"')
    out = {}
    for line in hlo_text.splitlines():
        m = pat.match(line)
        if not m or m.group(2) in NO_KERNEL_OPS:
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
