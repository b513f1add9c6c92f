"""Studies built on the simulator: the paper's experiment, sweeps (+ their TOML specs),
stability maps, capturability theory, the standing check and gradient tuning.

  paper.py           `tkujax paper`: the paper's 8 cases, Tables 4-5, Figs. 13-16
  spec.py            sweep specs: TOML schema and validation
  sweep.py           `tkujax sweep`: chunked, resumable, sharded sweeps; load()
  chunk_program.py   the compiled MJX program of a sweep chunk, and its record inputs
  mujoco_chunk.py    a sweep chunk on MuJoCo C
  sweep_hash.py      the spec hash: when a rerun resumes a sweep
  record_schema.py   the manifest's versioned record schema (fields, values before them)
  replay.py          `tkujax replay`: one record re-simulated
  maps.py            `tkujax map`: stability maps and capture regions from a sweep
  map_cells.py       the maps' binned statistics: cells, fall boundaries, fall by phase
  compare.py         `tkujax compare`: fall-rate cells, verdict (compare_report.py: files)
  fpga.py            `tkujax fpga`: the fixed-point controller against the float one
  capturability.py   LIP capturability bounds the maps are checked against
  stand.py           `tkujax stand`: the robot standing, MJX or MuJoCo C
  tune/              `tkujax tune`: spec, reparam, loss, problem, methods, evaluate, report, run
  capture/           `tkujax capture`: one-step capture regions vs theory and the controller
"""
