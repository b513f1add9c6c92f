"""The Robot value (tkujax.sim.robot): TKU-X from ModelParams (`builtin`) and a robot file
(`robot_from_file`) as one value, resolved once by `as_robot`; what a sweep records and hashes
of it; the C rollout's start is the settled stand of `tkujax.sim.physics`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.robot import Robot, as_robot, builtin_robot, robot_from_file
from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.robot_setup import file_digest
from tkujax.sim import physics
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sim.setup import SETTLE_S, init, model_index
from tkujax.dialects.sweep_spec import parse_spec
from tkujax.sweeps.sweep_folder import model_record
from tkujax.sweeps.sweep_hash import spec_hash

# TKU-X with lighter legs (the total mass follows).
LIGHT = dataclasses.replace(ModelParams(), leg_mass_kg=0.9,
                            total_mass_kg=ModelParams().total_mass_kg
                            - 2 * (ModelParams().leg_mass_kg - 0.9))


def test_builtin_is_one_value_per_parameter_set():
    tkux = builtin_robot()
    assert tkux is builtin_robot(None) is builtin_robot(ModelParams()) is as_robot(None)
    light = builtin_robot(LIGHT)
    assert light is builtin_robot(dataclasses.replace(LIGHT)) is not builtin_robot()
    assert light.builtin and light.model_params == LIGHT and light.name == "TKU-X"
    assert light.digest != builtin_robot().digest
    # The setup is the cached init() of the same parameters: the rollouts share its objects
    # (LIGHT, first built just above; the default robot's init may have left the lru cache
    # since another test file built its Robot, so it is compared by value).
    assert light.setup is init(LIGHT)
    assert builtin_robot().host_model.nq == init(None).host_model.nq
    assert builtin_robot().index.leg_actuators.tolist() == model_index(None).leg_actuators.tolist()
    assert light.index.leg_actuators.tolist() == model_index(LIGHT).leg_actuators.tolist()
    assert light.params == ControllerParams.paper(LIGHT) == light.defaults
    assert light.params.com_height != builtin_robot().params.com_height   # its own geometry


def test_builtin_settled_stand_is_physics_settled_stand():
    """The C rollout's start (Robot.settled) is the keyframe held SETTLE_S, as MJX's."""
    robot = builtin_robot(LIGHT)
    ref = physics.settled_stand_data(physics.host_model(LIGHT), SETTLE_S)
    np.testing.assert_array_equal(robot.settled.qpos, ref.qpos)
    np.testing.assert_array_equal(robot.settled.qvel, ref.qvel)
    np.testing.assert_allclose(np.asarray(robot.stand_state.qpos), ref.qpos, atol=1e-6)


def test_as_robot_resolves_once_and_refuses_what_is_no_robot(tmp_path):
    robot = builtin_robot(LIGHT)
    assert as_robot(robot) is robot and as_robot(model_params=robot) is robot
    assert as_robot(LIGHT) is robot and as_robot(model_params=LIGHT) is robot
    with pytest.raises(ValueError, match="robot= or model_params=, not both"):
        as_robot(robot, LIGHT)
    with pytest.raises(TypeError, match="expected a Robot .*robot_from_file.*got 'op3.toml'"):
        as_robot("op3.toml")


def test_a_robot_file_is_the_same_value(tmp_path):
    path = write_generated_robot(tmp_path, GENERATED_SECOND, name="second")
    robot = robot_from_file(path)
    assert isinstance(robot, Robot) and not robot.builtin and robot.model_params is None
    assert robot is robot_from_file(path) and as_robot(robot) is robot
    assert robot.record() == dict(robot="second", robot_file=str(path.resolve()),
                                  robot_sha256=file_digest(path))
    assert robot.sim_setup() is robot.setup
    with pytest.raises(ValueError, match="float32, settled"):
        robot.sim_setup(float64=True)
    assert robot.host_model.nu == robot.device_model.nu == len(robot.settled.ctrl)


def test_what_a_sweep_records_and_hashes_of_tkux_is_its_model_params():
    """Records and hashes of TKU-X sweeps stay those of its ModelParams (committed sweeps
    resume): a Robot and its ModelParams give the same manifest model and spec hash."""
    spec = parse_spec({"sweep": {"name": "t", "chunk_size": 2},
                       "push": {"grid": {"impulse_ns": [0.3], "azimuth_deg": [0.0]}}})
    params = ControllerParams.paper()
    assert model_record(builtin_robot(LIGHT)) == dataclasses.asdict(LIGHT)
    assert model_record(None) == dataclasses.asdict(ModelParams())
    assert spec_hash(spec, params, builtin_robot(LIGHT)) == spec_hash(spec, params, LIGHT)
    assert spec_hash(spec, params, builtin_robot()) == spec_hash(spec, params, ModelParams())
    assert spec_hash(spec, params, builtin_robot()) != spec_hash(spec, params, LIGHT)


def test_simulate_takes_the_robot_or_its_model_params_alike():
    pushes = stack_pushes([make_push(0.25, 0.0, onset_s=0.06), make_push(0.25, 180.0,
                                                                         onset_s=0.06)])
    config = RolloutConfig(duration_s=0.3)
    params = ControllerParams.paper(LIGHT)
    a = simulate_mujoco(pushes, 1.0, params, model_params=LIGHT, config=config, n_threads=1)[0]
    b = simulate_mujoco(pushes, 1.0, params, robot=builtin_robot(LIGHT), config=config,
                        n_threads=1)[0]
    for k in ("pitch", "com", "pitch_est"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    # ... and another model is another simulation.
    c = simulate_mujoco(pushes, 1.0, params, config=config, n_threads=1)[0]
    assert not np.array_equal(a.com, c.com)
