"""Actuator forces for joint, tendon and site transmissions: motors, general actuators and servos
(mj_fwdActuation)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import math, tree
from fastrl.physics.passive import gravcomp
from fastrl.physics.tendon import along
from fastrl.physics.types import Data, Model

_DSBL = mujoco.mjtDisableBit


def clamped_ctrl(m: Model, ctrl: jax.Array) -> jax.Array:
    """(nu,) the controls clamped to ``ctrlrange`` where limited (unless clampctrl is disabled)."""
    if m.actuator_ctrllimited.any() and not m.disableflags & _DSBL.mjDSBL_CLAMPCTRL:
        lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
        ctrl = jnp.where(m.actuator_ctrllimited.astype(bool), jnp.clip(ctrl, lo, hi), ctrl)
    return ctrl


def moment_actuators(m: Model) -> np.ndarray:
    """The actuators whose moment is a dense row: tendon and site transmissions (not joints)."""
    return np.flatnonzero(m.actuator_trntype != int(mujoco.mjtTrn.mjTRN_JOINT))


def moments(m: Model, d: Data) -> tuple[jax.Array, jax.Array]:
    """(n, nv) moments and (n,) lengths of the ``moment_actuators`` (mj_transmission).

    A tendon's moment is ``gear * ten_J``, its length ``gear * ten_length``. A site's (without a
    reference site) is its Jacobian projected on the gear wrench turned into the world frame,
    ``J_pos^T R gear[:3] + J_rot^T R gear[3:]``, and its length is 0. Expects ``tendon`` to have
    run where there are tendon actuators.
    """
    acts = moment_actuators(m)
    gear, ids = m.actuator_gear[acts], m.actuator_trnid[acts]
    tendons = m.actuator_trntype[acts] == int(mujoco.mjtTrn.mjTRN_TENDON)
    moment = jnp.zeros((acts.size, m.nv), d.qpos.dtype)
    length = jnp.zeros(acts.size, d.qpos.dtype)
    ten = np.flatnonzero(tendons)
    if ten.size:
        moment = moment.at[ten].set(gear[ten, :1] * d.ten_J[ids[ten]])
        length = length.at[ten].set(gear[ten, 0] * d.ten_length[ids[ten]])
    site = np.flatnonzero(~tendons)
    if site.size:
        sites = ids[site]
        rot = d.site_xmat[sites]
        force, torque = math.matvec(rot, gear[site, :3]), math.matvec(rot, gear[site, 3:])
        moved = jnp.asarray(tree.body_dof_ancestors(m)[m.site_bodyid[sites]], moment.dtype)
        turn = (torque @ d.cdof[:, :3].T) * moved
        moment = moment.at[site].set(along(m, d, d.site_xpos[sites], m.site_bodyid[sites], force) + turn)
    return moment, length


def transmission(m: Model, d: Data) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(nu,) actuator lengths and velocities (mj_transmission), and the ``moments`` of the
    ``moment_actuators``. A joint transmission's length and velocity are ``gear`` times the
    joint's position and velocity; the others' velocities are ``moment qvel``."""
    gear = m.actuator_gear[:, 0]
    jnt = m.actuator_trnid
    others = moment_actuators(m)
    if not others.size:
        empty = jnp.zeros((0, m.nv), d.qpos.dtype)
        return gear * d.qpos[m.jnt_qposadr[jnt]], gear * d.qvel[m.jnt_dofadr[jnt]], empty
    joint = tree.joint_actuators(m)
    moment, other_length = moments(m, d)
    zeros = jnp.zeros(m.nu, d.qpos.dtype)
    length = zeros.at[joint].set(gear[joint] * d.qpos[m.jnt_qposadr[jnt[joint]]])
    velocity = zeros.at[joint].set(gear[joint] * d.qvel[m.jnt_dofadr[jnt[joint]]])
    return length.at[others].set(other_length), velocity.at[others].set(moment @ d.qvel), moment


def actuation(m: Model, d: Data) -> Data:
    """``force = gain * ctrl + bias`` with affine gain/bias in length and velocity, clamped.

    Position servos are ``gain = kp, bias = -kp * length - kv * velocity``; velocity servos
    ``gain = kv, bias = -kv * velocity``; motors ``gain = 1, bias = 0`` (all as MuJoCo compiles them).
    """
    if m.nu == 0 or m.disableflags & _DSBL.mjDSBL_ACTUATION:
        zeros = jnp.zeros((m.nu,), d.qvel.dtype)
        return d.replace(
            actuator_length=zeros, actuator_velocity=zeros, actuator_force=zeros,
            qfrc_actuator=jnp.zeros_like(d.qvel),
        )  # fmt: skip
    ctrl = clamped_ctrl(m, d.ctrl)
    gear = m.actuator_gear[:, 0]
    length, velocity, moment = transmission(m, d)
    gp, bp = m.actuator_gainprm, m.actuator_biasprm
    affine_gain = jnp.asarray(m.actuator_gaintype == 1, ctrl.dtype)
    affine_bias = jnp.asarray(m.actuator_biastype == 1, ctrl.dtype)
    gain = gp[:, 0] + affine_gain * (gp[:, 1] * length + gp[:, 2] * velocity)
    bias = affine_bias * (bp[:, 0] + bp[:, 1] * length + bp[:, 2] * velocity)
    force = gain * ctrl + bias
    if m.actuator_forcelimited.any():
        lo, hi = m.actuator_forcerange[:, 0], m.actuator_forcerange[:, 1]
        force = jnp.where(m.actuator_forcelimited.astype(bool), jnp.clip(force, lo, hi), force)
    pattern = jnp.asarray(tree.actuator_moment_pattern(m), ctrl.dtype)
    qfrc = pattern @ (gear * force)
    others = moment_actuators(m)
    if others.size:
        qfrc = qfrc + moment.T @ force[others]
    if m.gravcomp_bodies.size and m.jnt_actgravcomp.any():
        # actuatorgravcomp: the joint's gravity compensation counts as actuator force (MuJoCo
        # adds it before the joint-level actfrcrange clamp; ``passive`` left it out)
        qfrc = qfrc + jnp.where(m.jnt_actgravcomp[m.dof_jntid].astype(bool), gravcomp(m, d), 0.0)
    if m.jnt_actfrclimited.any():
        lim = m.jnt_actfrclimited.astype(bool)
        dofs = m.jnt_dofadr[lim]
        lo, hi = m.jnt_actfrcrange[lim, 0], m.jnt_actfrcrange[lim, 1]
        qfrc = qfrc.at[dofs].set(jnp.clip(qfrc[dofs], lo, hi))
    return d.replace(
        actuator_length=length, actuator_velocity=velocity, actuator_force=force, qfrc_actuator=qfrc
    )
