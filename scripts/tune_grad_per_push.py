"""Per-push gradients of the soft-gate loss (mlp policy, CPU): their norm distribution, and
whether a per-push clipped mean is a descent direction of the hard loss."""
# ruff: noqa: UP031   (research script)

import dataclasses
import sys
import time
import numpy as np
import jax
from tkujax.studies.tune.tune_spec import load_tune_spec, make_problem, sample_pushes


def main() -> None:
    policy = sys.argv[1]
    n = int(sys.argv[2])
    spec = dataclasses.replace(load_tune_spec("specs/tune/tune_dimension.toml"), batch=n)
    rep = spec.policy_reparam(policy)
    prob = make_problem(spec, rep)
    z0 = rep.latent_of(spec.base_params())
    batch = sample_pushes(spec, n, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), n)
    tau = 0.5 * np.pi / 180
    t = time.time()
    L, G = prob.grouped_value_and_grad(z0, tau, batch, keys, n)
    print("per-push grads", time.time() - t, "s", flush=True)
    norms = np.linalg.norm(G, axis=1)
    print(
        "norm quantiles 0,10,50,90,99,100:",
        np.round(np.quantile(norms, [0, 0.1, 0.5, 0.9, 0.99, 1]), 4),
    )
    print("share of squared norm in top 5 pushes:", np.sort(norms**2)[-5:].sum() / (norms**2).sum())
    print(
        "impulse of top-5:",
        np.round(batch["impulse_ns"][np.argsort(norms)[-5:]], 2),
        "loss of top-5",
        np.round(L[np.argsort(norms)[-5:]], 2),
    )
    np.savez("/tmp/diag/push_grads_%s.npz" % policy, G=G, L=L, imp=batch["impulse_ns"])


    def desc(g):
        return -g / np.linalg.norm(g)


    med = np.median(norms)
    clipped = G * np.minimum(1.0, med / np.maximum(norms, 1e-12))[:, None]
    dirs = {"mean": desc(G.mean(0)), "clip@median": desc(clipped.mean(0))}
    # half-batch agreement: cosine between the two halves' directions (a noise gauge)
    for name, GG in (("mean", G), ("clip@median", clipped)):
        a, b = GG[: n // 2].mean(0), GG[n // 2 :].mean(0)
        print(name, "cos(halves)", round(float(a @ b / np.linalg.norm(a) / np.linalg.norm(b)), 3))
    ts = [0.03, 0.1, 0.3, 1.0]
    zs = [z0] + [z0 + t * d for d in dirs.values() for t in ts]
    h = prob.population(np.stack(zs), 0.0, batch, keys)
    for i, name in enumerate(dirs):
        print(name, {t: round(float(h[1 + i * len(ts) + j] - h[0]), 4) for j, t in enumerate(ts)})


if __name__ == "__main__":
    main()
