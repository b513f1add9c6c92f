"""Is the soft-gate gradient a descent direction of the hard loss, for the mlp policy? (CPU)"""

import dataclasses
import sys
import time
import numpy as np
import jax
from tkujax.studies.tune.tune_spec import load_tune_spec, make_problem, sample_pushes


def main() -> None:
    policy = sys.argv[1] if len(sys.argv) > 1 else "mlp"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 64
    spec = load_tune_spec("specs/tune/tune_dimension.toml")
    spec = dataclasses.replace(spec, batch=n)
    rep = spec.policy_reparam(policy)
    prob = make_problem(spec, rep)
    z0 = rep.latent_of(spec.base_params())
    batch = sample_pushes(spec, n, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), n)
    tau = 0.5 * np.pi / 180
    t = time.time()
    losses, grads = prob.grouped_value_and_grad(z0, tau, batch, keys, 4)
    print("grad", time.time() - t, "s; soft losses", losses, flush=True)
    g = grads.mean(0)
    k = rep.k
    print(
        "norm g",
        np.linalg.norm(g),
        "scalar part",
        np.linalg.norm(g[:k]),
        "schedule part",
        np.linalg.norm(g[k:]),
    )
    se = np.sqrt(grads.var(0, ddof=1).sum() / 4)
    print("std err of g (norm)", se)
    cos = [
        float(grads[i] @ grads[j] / np.linalg.norm(grads[i]) / np.linalg.norm(grads[j]))
        for i in range(4)
        for j in range(i + 1, 4)
    ]
    print("cos between group grads", np.round(cos, 3))
    d = -g / np.linalg.norm(g)
    ts = [0.01, 0.03, 0.1, 0.3, 1.0]
    rng = np.random.default_rng(0)
    r = rng.standard_normal(g.shape)
    r /= np.linalg.norm(r)
    s = -np.sign(g)
    s /= np.linalg.norm(s)
    zs = [z0] + [z0 + tt * d for tt in ts] + [z0 + tt * s for tt in ts] + [z0 + tt * r for tt in ts]
    t = time.time()
    h = prob.population(np.stack(zs), 0.0, batch, keys)
    print("pop", time.time() - t, "s")
    print("hard at z0", h[0])
    for name, o in (("-g", 1), ("-sign g", 1 + len(ts)), ("random", 1 + 2 * len(ts))):
        print(name, {tt: round(float(h[o + i] - h[0]), 4) for i, tt in enumerate(ts)})
    soft = prob.population(np.stack(zs[: 1 + len(ts)]), tau, batch, keys)
    print(
        "soft along -g",
        {tt: round(float(soft[1 + i] - soft[0]), 4) for i, tt in enumerate(ts)},
        "pred",
        {tt: round(float(-tt * np.linalg.norm(g)), 4) for tt in ts},
    )


if __name__ == "__main__":
    main()
