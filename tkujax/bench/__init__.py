"""`tkujax bench`: throughput of the same TKU-X push sweep, measured side by side.

  a. raw MJX stepping of TKU-X holding fixed targets (no controller): physics steps/s;
  b. the closed-loop sweep (sensors, controller, metrics): physics steps/s and pushes/s;
  c. the CPU peer: MuJoCo C physics across all cores with the JAX controller between ticks;
  d. one tuning gradient step: time and the process's peak device memory;
  e. compile time of (b), cold (empty persistent cache) and from the persistent cache;
  f. compile time of the tuning gradient, per variant of its program (remat, unrolling);
  g. the profile of (b): what each part costs per control tick.

Modules (imports go one way, top to bottom):

  common.py            the timing rule, the push batch, the traced parameters
  ablation.py          the closed loop with parts stood in for (from the rollout's pieces)
  stages.py            a-f, each a function of its sizes returning its JSON record
  profile.py           g: the ablation table, the jax.profiler trace by named scope
  controller_parts.py  g: the controller's pieces timed alone
  report.py            the Markdown summary
  runner.py            BenchConfig, MODES, run_bench: the stages one by one, resumable
  cli.py               add_bench_command: the `tkujax bench` command

Speeds are reported, never asserted.
"""

from __future__ import annotations

import importlib

# Names resolved on first use (as tkujax/__init__.py does): `tkujax.cli` registers the bench
# command through tkujax.bench.cli, and importing the stages here would import mujoco before
# the command line has chosen its GL backend (tkujax.cli.runtime.configure_runtime).
_API = {
    **dict.fromkeys(("push_batch", "timed", "traced_paper_params"), "tkujax.bench.common"),
    **dict.fromkeys(("loop_fn", "per_robot", "variant_loop_fn"), "tkujax.bench.profile"),
    **dict.fromkeys(("profile_markdown", "summary_markdown"), "tkujax.bench.bench_summary"),
    **dict.fromkeys(("MODES", "STAGE_GROUPS", "BenchConfig", "run_bench"),
                    "tkujax.bench.runner"),
    **dict.fromkeys(("closed_loop", "compile_times", "cpu_peer", "gradient_compile",
                     "parse_grad_variants", "raw_program", "raw_stepping"),
                    "tkujax.bench.stages"),
}

__all__ = sorted(_API)


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'tkujax.bench' has no attribute {name!r}")
