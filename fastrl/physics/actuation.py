"""Actuator forces for joint transmissions: motors, general actuators and servos (mj_fwdActuation)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco

from fastrl.physics import tree
from fastrl.physics.passive import gravcomp
from fastrl.physics.types import Data, Model

_DSBL = mujoco.mjtDisableBit


def clamped_ctrl(m: Model, ctrl: jax.Array) -> jax.Array:
    """(nu,) the controls clamped to ``ctrlrange`` where limited (unless clampctrl is disabled)."""
    if m.actuator_ctrllimited.any() and not m.disableflags & _DSBL.mjDSBL_CLAMPCTRL:
        lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
        ctrl = jnp.where(m.actuator_ctrllimited.astype(bool), jnp.clip(ctrl, lo, hi), ctrl)
    return ctrl


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
    jnt = m.actuator_trnid
    length = gear * d.qpos[m.jnt_qposadr[jnt]]
    velocity = gear * d.qvel[m.jnt_dofadr[jnt]]
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
