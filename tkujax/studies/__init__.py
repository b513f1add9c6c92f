"""Studies built on the simulator: the paper's experiment, sweeps (+ their TOML specs),
stability maps, capturability theory, the standing check and gradient tuning.

  paper.py           `tkujax paper`: the paper's 8 cases, Tables 4-5, Figs. 13-16
  spec.py            sweep specs: TOML schema and validation
  sweep.py           `tkujax sweep`: chunked, resumable, sharded sweeps; load()
  maps.py            `tkujax map`: stability maps and capture regions from a sweep
  capturability.py   LIP capturability bounds the maps are checked against
  stand.py           `tkujax stand`: the robot standing, MJX or MuJoCo C
  tune/              `tkujax tune`: spec, reparam, loss, problem, methods, evaluate, report, run
  capture/           `tkujax capture`: one-step capture regions vs theory and the controller
"""
