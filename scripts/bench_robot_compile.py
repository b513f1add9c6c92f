"""Where a robot's cold compile goes, and what its MJX step costs (docs/performance.md,
"Compile time per robot"; results/bench/*_robot_compile.json).

    python scripts/bench_robot_compile.py OUT.json [--batch 1024] [--cases tkux,op3,...]
        [--stages closed_loop,raw]

A case is TKU-X or a robot file, some with one table added ([collision] floor = "feet": only
the feet touch the floor; [solver]: the solver's iteration caps), written beside a copy of the
file's controller files in a temporary folder. Per case:

- the model's size: bodies, geoms, DOF, actuators, sensors; MJX's collision functions (one per
  geom-type pair, mesh and condim: `_geom_groups`, each traced and compiled on its own) and
  the contacts a step computes; the solver's caps;
- in an empty persistent cache, with JAX's in-process caches cleared: the sweeps' closed-loop
  chunk (`make_chunk_fn`, 1.5 s, the paper's controller traced) traced and lowered, then
  compiled, timed apart, with the size of its lowered program; then its run at the batch
  (pushes/s, the compile excluded);
- the same for raw MJX stepping (`mjx.step` holding the stand's targets, 45 steps, vmapped).

The figures are the device's; XLA's in-process autotuning results can carry from one case to
the next (the cases run in one process), so a later case's compile is at most as cold as the
first's. The JSON is rewritten after every case.
"""
# ruff: noqa: E501   (research script)

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = ROOT / "specs" / "robots"
FEET = '\n[collision]\nfloor = "feet"\n'
SOLVER_CAPS = '\n[solver]\niterations = 10\nls_iterations = 20\n'
CASES = {
    "tkux": (None, ""),
    "op3": ("op3.toml", ""),
    "op3_solver_caps": ("op3.toml", SOLVER_CAPS),
    "op3_feet_floor": ("op3.toml", FEET),
    "op3_fast": ("op3_fast.toml", ""),
    "t1": ("t1.toml", ""),
    "t1_feet_floor": ("t1.toml", FEET),
}
RAW_STEPS = 45          # 3 control ticks of TKU-X's 2 ms steps


def case_file(name: str, folder: Path) -> str | None:
    """The case's robot file: as committed, or a copy with its extra table and the controller
    files it names beside it."""
    base, extra = CASES[name]
    if base is None:
        return None
    if not extra:
        return str(ROBOTS / base)
    text = (ROBOTS / base).read_text()
    for ref in re.findall(r'^\s*(?:walk_)?controller\s*=\s*"([^"]+)"', text, re.MULTILINE):
        shutil.copy(ROBOTS / ref, folder / ref)
    mjcf = re.search(r'^mjcf\s*=\s*"([^"]+)"', text, re.MULTILINE).group(1)
    absolute = mjcf.replace("../../../shared/models", str(ROOT.parent / "shared" / "models"))
    text = text.replace(mjcf, absolute) + extra
    path = folder / f"{name}.toml"
    path.write_text(text)
    return str(path)


def model_facts(robot) -> dict:
    from mujoco.mjx._src.collision_driver import _geom_groups

    m = robot.host_model
    groups = _geom_groups(m)
    by_types: dict[str, int] = {}
    for key, pairs in groups.items():
        label = "-".join(mujoco.mjtGeom(int(t)).name[7:].lower() for t in key.types)
        by_types[label] = by_types.get(label, 0) + len(pairs)
    return dict(nbody=m.nbody, ngeom=m.ngeom, nv=m.nv, nu=m.nu, nsensor=m.nsensor,
                nsensordata=m.nsensordata, collision_functions=len(groups),
                collision_pairs=sum(len(p) for p in groups.values()),
                pairs_by_types=by_types, contacts_per_step=int(robot.stand_state._impl.contact.dist.shape[0]),
                timestep_s=float(m.opt.timestep), iterations=int(m.opt.iterations),
                ls_iterations=int(m.opt.ls_iterations))


def timed_compile(fn, *args) -> tuple[dict, object]:
    from tkujax.sweeps.compile_cache import fresh_compilation_cache

    with fresh_compilation_cache():
        jax.clear_caches()
        t0 = time.perf_counter()
        lowered = fn.lower(*args)
        t1 = time.perf_counter()
        exe = lowered.compile()
        t2 = time.perf_counter()
    return dict(lower_s=round(t1 - t0, 2), compile_s=round(t2 - t1, 2),
                hlo_chars=len(lowered.as_text())), exe


def run_time(exe, *args) -> float:
    jax.block_until_ready(exe(*args))
    t0 = time.perf_counter()
    jax.block_until_ready(exe(*args))
    return time.perf_counter() - t0


def closed_loop(robot, batch: int) -> dict:
    from tkujax.bench.common import push_batch
    from tkujax.sweeps.sweep import make_chunk_fn, traced_params

    duration_s = 1.5
    fn = make_chunk_fn((), duration_s, robot)
    recs = push_batch(batch)
    recs["height_m"] = jnp.full(batch, float(robot.params.com_height), jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    params = traced_params(robot.params)
    record, exe = timed_compile(fn, recs, keys, params)
    sec = run_time(exe, recs, keys, params)
    return record | dict(batch=batch, duration_s=duration_s, run_s=round(sec, 3),
                         pushes_per_s=round(batch / sec, 1))


def raw(robot, batch: int) -> dict:
    from tkujax.sim import physics
    from tkujax.sweeps.sweep import SWEEP_COMPILER_OPTIONS

    model, stand = robot.device_model, robot.stand_state
    ctrl = jnp.asarray(stand.ctrl)
    fn = jax.jit(jax.vmap(lambda d: physics.step_holding(model, d, ctrl, RAW_STEPS)[0].qpos),
                 compiler_options=SWEEP_COMPILER_OPTIONS)
    state = physics.batch_state(stand, batch)
    record, exe = timed_compile(fn, state)
    sec = run_time(exe, state)
    return record | dict(batch=batch, steps=RAW_STEPS, run_s=round(sec, 4),
                         steps_per_s=round(batch * RAW_STEPS / sec))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--stages", default="closed_loop,raw")
    args = ap.parse_args()
    from tkujax.robot import builtin_robot, robot_from_file

    names = [c for c in args.cases.split(",") if c]
    unknown = sorted(set(names) - set(CASES))
    if unknown:
        raise SystemExit(f"--cases: unknown {unknown}; known: {sorted(CASES)}")
    d = jax.devices()[0]
    out = dict(device=getattr(d, "device_kind", d.platform), jax=jax.__version__,
               batch=args.batch, cases={})
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            t0 = time.perf_counter()
            path = case_file(name, Path(tmp))
            robot = builtin_robot() if path is None else robot_from_file(path)
            record = dict(robot=robot.name, extra=CASES[name][1].strip(),
                          load_s=round(time.perf_counter() - t0, 1), model=model_facts(robot))
            stages = {"closed_loop": closed_loop, "raw": raw}
            for stage in args.stages.split(","):
                fn = stages[stage]
                try:
                    record[stage] = fn(robot, args.batch)
                except Exception as exc:  # noqa: BLE001 -- recorded; the next stage runs
                    record[stage] = dict(error=f"{type(exc).__name__}: {exc}"[:500])
                print(f"[{name}] {stage}: {record[stage]}", flush=True)
            out["cases"][name] = record
            Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: {s: {f: v[s].get(f) for f in ("lower_s", "compile_s")}
                          for s in args.stages.split(",")} for k, v in out["cases"].items()}))


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    np.set_printoptions(precision=3)
    main()
