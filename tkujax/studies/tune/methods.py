"""Optimisers over the latents: gradient descent (optax) and the (1+1)-ES baseline."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from tkujax.studies.tune.reparam import DEG, TUNABLE, Reparam


def temperature_schedule(start_deg: float, end_deg: float, n: int,
                         kind: str = "geometric") -> np.ndarray:
    """(n,) gate temperatures in radians from start to end (anneals toward the hard gate)."""
    k = np.arange(n) / max(n - 1, 1)
    if kind == "geometric":
        deg = start_deg * (end_deg / start_deg) ** k
    elif kind == "linear":
        deg = start_deg + (end_deg - start_deg) * k
    else:
        raise ValueError(f"schedule must be 'geometric' or 'linear', got {kind!r}")
    return deg * DEG


def make_optimizer(learning_rate: float, clip_norm: float) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(clip_norm), optax.adam(learning_rate))


StepFn = Callable[[np.ndarray, float], tuple[float, dict, np.ndarray]]


def optimise(step_fn: StepFn, z0, temperatures, optimizer: optax.GradientTransformation,
             reparam: Reparam | None = None, log: Callable[[str], None] | None = print,
             pushes_per_step: int = 0) -> tuple[np.ndarray, list[dict]]:
    """Gradient descent on latents. step_fn(z, temperature) -> (loss, aux, grad) (numpy).

    A non-finite loss or gradient is skipped: the latents and the optimiser state stay as they
    were; the iteration is recorded with skipped = True. Returns (final z, history rows)."""
    z = jnp.asarray(np.asarray(z0, float))
    opt_state = optimizer.init(z)

    @jax.jit
    def apply(z, opt_state, g):
        updates, opt_state = optimizer.update(g, opt_state, z)
        return optax.apply_updates(z, updates), opt_state

    history, n_skipped = [], 0
    t0 = time.perf_counter()
    for it, tau in enumerate(np.asarray(temperatures, float)):
        z_before = np.asarray(z, float)
        loss, aux, g = step_fn(z_before, float(tau))
        g = np.asarray(g, float)
        finite = bool(np.isfinite(loss) and np.all(np.isfinite(g)))
        gnorm = float(np.linalg.norm(g)) if finite else float("nan")
        if finite:
            z, opt_state = apply(z, opt_state, jnp.asarray(g, z.dtype))
        else:
            n_skipped += 1
        terms = aux.get("terms", {}) if isinstance(aux, dict) else {}
        row = dict(iteration=it, temperature_deg=float(tau) / DEG, loss=or_none(loss),
                   terms={k: or_none(np.mean(v)) for k, v in terms.items()},
                   grad_norm=gnorm, grad=[or_none(x) for x in g], finite=finite, skipped=not finite,
                   n_nonfinite_grad=int(np.sum(~np.isfinite(g))), latent=z_before.tolist(),
                   wall_s=round(time.perf_counter() - t0, 3),
                   pushes_simulated=(it + 1) * pushes_per_step)
        if reparam is not None:
            row["params"] = reparam.user(z_before)
        history.append(row)
        if log:
            log(_progress_line(row, len(temperatures), reparam, n_skipped))
    return np.asarray(z, float), history


def or_none(x) -> float | None:
    """x as a float, None where it is not finite (JSON has no NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _progress_line(row: dict, n: int, reparam: Reparam | None, n_skipped: int) -> str:
    loss = "nan" if row["loss"] is None else f"{row['loss']:.4f}"
    terms = " ".join(f"{k} {v:.3g}" for k, v in row["terms"].items()
                     if k in ("fall", "recovery", "step") and v is not None)
    terms = f" ({terms})" if terms else ""
    text = (f"it {row['iteration'] + 1:3d}/{n}  tau {row['temperature_deg']:.2f} deg  loss {loss}"
            f"{terms}  |g| {row['grad_norm']:.3g}")
    if reparam is not None:
        text += "  " + _fmt_params(row["params"])
    if row["skipped"]:
        text += f"  SKIPPED: non-finite loss/gradient ({n_skipped} so far)"
    return text


def _fmt_params(user: dict) -> str:
    names = {"step_period": "T", "double_support_ratio": "gamma", "lift_height": "H",
             "eps_forward": "eps1", "eps_backward": "eps2", "cp_gain": "k_cp",
             "kalman_q": "q", "kalman_r": "r"}
    out = []
    for f, v in user.items():
        unit = TUNABLE[f][3]
        out.append(f"{names[f]} {v:.3g}{' ' + unit if unit and unit != 'rad^2' else ''}")
    return ", ".join(out)


def evolution_baseline(loss_fn: Callable[[np.ndarray], float], z0, n_evals: int,
                       sigma0: float = 0.5, seed: int = 0,
                       log: Callable[[str], None] | None = print,
                       pushes_per_eval: int = 0) -> tuple[np.ndarray, list[dict]]:
    """(1+1)-ES with the 1/5 success rule in latent space, n_evals loss evaluations in all
    (the first is the start point). Candidates z + sigma N(0, I) (jax.random); a candidate
    replaces the incumbent when its loss is lower (non-finite losses never do). Returns
    (best z, rows)."""
    key = jax.random.PRNGKey(seed)
    z = np.asarray(z0, float)
    best = float(loss_fn(z))
    best = best if math.isfinite(best) else math.inf
    sigma = sigma0
    rows = [dict(evaluation=0, loss=or_none(best), best_loss=or_none(best), sigma=sigma,
                 accepted=True, latent=z.tolist(), pushes_simulated=pushes_per_eval)]
    up, down = 1.5, 1.5 ** -0.25              # 1/5 rule: stationary at a 20% success rate
    for i in range(1, n_evals):
        key, sub = jax.random.split(key)
        cand = z + sigma * np.asarray(jax.random.normal(sub, z.shape), float)
        loss = float(loss_fn(cand))
        ok = math.isfinite(loss) and loss < best
        if ok:
            z, best, sigma = cand, loss, sigma * up
        else:
            sigma = sigma * down
        rows.append(dict(evaluation=i, loss=or_none(loss), best_loss=or_none(best), sigma=sigma,
                         accepted=ok, latent=cand.tolist(),
                         pushes_simulated=(i + 1) * pushes_per_eval))
        if log:
            log(f"es  {i + 1:3d}/{n_evals}  loss {loss:.4f}  best {best:.4f}  sigma {sigma:.3f}"
                f"{'  accepted' if ok else ''}")
    return z, rows
