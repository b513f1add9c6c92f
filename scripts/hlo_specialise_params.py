"""Upper bound of building unused controller options out of the sweep program (results/bench/specialise_hlo_cpu.txt), on
the CPU: the sweep chunk (batch 4 x 0.3 s) compiled with the controller parameters traced (as
the sweeps run) and with every parameter a compile-time constant; prints the three largest
computations of each optimised HLO (ops, fusions, copies) and checks the outcomes agree.
Run from the project root: python scripts/hlo_specialise_params.py"""
# ruff: noqa: B023, E501   (research script)

import re
import time
import collections
import jax
import jax.numpy as jnp
from tkujax.bench import push_batch
from tkujax.sweeps.sweep import make_chunk_fn, traced_params
from tkujax.control.controller_params import ControllerParams


def main() -> None:
    B = 4
    recs = push_batch(B)
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    fn = make_chunk_fn((), 0.3)


    def body_counts(txt):
        comps = re.split(r"\n\n", txt)
        res = []
        for comp in comps:
            head = comp.strip().split("\n", 1)[0]
            ops = collections.Counter(re.findall(r"= [^=]*? (\w[\w\-\.]*)\(", comp))
            res.append((sum(ops.values()), ops["fusion"], ops["copy"], head[:40]))
        return sorted(res, reverse=True)[:3]


    for name, p in (
        ("paper", ControllerParams.paper()),
        ("recommended", ControllerParams.recommended()),
    ):
        tp = traced_params(p)
        t = time.time()
        c1 = fn.lower(recs, keys, tp).compile()
        t1 = time.time() - t
        txt1 = c1.as_text()
        const = jax.jit(lambda r, k: fn(r, k, p))
        t = time.time()
        c2 = const.lower(recs, keys).compile()
        t2 = time.time() - t
        txt2 = c2.as_text()
        o1 = fn(recs, keys, tp)
        o2 = const(recs, keys)
        same = all(bool(jnp.array_equal(o1[k], o2[k], equal_nan=True)) for k in o1)
        print(name, "traced", len(txt1), body_counts(txt1), round(t1, 1))
        print(name, "const ", len(txt2), body_counts(txt2), round(t2, 1), "same outcomes", same)


if __name__ == "__main__":
    main()
