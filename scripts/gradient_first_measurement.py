"""First measurement (CPU, small batch): per-push gradients through MJX of the tuning loss and
of the bounded margin loss in 10 scalar parameters of the recommended controller; their
diagnostics; the predicted vs measured change of each loss along -g on the training pushes
(MJX forward); the hard fall count on held-out pushes along -g (MuJoCo C).

  python scripts/gradient_first_measurement.py --out /tmp/first [--n 32] [--duration 1.2]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from tkujax.control import ControllerParams
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.gradients import diagnostics as dg
from tkujax.studies.gradient_measure import (Latent, batch_functions, loss_names, make_per_push,
                                             pushes_from)

CPU_OPTIONS = {"xla_llvm_disable_expensive_passes": True}


def sample(n: int, seed: int, impulse_ns):
    rng = np.random.default_rng(seed)
    return pushes_from(rng.uniform(*impulse_ns, n), rng.uniform(0, 2 * np.pi, n),
                       0.1 + 0.03 * rng.uniform(0, 1, n))


def held_out_falls(latent: Latent, z, pushes, duration_s: float) -> dict:
    _, out = simulate_mujoco(pushes, 1.0, latent.concrete(z),
                             config=RolloutConfig(duration_s=duration_s), n_threads=1)
    keep = ~np.asarray(out.diverged)
    return dict(fell=int(np.asarray(out.fell)[keep].sum()), diverged=int((~keep).sum()))


def directions(G: np.ndarray) -> dict[str, np.ndarray]:
    """Descent candidates per loss: the mean and the per-push clip at the median norm."""
    med = float(np.median(np.linalg.norm(G, axis=1)))
    return {"mean": G.mean(0), "clip_median": dg.clip_rows(G, med).mean(0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--n-held-out", type=int, default=192)
    ap.add_argument("--duration", type=float, default=1.2)
    ap.add_argument("--eval-duration", type=float, default=None,
                    help="held-out MuJoCo C horizon (s; default --duration)")
    ap.add_argument("--timing-gradient", action="store_true")
    ap.add_argument("--z0", default="", help="start latents, e.g. cp_gain=-3,step_period=2 "
                    "(field = recommended + scale * z; default all 0: the recommended controller)")
    ap.add_argument("--margins", default="margin", help="comma-separated names of MARGINS")
    ap.add_argument("--steps", default="0.1,0.3,1.0", help="step sizes along -g (latent units)")
    a = ap.parse_args()
    margins = tuple(a.margins.split(","))
    losses = loss_names(margins)
    steps = tuple(float(x) for x in a.steps.split(","))
    eval_s = a.eval_duration or a.duration
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    latent = Latent(ControllerParams.recommended(), timing_gradient=a.timing_gradient)
    d = len(latent.names)
    z0 = np.zeros(d, np.float32)
    for item in filter(None, a.z0.split(",")):
        name, value = item.split("=")
        z0[latent.names.index(name)] = float(value)
    train = sample(a.n, 1, (1.2, 2.6))
    held = sample(a.n_held_out, 2, (1.2, 2.6))
    keys = jax.random.split(jax.random.PRNGKey(0), a.n)
    fwd, jac = batch_functions(make_per_push(latent, a.duration, margins), CPU_OPTIONS)
    res = dict(device="cpu", n=a.n, duration_s=a.duration, eval_duration_s=eval_s,
               params=list(latent.names), z0=z0.tolist(),
               timing_gradient=a.timing_gradient)
    t0 = time.time()
    J = np.asarray(jac(z0, train, keys))                      # (n, 2, d)
    res["jacobian_s"] = time.time() - t0
    L0, aux = fwd(z0, train, keys)
    L0 = np.asarray(L0)
    res["train"] = dict(fell=int(np.asarray(aux["fell"]).sum()),
                        mean_loss={k: float(L0[:, i].mean()) for i, k in enumerate(losses)})
    print("jacobian", res["jacobian_s"], "s;", res["train"], flush=True)
    np.savez(out / "per_push.npz", J=J, L=L0, margin_m=np.asarray(aux["margin_m"]),
             fell=np.asarray(aux["fell"]))
    res["nonfinite_grads"] = int((~np.isfinite(J)).any(axis=(1, 2)).sum())
    J = np.where(np.isfinite(J), J, 0.0)
    base_falls = held_out_falls(latent, z0, held, eval_s)
    res["held_out"] = dict(n=a.n_held_out, base=base_falls)
    for i, name in enumerate(losses):
        G = J[:, i, :]
        res[name] = dict(diagnostics=dg.summary(G), steps={})
        for dname, g in directions(G).items():
            loss = lambda z, i=i: float(np.asarray(fwd(np.float32(z), train, keys)[0])[:, i].mean())  # noqa: E731
            checks = dg.step_check(loss, z0, g, steps)
            falls = {s: held_out_falls(latent, z0 - s * g / np.linalg.norm(g), held, eval_s)
                     for s in steps}
            res[name]["steps"][dname] = dict(
                direction=(g / np.linalg.norm(g)).tolist(),
                predicted=[c.predicted for c in checks], measured=[c.measured for c in checks],
                held_out_fell={str(s): f["fell"] for s, f in falls.items()})
            print(name, dname, res[name]["steps"][dname], flush=True)
        (out / "first_measurement.json").write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps({k: res[k]["diagnostics"] for k in losses}, indent=1))


if __name__ == "__main__":
    main()
