"""Jacobians of points and bodies, and their rates, from the com-based motion dofs (``cdof``).

A point p fixed to a body moves with ``lin_d + ang_d x (p - c)`` per unit velocity of every dof d
that moves the body (c: the centre of mass of its tree, where ``cdof`` is expressed); the body
turns with ``ang_d``. Used by contact rows (``constraint``) and equality rows (``equality``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import math, tree
from fastrl.physics.types import Data, JointType, Model


def dof_mask(m: Model, bodies: np.ndarray, dtype) -> jax.Array:
    """(n, nv) 1 where the dof moves the body."""
    return jnp.asarray(tree.body_dof_ancestors(m)[bodies], dtype)


def point_jacobian_masked(d: Data, mask: jax.Array, com: jax.Array, points: jax.Array) -> jax.Array:
    """(n, 3, nv) translational Jacobians given each point's dof mask (n, nv) and its tree's com."""
    ang, lin = d.cdof[:, :3], d.cdof[:, 3:]  # (nv, 3)
    jac = lin[None] + math.cross(ang[None], (points - com)[:, None, :])  # (n, nv, 3)
    return jnp.swapaxes(jac * mask[:, :, None], 1, 2)


def rotation_jacobian(d: Data, mask: jax.Array) -> jax.Array:
    """(n, 3, nv) rotational Jacobians of bodies given their dof masks (n, nv)."""
    return jnp.swapaxes(d.cdof[None, :, :3] * mask[:, :, None], 1, 2)


def point_and_rotation(
    m: Model, d: Data, bodies: np.ndarray, points: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """(n, 3, nv) translational and rotational Jacobians of world points fixed to ``bodies``."""
    mask = dof_mask(m, bodies, points.dtype)
    com = d.subtree_com[m.body_rootid[bodies]]
    return point_jacobian_masked(d, mask, com, points), rotation_jacobian(d, mask)


def point_jac_dot_v(m: Model, d: Data, bodies: np.ndarray, points: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(n, 3) ``Jdot qvel`` of the translational and rotational Jacobians (mj_jacDot).

    ``cdof_dot`` gives each dof axis' rate; a ball or free-rotation dof uses its own body's
    velocity (``cvel x cdof``). The point's term also carries the axis sweeping past the point
    as the point moves (``cdof x v_point``).
    """
    mask = dof_mask(m, bodies, points.dtype)
    quat = np.zeros(m.nv, bool)
    for j, t in enumerate(m.jnt_type):
        a = m.jnt_dofadr[j]
        if t == JointType.BALL:
            quat[a : a + 3] = True
        elif t == JointType.FREE:
            quat[a + 3 : a + 6] = True
    cdof_dot = d.cdof_dot
    if quat.any():
        own = math.cross_motion(d.cvel[m.dof_bodyid], d.cdof)
        cdof_dot = jnp.where(jnp.asarray(quat)[:, None], own, cdof_dot)
    offset = points - d.subtree_com[m.body_rootid[bodies]]  # (n, 3)
    vel = d.cvel[bodies]
    pvel = vel[:, 3:] + math.cross(vel[:, :3], offset)  # the point's velocity
    w = mask * d.qvel[None]  # (n, nv)
    rot = w @ cdof_dot[:, :3]
    lin = w @ cdof_dot[:, 3:] + math.cross(rot, offset) + math.cross(w @ d.cdof[:, :3], pvel)
    return lin, rot
