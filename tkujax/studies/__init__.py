"""The studies built on the simulator and its sweeps.

  paper.py           `tkujax paper`: the paper's 8 cases, Tables 4-5, Figs. 13-16
  converge.py        `tkujax converge`: the fall outcomes' numerical convergence
  fpga.py            `tkujax fpga`: the fixed-point controller against the float one
  tune/              `tkujax tune`: spec, reparam, loss, problem, methods, evaluation, outputs
  robot_tune.py      `tkujax tune --robot`: pushes, structure and verdict from a robot file
                     or the built-in TKU-X (robot_pushes.py, robot_structure.py,
                     robot_tune_specs.py, robot_policy.py, robot_verdict.py)
  robot_inputs.py    the robot a sweep, capture or tune command runs on
  calibrate/         `tkujax calibrate`: the model's unknowns fitted to the paper's tables
  capture/           `tkujax capture`: one-step capture regions vs theory and the controller
  gradient_measure.py  the first measurement of tuning gradients
"""
