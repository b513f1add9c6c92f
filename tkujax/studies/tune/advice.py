"""Which search method to use for a parameterisation's size: the dimension study's evidence.

`tune.method = "auto"` picks `recommended_method(n_params)`; with any other method,
`tkujax tune` names the recommendation in its log when it differs. The table is copied from
`results/tune_dimension` (the dimension study: one NVIDIA H100, 120 s of wall clock per run,
3 seeds side by side) up to 128 parameters, from `results/gradients_paper_mlpr8` and
`results/gradients_paper_mlpr16` (one NVIDIA H200, 210 s per run compile included) at 160 and
296, and from `results/gradients_paper` (140 s) at the policy size: the method with the
lowest mean held-out fall rate per size among those run so far, updated with those studies.
"""

from __future__ import annotations

import math

# (parameters, method): 16 scalars, 48 = sectors4, 80 = sectors8, 128 = mlp (sep-CMA-ES from
# 64 parameters), 160 = mlpr8, 296 = mlpr16 and 1,656 = mlpr96 (the line search: the
# gradient's direction, its step measured). 128 was measured from the recommended controller
# (where no gradient step helped), 160 and up from the paper's.
EVIDENCE = ((16, "cma"), (48, "cma"), (80, "sepcma"), (128, "sepcma"), (160, "linesearch"),
            (296, "linesearch"), (1656, "linesearch"))
EVIDENCE_NOTE = ("results/tune_dimension (one H100, all 48 runs and the line search at 128): "
                 "CMA-ES at 16 and 48 parameters, sep-CMA-ES at 80 and 128; the gradient, the "
                 "hybrid and the line search made no progress at any size. The comparison "
                 "at equal wall clock, compile included (results/gradients_soft, one H200, "
                 "selection by validation falls): sep-CMA-ES 20.2 % from 21.7 % at 80 "
                 "parameters; Adam's iterates rose to 23.5 %; at 1,272 no method improved "
                 "on the start in 140 s. From the paper's controller (results/gradients_paper, "
                 "one H200): sep-CMA-ES 32.7 % from 35.0 % at 80 parameters (the gradient methods "
                 "34.5-35.1 %); at 1,656 the line search 34.2 %, guided sep-CMA-ES 34.7 %, "
                 "Adam 34.9 %, sep-CMA-ES 35.0 % (the start). At 210 s per run from 35.0 %: "
                 "160 parameters (results/gradients_paper_mlpr8) the line search 28.9 %, "
                 "sep-CMA-ES 34.8 %; 296 (results/gradients_paper_mlpr16) 31.0 % against "
                 "33.6 %")


def recommended_method(n_params: int) -> str:
    """The method of the measured size nearest to n_params (on a log scale)."""
    if not isinstance(n_params, int) or isinstance(n_params, bool) or n_params < 1:
        raise ValueError(f"n_params must be a positive integer, got {n_params!r}")
    return min(EVIDENCE, key=lambda e: abs(math.log(e[0] / n_params)))[1]
