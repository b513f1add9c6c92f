"""Adam on the clipped first-order gradient (the study's gradient method, push_clip 1), mlp
policy, CPU, small batch: the SOFT loss it descends and the HARD loss it is judged by, per
iterate. Shows whether the gradient descends its own surrogate while the hard loss climbs."""

import dataclasses
import json
import sys
import time
from pathlib import Path
import numpy as np
import jax
import jax.numpy as jnp
from tkujax.studies.tune.tune_spec import load_tune_spec, make_problem, sample_pushes
from tkujax.studies.tune.search import SearchConfig, first_order_grads
from tkujax.studies.tune.searchers import adam_update
from tkujax.studies.tune.methods import make_optimizer


def main() -> None:
    policy, n, iters = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    lr = float(sys.argv[4]) if len(sys.argv) > 4 else 0.05
    spec = dataclasses.replace(load_tune_spec("specs/tune/tune_dimension.toml"), batch=n)
    rep = spec.policy_reparam(policy)
    prob = make_problem(spec, rep)
    z = jnp.asarray(rep.latent_of(spec.base_params()))
    batch = sample_pushes(spec, n, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), n)
    tau = 0.5 * np.pi / 180
    cfg = SearchConfig(groups=4, push_clip=1.0, learning_rate=lr, clip_norm=1.0)
    opt = make_optimizer(cfg.learning_rate, cfg.clip_norm)
    state = opt.init(z)
    rows = []
    for it in range(iters):
        t = time.time()
        zc = np.asarray(z, float)
        g = first_order_grads(prob.grouped_value_and_grad, zc, tau, batch, keys, cfg, n).mean(0)
        hard = float(prob.forward(zc, 0.0, batch, keys)[0])
        soft = float(prob.forward(zc, tau, batch, keys)[0])
        rows.append(dict(it=it, hard=hard, soft=soft, gnorm=float(np.linalg.norm(g))))
        print(rows[-1], f"{time.time() - t:.0f} s", flush=True)
        z, state = adam_update(opt, z, state, jnp.asarray(g, z.dtype))
    json.dump(rows, open(Path(__file__).parent / f"soft_hard_{policy}_lr{lr:g}.json", "w"))


if __name__ == "__main__":
    main()
