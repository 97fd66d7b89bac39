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


def dynamic_actuators(m: Model) -> np.ndarray:
    """The actuators with activation dynamics (``dyntype`` not none), each owning one ``act``."""
    return np.flatnonzero(m.actuator_dyntype != int(mujoco.mjtDyn.mjDYN_NONE))


def _time_constant(m: Model, dyn: np.ndarray) -> jax.Array:
    return jnp.maximum(mujoco.mjMINVAL, m.actuator_dynprm[dyn, 0])


def activation_rate(m: Model, d: Data, ctrl: jax.Array) -> jax.Array:
    """(na,) ``act_dot`` (mj_fwdActuation): ``ctrl`` for an integrator, ``(ctrl - act) / tau`` for
    a filter (exact or not), with ``ctrl`` clamped and ``tau = dynprm[0]``."""
    dyn = dynamic_actuators(m)
    adr = m.actuator_actadr[dyn]
    u = ctrl[dyn]
    integrator = m.actuator_dyntype[dyn] == int(mujoco.mjtDyn.mjDYN_INTEGRATOR)
    rate = jnp.where(integrator, u, (u - d.act[adr]) / _time_constant(m, dyn))
    return jnp.zeros_like(d.act).at[adr].set(rate)


def next_activation(m: Model, act: jax.Array, act_dot: jax.Array) -> jax.Array:
    """(na,) the activations one timestep on at rate ``act_dot`` (mj_nextActivation).

    Euler, ``act + h act_dot``, except for the exact filter, which integrates its linear ODE
    exactly: ``act + act_dot tau (1 - exp(-h / tau))``. Then clamped to ``actrange`` where
    ``actlimited``.
    """
    dyn = dynamic_actuators(m)
    adr = m.actuator_actadr[dyn]
    h = m.timestep
    step = h * act_dot[adr]
    exact = m.actuator_dyntype[dyn] == int(mujoco.mjtDyn.mjDYN_FILTEREXACT)
    if exact.any():
        tau = _time_constant(m, dyn)
        step = jnp.where(exact, act_dot[adr] * tau * -jnp.expm1(-h / tau), step)
    new = act[adr] + step
    limited = m.actuator_actlimited[dyn].astype(bool)
    if limited.any():
        lo, hi = m.actuator_actrange[dyn, 0], m.actuator_actrange[dyn, 1]
        new = jnp.where(limited, jnp.clip(new, lo, hi), new)
    return act.at[adr].set(new)


def actuator_input(m: Model, d: Data) -> jax.Array:
    """(nu,) what each actuator's gain multiplies: the clamped ``ctrl``, or for an actuator with
    activation dynamics its ``act`` (with ``actearly``, the next step's ``next_activation``).
    Expects ``d.act_dot`` to be this state's (``actuation`` sets it)."""
    ctrl = clamped_ctrl(m, d.ctrl)
    dyn = dynamic_actuators(m)
    if not dyn.size:
        return ctrl
    adr = m.actuator_actadr[dyn]
    act = d.act[adr]
    early = m.actuator_actearly[dyn].astype(bool)
    if early.any():
        act = jnp.where(early, next_activation(m, d.act, d.act_dot)[adr], act)
    return jnp.asarray(ctrl).at[dyn].set(act)  # ctrl may be a host array outside jit


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
    An actuator with activation dynamics multiplies its gain by its activation instead of ctrl
    (``actuator_input``), and sets the rate ``act_dot`` that the integrator advances it with.
    """
    if m.nu == 0 or m.disableflags & _DSBL.mjDSBL_ACTUATION:
        zeros = jnp.zeros((m.nu,), d.qvel.dtype)
        return d.replace(
            actuator_length=zeros, actuator_velocity=zeros, actuator_force=zeros,
            qfrc_actuator=jnp.zeros_like(d.qvel),
        )  # fmt: skip
    if m.na:
        d = d.replace(act_dot=activation_rate(m, d, clamped_ctrl(m, d.ctrl)))
    ctrl = actuator_input(m, d)
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
