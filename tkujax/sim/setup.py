"""One init for every simulation (Brax-style): `init(model_params)` -> SimSetup, the host
(MuJoCo C) model, the device (MJX) model, the static model index and the settled stand state.

Cached per (model_params, settle_s, float64): the rollouts, sweeps, tuning, the capture-step
optimiser, the calibration refinement and the paper's GIF build the same objects once.
A `tkujax.sim.robot.Robot` carries its SimSetup with the rest of what a simulation takes.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tkujax.model import FSR_SENSORS, LEG_ACTUATORS, ModelParams
from tkujax.sim import physics
from tkujax.sim.mjx_import import mjx

SETTLE_S = 1.0   # the stand is held this long before t = 0 (see physics.settled_stand_data)


@dataclasses.dataclass(frozen=True)
class ModelIndex:
    """Static indices into the compiled model (plain numpy, never traced)."""

    leg_actuators: np.ndarray
    chest_body: int
    chest_stand_z: float          # chest body origin height in the stand keyframe, m
    chest_stand_cos: float        # cos of its tilt there (the chest axis leans by the stand lean)
    gyro_adr: int
    accel_adr: int
    fsr_adr: np.ndarray
    fsr_sites: np.ndarray
    sphere_geoms: np.ndarray      # non-foot collision spheres (knees, hands, head, pelvis)
    sphere_radii: np.ndarray
    box_geoms: np.ndarray         # non-foot collision boxes (chest)
    box_half_sizes: np.ndarray    # (nb, 3)
    ankle_sites: tuple[int, int]  # r_ankle, l_ankle
    stand_ctrl: np.ndarray
    timestep_s: float
    # Per-physics-step gains of the IMU's first-order low-pass (ModelParams.accel_lowpass_hz,
    # gyro_lowpass_hz); 0 = no filter, the rollouts read the instantaneous sensor value.
    accel_alpha: float = 0.0
    gyro_alpha: float = 0.0
    # The IMU's sites, their bodies and the accelerometer body's tree root (the rollout computes
    # the two IMU sensors itself every physics step: tkujax.sim.physics.imu_reading).
    gyro_site: int = -1
    gyro_body: int = -1
    accel_site: int = -1
    accel_body: int = -1
    accel_root: int = -1
    accel_parent: int = -1          # the accelerometer body's parent (0: a root body)
    accel_dofs: tuple[int, int] = (0, 0)   # its (first dof, number of dofs)
    # A robot file's leg map (tkujax.robot): the actuator target of controller slot k is
    # leg_signs[k] * q_k + leg_offsets[k] (q in TKU-X's joint conventions); None: TKU-X's
    # own model, the controller's targets as they are.
    leg_signs: np.ndarray | None = None
    leg_offsets: np.ndarray | None = None
    # A robot whose leg chain is not TKU-X's (tkujax.robot.leg_map): the targets are
    # leg_matrix (n_act, 12) @ q + leg_offsets; leg_signs is then None.
    leg_matrix: np.ndarray | None = None
    # ... and the robot's IK of the foot pose the controller asks for, started from that
    # linear map (tkujax.sim.leg_chain.LegChain); when set, the targets are its solution.
    leg_chain: object = None
    # Non-foot collision meshes for the fall test: geom ids and each one's vertices in its
    # geom frame (the lowest vertex is the geom's lowest point).
    mesh_geoms: tuple[int, ...] = ()
    mesh_points: tuple[np.ndarray, ...] = ()
    # Non-foot collision capsules and cylinders for the fall test: geom ids and each one's
    # (radius, half length), its axis the geom frame's z (`tkujax.sim.recording.axial_lows`).
    capsule_geoms: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))
    capsule_sizes: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    cylinder_geoms: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))
    cylinder_sizes: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def imu_filtered(self) -> bool:
        """Whether the IMU has a low-pass (either gain > 0)."""
        return self.accel_alpha > 0.0 or self.gyro_alpha > 0.0

    @property
    def imu_gains(self) -> tuple[float, float]:
        """(gyro, accel) gains of y += gain (x - y) per physics step; 1 where a filter is off
        (y = x, the instantaneous value), so both rollouts run one update for both."""
        return (self.gyro_alpha or 1.0, self.accel_alpha or 1.0)

    @staticmethod
    def of(model: mujoco.MjModel) -> ModelIndex:
        data = physics.stand_data(model)
        chest = model.body("chest").id
        foot_names = set(FSR_SENSORS)
        pair_geoms = [int(g) for g in model.pair_geom2 if model.geom(int(g)).name not in foot_names]
        sensor_adr = lambda n: int(model.sensor_adr[model.sensor(n).id])  # noqa: E731
        return ModelIndex(
            leg_actuators=np.array([model.actuator(n).id for n in LEG_ACTUATORS]),
            chest_body=chest, chest_stand_z=float(data.xpos[chest][2]),
            chest_stand_cos=float(data.xmat[chest][8]),
            gyro_adr=sensor_adr("gyro"), accel_adr=sensor_adr("accel"),
            fsr_adr=np.array([sensor_adr(n) for n in FSR_SENSORS]),
            fsr_sites=np.array([model.site(n).id for n in FSR_SENSORS]),
            **fall_geom_fields(model, pair_geoms),
            ankle_sites=(model.site("r_ankle").id, model.site("l_ankle").id),
            stand_ctrl=np.array(model.key("stand").ctrl), timestep_s=float(model.opt.timestep),
            **imu_indices(model))


def fall_geom_fields(model: mujoco.MjModel, geoms) -> dict:
    """ModelIndex's fall-test fields (sphere_geoms ... cylinder_sizes) of the collision geoms
    `geoms`, by their type: spheres, boxes, capsules and cylinders (meshes and other types are
    not among them: a robot file's meshes are `mesh_geoms`)."""
    def of(kind) -> list[int]:
        return [int(g) for g in geoms if model.geom_type[g] == kind]

    spheres, boxes = of(mujoco.mjtGeom.mjGEOM_SPHERE), of(mujoco.mjtGeom.mjGEOM_BOX)
    capsules, cylinders = of(mujoco.mjtGeom.mjGEOM_CAPSULE), of(mujoco.mjtGeom.mjGEOM_CYLINDER)
    return dict(sphere_geoms=np.array(spheres, dtype=int), sphere_radii=model.geom_size[spheres, 0],
                box_geoms=np.array(boxes, dtype=int), box_half_sizes=model.geom_size[boxes],
                capsule_geoms=np.array(capsules, dtype=int),
                capsule_sizes=model.geom_size[capsules, :2].reshape(-1, 2),
                cylinder_geoms=np.array(cylinders, dtype=int),
                cylinder_sizes=model.geom_size[cylinders, :2].reshape(-1, 2))


def imu_indices(model: mujoco.MjModel, gyro: str = "gyro", accel: str = "accel") -> dict:
    """ModelIndex's IMU fields (gyro_site ... accel_dofs) for the gyro and accelerometer
    sensors named `gyro` and `accel`: what `tkujax.sim.physics.imu_reading` reads."""
    site_of = lambda n: int(model.sensor_objid[model.sensor(n).id])  # noqa: E731
    gyro_site, accel_site = site_of(gyro), site_of(accel)
    body = int(model.site_bodyid[accel_site])
    return dict(gyro_site=gyro_site, gyro_body=int(model.site_bodyid[gyro_site]),
                accel_site=accel_site, accel_body=body, accel_root=int(model.body_rootid[body]),
                accel_parent=int(model.body_parentid[body]),
                accel_dofs=(int(model.body_dofadr[body]), int(model.body_dofnum[body])))


@functools.lru_cache(maxsize=8)
def model_index(params: ModelParams | None = None) -> ModelIndex:
    """The ModelIndex of TKU-X built from `params` (a robot's own: `Robot.index`)."""
    return index_of(physics.host_model(params), params)


def index_of(host: mujoco.MjModel, params: ModelParams | None) -> ModelIndex:
    """The ModelIndex of a host model built from `params` (None: the default robot): the
    compiled model's indices plus what lives outside MuJoCo (the IMU's low-pass gains)."""
    p = params or ModelParams()
    return dataclasses.replace(ModelIndex.of(host), accel_alpha=p.imu_lowpass_alpha("accel"),
                               gyro_alpha=p.imu_lowpass_alpha("gyro"))


class SimSetup(NamedTuple):
    """What a simulation starts from (see `init`)."""

    host_model: mujoco.MjModel     # MuJoCo C (rendering, the C backend, static sizes)
    device_model: mjx.Model        # MJX, on this process's first local device
    index: ModelIndex              # static indices (never traced)
    stand_state: mjx.Data          # the stand keyframe, settled for settle_s, clock at 0


def init(model_params: ModelParams | None = None, settle_s: float = SETTLE_S,
         float64: bool = False) -> SimSetup:
    """The SimSetup of TKU-X built from `model_params` (None: the default robot), cached (a
    robot's: `tkujax.sim.robot.Robot.setup`).

    float64: the MJX model and state put in float64 (built under jax.enable_x64; callers run
    their programs under it too), for derivative checks; the state's integer fields take the
    types `mjx.step` returns under x64, so it can be a lax.scan carry."""
    # One cache key however the arguments are spelled (lru_cache keys f(a) and f(a, 1.0) apart).
    return _init(model_params, float(settle_s), bool(float64))


@functools.lru_cache(maxsize=16)
def _init(model_params: ModelParams | None, settle_s: float, float64: bool) -> SimSetup:
    host = physics.host_model(model_params)
    index = model_index(model_params)
    if not float64:
        return SimSetup(host, physics.device_model(model_params), index,
                        physics.stand_state(host, settle_s))
    with jax.enable_x64(True):
        model = mjx.put_model(host)
        state = physics.stand_state(host, settle_s)
        # mjx.step returns some integer fields (contact geom ids) as int64 under x64 while
        # put_data makes int32: match the step's output types.
        shapes = jax.eval_shape(mjx.step, model, state)
        state = jax.tree_util.tree_map(lambda x, s: jnp.asarray(x, s.dtype), state, shapes)
    return SimSetup(host, model, index, state)
