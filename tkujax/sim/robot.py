"""The Robot: one value for everything a simulation of one robot starts from.

A Robot holds the compiled MuJoCo model (host and MJX device copies), its static index (leg
actuators, IMU and touch sensors, fall-test geometry, and for a robot file the leg map with its
IK chain), the stand settled `SETTLE_S` (as MJX state and as MuJoCo C data), the controller's
parameters for it and their scaled defaults, and its name, digest and source.

Two constructors, one value:

  builtin_robot(model_params)           TKU-X, its MJCF generated from `ModelParams` (None: the
                                        default robot); cached per parameter set
  tkujax.robot.robot_from_file(path)    a robot file (docs/robots.md); cached per file content

Every simulation entry point takes a Robot; what it is given (a Robot, a `ModelParams` or None
at the public edges, `model_params=`) is resolved once, by `as_robot`. Robots are compared and
hashed by identity (the caches key compiled programs on them).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json

import mujoco

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim import physics
from tkujax.sim.mjx_import import mjx
from tkujax.sim.setup import SETTLE_S, ModelIndex, SimSetup, init

BUILTIN_NAME = "TKU-X"
BUILTIN_SOURCE = "tkujax.model"   # the built-in robot's source: the MJCF generator


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Robot:
    """One robot as every simulation takes it (see the module doc).

    setup: the SimSetup (host model, device model, index, settled MJX stand state).
    settled: the same settled stand as MuJoCo C data (the C rollout's start).
    params: the controller's parameters for this robot (TKU-X: the paper's, with this model's
      geometry; a robot file: the controller it names, else the conservative default).
    defaults: the controller's scaled defaults for its geometry (the tune's start).
    name, digest (sha256, hex: of the robot file and its model files, or of the ModelParams),
    source (the robot file's path; BUILTIN_SOURCE for TKU-X), controller (where `params`
    came from). model_params: TKU-X's generator parameters; None for a robot file.
    walk_params, walk_controller: the controller while walking and where it came from (None,
    "": `params`; `walking_params` gives the one in use).
    gait: (WalkCommand field, value) pairs overriding the gait's defaults
    (`WalkCommand.for_params`): a robot file's defaults from its stand
    (`tkujax.robot.walk_defaults`), then its [walk] table (later pairs win); () for TKU-X.
    schedule: the scheduled policy's Schedule (`tkujax.control.policy`) when the robot file's
    controller is a policy file, with `params` its scalars; None otherwise. Sweeps standing
    run it with `params`; walking and capture regions take `params` alone.
    """

    setup: SimSetup
    settled: mujoco.MjData
    params: ControllerParams
    name: str
    digest: str
    source: str
    controller: str = ""
    defaults: ControllerParams | None = None
    model_params: ModelParams | None = None
    walk_params: ControllerParams | None = None
    walk_controller: str = ""
    gait: tuple[tuple[str, float], ...] = ()
    schedule: object | None = None

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, source={self.source!r}, digest={self.digest[:12]!r})"

    @property
    def walking_params(self) -> ControllerParams:
        """The controller while walking: the robot file's `walk_controller`, else `params`."""
        return self.params if self.walk_params is None else self.walk_params

    @property
    def builtin(self) -> bool:
        """Whether this is TKU-X from its MJCF generator (not a robot file)."""
        return self.model_params is not None

    @property
    def host_model(self) -> mujoco.MjModel:
        return self.setup.host_model

    @property
    def device_model(self) -> mjx.Model:
        return self.setup.device_model

    @property
    def index(self) -> ModelIndex:
        return self.setup.index

    @property
    def stand_state(self) -> mjx.Data:
        return self.setup.stand_state

    @property
    def leg_chain(self):
        """The leg IK chain of a robot whose legs are not TKU-X's (None: the linear map)."""
        return self.setup.index.leg_chain

    def sim_setup(self, settle_s: float = SETTLE_S, float64: bool = False) -> SimSetup:
        """The SimSetup, or for TKU-X one settled `settle_s` or in float64
        (`tkujax.sim.setup.init`); a robot file's is float32, settled SETTLE_S."""
        if float(settle_s) == SETTLE_S and not float64:
            return self.setup
        if not self.builtin:
            raise ValueError(f"{self.name}: a robot file's setup is float32, settled "
                             f"{SETTLE_S} s")
        return init(self.model_params, settle_s, float64)

    def record(self) -> dict:
        """What a sweep's manifest records of the robot: TKU-X's ModelParams fields, or a
        robot file's name, path and sha256."""
        if self.builtin:
            return dataclasses.asdict(self.model_params)
        return dict(robot=self.name, robot_file=self.source, robot_sha256=self.digest)


def params_digest(model_params: ModelParams) -> str:
    """sha256 (hex) of a ModelParams' fields: the built-in robot's digest."""
    text = json.dumps(dataclasses.asdict(model_params), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def builtin_robot(model_params: ModelParams | None = None) -> Robot:
    """TKU-X built from `model_params` (None: the default robot), cached: one Robot per
    parameter set, None and ModelParams() alike."""
    p = model_params or ModelParams()
    return _builtin(None if p == ModelParams() else p)


@functools.lru_cache(maxsize=16)
def _builtin(model_params: ModelParams | None) -> Robot:
    setup = init(model_params)
    paper = ControllerParams.paper(model_params)
    return Robot(setup=setup, settled=physics.settled_stand_data(setup.host_model, SETTLE_S),
                 params=paper, name=BUILTIN_NAME,
                 digest=params_digest(model_params or ModelParams()), source=BUILTIN_SOURCE,
                 controller="the paper's (ControllerParams.paper)", defaults=paper,
                 model_params=model_params or ModelParams())


def as_robot(robot: Robot | ModelParams | None = None,
             model_params: ModelParams | Robot | None = None) -> Robot:
    """The Robot a simulation runs: `robot`, else `model_params` (the older keyword), as a
    Robot: a Robot as it is, a ModelParams or None as TKU-X (`builtin_robot`). The one place
    where what a caller gives is resolved to a Robot."""
    if robot is not None and model_params is not None:
        raise ValueError("give the robot once: robot= or model_params=, not both")
    given = robot if robot is not None else model_params
    if isinstance(given, Robot):
        return given
    if given is not None and not isinstance(given, ModelParams):
        raise TypeError(f"expected a Robot (tkujax.robot.robot_from_file loads a robot file) "
                        f"or ModelParams, got {given!r}")
    return builtin_robot(given)
