"""Passive forces: joint and tendon springs and dampers, the inertia-box fluid model and gravity
compensation (mj_passive)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import math, tree
from fastrl.physics.types import Data, JointType, Model

_DSBL = mujoco.mjtDisableBit


def passive(m: Model, d: Data) -> Data:
    """Joint and tendon springs and dampers, plus fluid forces where the model has a medium.

    Spring ``-k (q - q_spring)`` on hinge/slide joints, damping ``-b qdot`` on every dof, tendon
    springs and dampers along ``ten_J`` (``_tendon_forces``, traced only if there are tendons), and
    ``fluid`` on the bodies of ``m.body_fluid`` (traced only if there are any). Expects
    ``com_vel`` to have run.
    """
    spring = jnp.zeros_like(d.qvel)
    scalar = np.flatnonzero((m.jnt_type == JointType.HINGE) | (m.jnt_type == JointType.SLIDE))
    if scalar.size and not m.disableflags & _DSBL.mjDSBL_SPRING:
        adr = m.jnt_qposadr[scalar]
        stretch = d.qpos[adr] - m.qpos_spring[adr]
        spring = spring.at[m.jnt_dofadr[scalar]].set(-m.jnt_stiffness[scalar] * stretch)
    damper = jnp.zeros_like(d.qvel)
    if not m.disableflags & _DSBL.mjDSBL_DAMPER:
        damper = -m.dof_damping * d.qvel
    if m.ntendon:
        spring, damper = _tendon_forces(m, d, spring, damper)
    total = spring + damper
    if m.body_fluid.any():
        total = total + fluid(m, d)
    if m.gravcomp_bodies.size:
        # a joint with actuatorgravcomp takes its share through its actuators instead
        total = total + jnp.where(m.jnt_actgravcomp[m.dof_jntid].astype(bool), 0.0, gravcomp(m, d))
    return d.replace(qfrc_spring=spring, qfrc_damper=damper, qfrc_passive=total)


def _tendon_forces(m: Model, d: Data, spring: jax.Array, damper: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Adds the tendons' springs and dampers, ``J^T f``, to the joint ones (mj_springdamper).

    The spring pulls the length back into its dead band ``tendon_lengthspring = [lo, hi]``
    (``-k (L - hi)`` above it, ``-k (L - lo)`` below, none inside); the damper is ``-b v``.
    """
    if not m.disableflags & _DSBL.mjDSBL_SPRING:
        length, (lo, hi) = d.ten_length, m.tendon_lengthspring.T
        stretch = jnp.where(length > hi, length - hi, jnp.where(length < lo, length - lo, 0.0))
        spring = spring + d.ten_J.T @ (-m.tendon_stiffness * stretch)
    if not m.disableflags & _DSBL.mjDSBL_DAMPER:
        damper = damper + d.ten_J.T @ (-m.tendon_damping * d.ten_velocity)
    return spring, damper


def gravcomp(m: Model, d: Data) -> jax.Array:
    """(nv,) MuJoCo's gravity compensation (mj_gravcomp, ``mjData.qfrc_gravcomp``): on each body
    of ``gravcomp_bodies`` the force ``-gravcomp * mass * gravity`` at its centre of mass, in
    joint space. Zero when gravity is (disabled and so) zero. Expects ``com_pos`` to have run.
    Not stored in ``Data``: ``passive`` and ``actuation`` each take their share of it."""
    bodies = m.gravcomp_bodies
    force = -(m.body_gravcomp[bodies] * m.body_mass[bodies])[:, None] * m.gravity
    return _wrench_at_com(m, d, bodies, jnp.zeros_like(force), force)


def _wrench_at_com(m: Model, d: Data, bodies: np.ndarray, torque: jax.Array, force: jax.Array) -> jax.Array:
    """(nv,) generalized forces of world-frame wrenches ``(torque, force)`` (n, 3) applied at the
    centres of mass of ``bodies`` (mj_applyFT at xipos). As a spatial force about the tree's
    com, the frame of cdof: ``qfrc_i = cdof_i . (sum of the wrenches on the bodies dof i moves)``."""
    offset = d.xipos[bodies] - d.subtree_com[m.body_rootid[bodies]]
    wrench = jnp.concatenate([torque + math.cross(offset, force), force], -1)
    moved = jnp.asarray(tree.body_dof_ancestors(m)[bodies].T, wrench.dtype)  # (nv, n)
    return jnp.sum(d.cdof * (moved @ wrench), -1)


def _box_sizes(mass: jax.Array, inertia: jax.Array) -> jax.Array:
    """(n, 3) sides of the uniform box with each body's mass and principal moments of inertia.

    A box of mass M and sides (a, b, c) has ``I_a = M (b^2 + c^2) / 12``, so
    ``a^2 = 6 (I_b + I_c - I_a) / M``; MuJoCo clamps the numerator at mjMINVAL, which keeps the
    sides real for a flat or rod-like body (and the square root differentiable).
    """
    other = inertia[:, [1, 0, 0]] + inertia[:, [2, 2, 1]] - inertia
    return jnp.sqrt(jnp.maximum(other, mujoco.mjMINVAL) / mass[:, None] * 6.0)


def _local_velocity(m: Model, d: Data, bodies: np.ndarray) -> tuple[jax.Array, jax.Array]:
    """(n, 3) angular and (n, 3) linear velocity of each body's inertial frame relative to the
    wind, in that frame's axes (mj_objectVelocity with flg_local, minus the rotated wind)."""
    offset = d.xipos[bodies] - d.subtree_com[m.body_rootid[bodies]]
    ang, lin = d.cvel[bodies, :3], d.cvel[bodies, 3:]
    lin = lin - math.cross(offset, ang) - m.wind  # cvel's linear part is at the tree's com
    rot = d.ximat[bodies]  # columns: the inertial axes in world coordinates
    return jnp.sum(rot * ang[:, :, None], 1), jnp.sum(rot * lin[:, :, None], 1)


def fluid(m: Model, d: Data) -> jax.Array:
    """Generalized forces (nv,) of MuJoCo's inertia-box fluid model on the bodies of ``body_fluid``.

    Each body is replaced by the box with its mass and inertia (``_box_sizes``), moving at its
    inertial frame's velocity relative to the wind. In that frame, per axis: Stokes drag of the
    sphere whose diameter is the mean side, ``-3 pi D mu v`` and torque ``-pi D^3 mu w``, and
    quadratic drag ``-rho A |v| v / 2`` on the face area A across the axis, with torque
    ``-rho a (b^4 + c^4) |w| w / 64`` (MuJoCo computation docs, "Fluid forces", "Inertia model").
    The wrench acts at the body's centre of mass (mj_applyFT at xipos).

    Args:
      m: the model; ``density``, ``viscosity`` and ``wind`` describe the medium.
      d: the data after ``com_vel`` (uses xipos, ximat, subtree_com, cvel, cdof).
    Returns:
      (nv,) the fluid forces, to be added to ``qfrc_passive``.
    """
    bodies = np.flatnonzero(m.body_fluid)
    box = _box_sizes(m.body_mass[bodies], m.body_inertia[bodies])
    ang, lin = _local_velocity(m, d, bodies)
    # MuJoCo skips a non-positive density or viscosity rather than reversing the drag.
    rho, mu = jnp.maximum(m.density, 0.0), jnp.maximum(m.viscosity, 0.0)
    diam = jnp.mean(box, -1, keepdims=True)
    area = box[:, [1, 0, 0]] * box[:, [2, 2, 1]]
    box4 = box**4
    arm = box * (box4[:, [1, 0, 0]] + box4[:, [2, 2, 1]]) / 64.0
    torque = -jnp.pi * diam**3 * mu * ang - rho * arm * jnp.abs(ang) * ang
    force = -3.0 * jnp.pi * diam * mu * lin - 0.5 * rho * area * jnp.abs(lin) * lin
    rot = d.ximat[bodies]
    torque, force = jnp.sum(rot * torque[:, None, :], -1), jnp.sum(rot * force[:, None, :], -1)
    return _wrench_at_com(m, d, bodies, torque, force)
