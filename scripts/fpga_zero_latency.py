"""FPGA twin diagnostic: the pushes of results/fpga_latency at zero latency with the largest step
gaps, re-run on MuJoCo C with the old (`ik_guard_bits = 0`) and the current datapath
(results/fpga/README.md, section 1, "The latency study's ~45 mm")."""
# ruff: noqa: E731, UP031   (research script)

import numpy as np
import jax.numpy as jnp
import dataclasses
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.dialects.sweep_spec import fixed_point_config


def main() -> None:
    cases = [
        (0.3, 180),
        (1.0, 135),
        (0.7, 90),
        (0.9, 270),
        (1.0, 90),
        (0.3, 90),
        (0.3, 45),
        (0.8, 225),
        (1.4, 90),
        (0.4, 225),
        (0.5, 135),
        (0.8, 135),
    ]
    imp = np.array([c[0] for c in cases])
    az = np.array([c[1] for c in cases], float)
    n = len(cases)
    P = Push(
        jnp.asarray(imp, jnp.float32),
        jnp.radians(jnp.asarray(az, jnp.float32)),
        jnp.full(n, 0.36, jnp.float32),
        jnp.full(n, 0.02, jnp.float32),
        jnp.full(n, 0.5, jnp.float32),
    )
    params = dataclasses.replace(ControllerParams.paper(), lateral_steps=1.0)
    res = {}
    for name, cfg in [
        ("float", None),
        ("new", fixed_point_config({"angle_state_frac_bits": 16, "cordic_iterations": 16})),
        (
            "old",
            fixed_point_config(
                {"angle_state_frac_bits": 16, "cordic_iterations": 16, "ik_guard_bits": 0}
            ),
        ),
    ]:
        res[name] = simulate_mujoco(
            P, np.ones(n, np.float32), params, config=RolloutConfig(duration_s=2.0, fixed=cfg)
        )[1]
    f = res["float"]
    for i in range(n):
        print(
            cases[i],
            "fell",
            int(f["fell"][i]),
            int(res["old"]["fell"][i]),
            int(res["new"]["fell"][i]),
            "step float %.2f old %.2f new %.2f mm"
            % tuple(1e3 * res[k]["step_length_m"][i] for k in ("float", "old", "new")),
        )
    both = lambda k: (~f["fell"].astype(bool)) & (~res[k]["fell"].astype(bool))
    for k in ("old", "new"):
        d = 1e3 * np.abs(res[k]["step_length_m"] - f["step_length_m"])[both(k)]
        print(
            k,
            "n both stand",
            len(d),
            "max |dstep| mm %.2f" % d.max(),
            "median %.2f" % np.median(d),
            "fall outcomes equal",
            bool((res[k]["fell"] == f["fell"]).all()),
        )


if __name__ == "__main__":
    main()
