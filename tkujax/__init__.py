"""tkujax: a JAX-vectorised, differentiable simulator for humanoid push-recovery sweeps.

Layers (imports go one way, left to right): model <- control <- sim <- robot <- studies <- cli.

The public API, in one place (submodules are imported lazily so that the CLI can set
MUJOCO_GL and XLA options first):

  tkujax.ModelParams, tkujax.load_model      the TKU-X model (tkujax.model)
  tkujax.ControllerParams                    the paper's controller (tkujax.control)
  tkujax.recommended_policy                  the recommended recovery policy (params, schedule)
  tkujax.make_push, tkujax.stack_pushes      pushes (tkujax.sim.push)
  tkujax.simulate                            a batch of closed-loop rollouts on MJX
  tkujax.RolloutConfig, tkujax.ProgramOptions  its physics and its program (remat, unrolling,
                                             loop, tree passes; tkujax.sim.options)
  tkujax.Episode                             one rollout's push, control switch, key, noise
  tkujax.simulate_mujoco                     the same on MuJoCo C (CPU)
  tkujax.run_paper                           the paper's experiment
  tkujax.run_sweep, tkujax.load              sweeps and their records
  tkujax.make_maps                           stability maps
  tkujax.compare_runs                        runs of one spec compared: difference maps, no harm
  tkujax.replay                              one sweep record re-simulated
  tkujax.init                                the set-up of a model (tkujax.sim.setup)
  tkujax.Robot, tkujax.builtin_robot,        the one value every simulation takes: TKU-X
  tkujax.robot_from_file                     from ModelParams, or a robot file (tkujax.robot)
  tkujax.run_tune                            controller tuning (CMA-ES, gradients, ...)
  tkujax.run_calibrate                       fit the model to the paper's Tables 4-5
  tkujax.run_capture, tkujax.StepOverride    capture regions, commanded recovery steps
  tkujax.WalkCommand, tkujax.simulate_walk   walking from the controller's CPG (docs/walking.md)
"""

from __future__ import annotations

import importlib

__version__ = "0.2.0"

_API = {
    "ModelParams": "tkujax.model", "load_model": "tkujax.model",
    "ControllerParams": "tkujax.control",
    "recommended_policy": "tkujax.control.params_files",
    "Push": "tkujax.sim.push", "make_push": "tkujax.sim.push", "stack_pushes": "tkujax.sim.push",
    "Series": "tkujax.sim.records", "Outcomes": "tkujax.sim.records",
    "simulate": "tkujax.sim.rollout_mjx", "RolloutConfig": "tkujax.sim.options",
    "ProgramOptions": "tkujax.sim.options", "Episode": "tkujax.sim.options",
    "simulate_mujoco": "tkujax.sim.rollout_mujoco",
    "init": "tkujax.sim.setup", "SimSetup": "tkujax.sim.setup",
    "Robot": "tkujax.sim.robot", "builtin_robot": "tkujax.sim.robot",
    "robot_from_file": "tkujax.robot.robot_setup",
    "run_paper": "tkujax.studies.paper",
    "run_sweep": "tkujax.sweeps.sweep", "load": "tkujax.sweeps.table_export",
    "make_maps": "tkujax.analysis.maps", "compare_runs": "tkujax.analysis.compare",
    "replay": "tkujax.sweeps.replay",
    "run_tune": "tkujax.studies.tune",
    "run_calibrate": "tkujax.studies.calibrate",
    "run_capture": "tkujax.studies.capture", "StepOverride": "tkujax.control",
    "WalkCommand": "tkujax.control.gait", "simulate_walk": "tkujax.walking.walk",
}
__all__ = [*_API, "__version__"]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'tkujax' has no attribute {name!r}")
