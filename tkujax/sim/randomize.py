"""The one differentiable model randomisation: scales and shifts of an MJX model's fields as
traced values (jit, vmap and grad go through them). Each argument left None leaves its fields
as they are (a static choice at trace time), so a caller pays only for what it varies.

Used per push by sweeps and tuning ([randomize]: mass, torso CoM, friction, servo kp) and by the
calibration refinement (leg servo kp and damping, chest CoM) through masks of the legs.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from tkujax.sim.mjx_import import mjx


def randomize_model(model: mjx.Model, chest_body: int, *, mass_scale=None, torso_com_dx_m=None,
                    friction=None, kp_scale=None, damping_scale=None,
                    actuator_mask: np.ndarray | None = None,
                    dof_mask: np.ndarray | None = None) -> mjx.Model:
    """`model` with:

    mass_scale: every body's mass and inertia times this. torso_com_dx_m: the chest CoM moved
    along its x by this (m). friction: the sliding friction of every contact pair (<= 0: keep
    the model's). kp_scale: the position servos' stiffness (gain and bias) times this, for the
    actuators in actuator_mask (None: all). damping_scale: joint damping times this, for the
    dofs in dof_mask (None: all).
    Masks are static numpy booleans: multiplications by a masked scale, not scatters (whose
    gradient JAX lacks for repeated indices).
    """
    fields = {}
    if mass_scale is not None:
        fields.update(body_mass=model.body_mass * mass_scale,
                      body_inertia=model.body_inertia * mass_scale)
    if torso_com_dx_m is not None:
        fields["body_ipos"] = model.body_ipos.at[chest_body, 0].set(
            model.body_ipos[chest_body, 0] + torso_com_dx_m)
    if kp_scale is not None:
        k = kp_scale if actuator_mask is None else jnp.where(actuator_mask, kp_scale, 1.0)
        fields.update(
            actuator_gainprm=model.actuator_gainprm.at[:, 0].set(model.actuator_gainprm[:, 0] * k),
            actuator_biasprm=model.actuator_biasprm.at[:, 1].set(model.actuator_biasprm[:, 1] * k))
    if damping_scale is not None:
        d = damping_scale if dof_mask is None else jnp.where(dof_mask, damping_scale, 1.0)
        fields["dof_damping"] = model.dof_damping * d
    if friction is not None:
        fields["pair_friction"] = jnp.where(friction > 0,
                                            model.pair_friction.at[:, :2].set(friction),
                                            model.pair_friction)
    return model.replace(**fields)
