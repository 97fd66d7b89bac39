"""Velocity derivatives of the smooth forces, for the implicitfast integrator (mjd_smooth_vel).

``implicitfast`` integrates ``(M - h D) qacc = qfrc`` with ``D = d qfrc_smooth / d qvel`` less
the Coriolis and centrifugal term (MuJoCo's ``mjd_smooth_vel`` with ``flg_bias = 0``), except on
trees that are one free joint and nothing else: there MuJoCo 4.0 keeps the bias derivative and
solves the (unsymmetric) 6x6 block on its own, which keeps a spinning body's rotation stable.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import math, smooth, tendon, tree
from fastrl.physics.actuation import actuator_input, moment_actuators, moments
from fastrl.physics.passive import fluid
from fastrl.physics.types import Data, JointType, Model

_DSBL = mujoco.mjtDisableBit


def _bias_vel(m: Model, d: Data) -> jax.Array:
    """(nu,) ``d actuator_force / d actuator_velocity``: ``biasprm[2] + gainprm[2] ctrl`` for
    affine bias and gain (``act`` in place of ctrl where the actuator has activation dynamics:
    ``actuation.actuator_input``), zero where the force is at its ``forcerange`` (as MuJoCo 4.0)."""
    ctrl = actuator_input(m, d)
    affine_gain = jnp.asarray(m.actuator_gaintype == 1, ctrl.dtype)
    affine_bias = jnp.asarray(m.actuator_biastype == 1, ctrl.dtype)
    bias_vel = affine_bias * m.actuator_biasprm[:, 2] + affine_gain * m.actuator_gainprm[:, 2] * ctrl
    if m.actuator_forcelimited.any():
        lo, hi = m.actuator_forcerange[:, 0], m.actuator_forcerange[:, 1]
        force = d.actuator_force
        saturated = m.actuator_forcelimited.astype(bool) & ((force <= lo) | (force >= hi))
        bias_vel = jnp.where(saturated, 0.0, bias_vel)
    return bias_vel


def _actuator_vel(m: Model, d: Data) -> jax.Array:
    """(nv,) ``d qfrc_actuator / d qvel`` of joint transmissions, diagonal (mjd_actuator_vel).

    ``gear^2 * _bias_vel``. As in MuJoCo 4.0, an actuator whose joint's actuator force is at its
    ``actuatorfrcrange`` contributes nothing (its force does not move with the velocity there).
    """
    if m.nu == 0 or m.disableflags & _DSBL.mjDSBL_ACTUATION:
        return jnp.zeros_like(d.qvel)
    bias_vel = _bias_vel(m, d)
    pattern = jnp.asarray(tree.actuator_moment_pattern(m), bias_vel.dtype)
    per_dof = pattern @ (m.actuator_gear[:, 0] ** 2 * bias_vel)
    if m.jnt_actfrclimited.any():
        lim = m.jnt_actfrclimited.astype(bool)
        dofs = m.jnt_dofadr[lim]
        lo, hi = m.jnt_actfrcrange[lim, 0], m.jnt_actfrcrange[lim, 1]
        frc = d.qfrc_actuator[dofs]
        per_dof = per_dof.at[dofs].set(jnp.where((frc <= lo) | (frc >= hi), 0.0, per_dof[dofs]))
    return per_dof


def _coupled_vel(m: Model, d: Data) -> jax.Array:
    """(nv, nv) the share of ``smooth_vel`` of tendon dampers, ``-J^T b J``, and of actuators with
    a moment row (tendons, sites), ``moment^T bias_vel moment``, kept (as in MuJoCo's sparse
    ``qDeriv``) between dofs on one path to the root."""
    out = jnp.zeros((m.nv, m.nv), d.qvel.dtype)
    if m.ntendon and not m.disableflags & _DSBL.mjDSBL_DAMPER:
        out = out - (d.ten_J.T * m.tendon_damping) @ d.ten_J
    others = moment_actuators(m)
    if others.size and not m.disableflags & _DSBL.mjDSBL_ACTUATION:
        moment, _ = moments(m, d)
        out = out + (moment.T * _bias_vel(m, d)[others]) @ moment
    return out * jnp.asarray(tendon.tree_mask(m), out.dtype)


def smooth_vel(m: Model, d: Data) -> jax.Array:
    """(nv, nv) ``d (qfrc_passive + qfrc_actuator) / d qvel`` (mjd_smooth_vel, ``flg_bias = 0``).

    Joint damping and joint actuators' velocity gains on the diagonal, tendon damping and tendon
    and site actuators (``_coupled_vel``), and the inertia-box fluid forces.
    MuJoCo's fluid derivative (mjd_inertiaBoxFluid, ``J^T B J`` in each body's inertial frame) is
    the exact derivative of the fluid force, so forward-mode autodiff of ``fluid`` gives it to
    rounding. Every term is symmetric, so MuJoCo's use of the lower triangle changes nothing.

    Args:
      m: the model.
      d: the data after ``forward`` (uses qvel, ctrl, actuator_force, qfrc_actuator, cdof).
    Returns:
      (nv, nv) the derivative.
    """
    diag = _actuator_vel(m, d)
    if not m.disableflags & _DSBL.mjDSBL_DAMPER:
        diag = diag - m.dof_damping
    deriv = jnp.diag(diag)
    if m.ntendon or moment_actuators(m).size:
        deriv = deriv + _coupled_vel(m, d)
    # fluid forces act only where springs and dampers are not both disabled (io_checks.fluid_enabled)
    if m.body_fluid.any():
        force = lambda qvel: fluid(m, smooth.com_vel(m, d.replace(qvel=qvel)))  # noqa: E731
        deriv = deriv + jax.jacfwd(force)(d.qvel)
    return deriv


def free_trees(m: Model) -> np.ndarray:
    """(nfree,) the free joints whose kinematic tree has no other dofs (welded bodies allowed).

    MuJoCo 4.0 solves these trees' 6x6 blocks with the bias derivative (measured: a free box
    with a welded, massive child body steps as the rigid whole does; one with a hinged child
    steps with the global symmetric solve).
    """
    root_of_dof = m.body_rootid[m.dof_bodyid]
    free = [
        j
        for j in np.flatnonzero(m.jnt_type == JointType.FREE)
        if np.sum(root_of_dof == m.body_rootid[m.jnt_bodyid[j]]) == 6
    ]
    return np.array(free, np.int64)


def _rigid_bias(mass, inertia, offset, rot, omega):
    """(6,) velocity part of a rigid free tree's ``qfrc_bias`` at body angular velocity omega.

    The centre of mass sits at ``offset`` from the joint anchor; at zero ``qacc`` it accelerates at
    ``w x (w x offset)`` and the angular momentum turns at ``w x (I w)``. The translational dofs
    take the force in world axes, the rotational ones the torque about the anchor in body axes.
    """
    w = rot @ omega
    force = mass * math.cross(w, math.cross(w, offset))
    torque = math.cross(w, inertia @ w) + math.cross(offset, force)
    return jnp.concatenate([force, rot.T @ torque])


def free_tree_acc(m: Model, d: Data, deriv: jax.Array, qfrc: jax.Array, qacc: jax.Array) -> jax.Array:
    """``qacc`` with each ``free_trees`` block replaced by ``(M - h D + h B)^-1 qfrc`` (mjd_freeMhat).

    ``B = d qfrc_bias / d qvel`` of the tree as one rigid body (zero in the translational columns).
    The block is decoupled from every other dof, so the rest of ``qacc`` is unchanged.

    Args:
      m: the model.
      d: the data after ``forward``.
      deriv: (nv, nv) ``smooth_vel(m, d)``.
      qfrc: (nv,) ``qfrc_smooth + qfrc_constraint``.
      qacc: (nv,) the acceleration of the global solve.
    Returns:
      (nv,) the acceleration the velocity update uses.
    """
    joints = free_trees(m)
    if not joints.size:
        return qacc
    idx = m.jnt_dofadr[joints][:, None] + np.arange(6)  # (n, 6)
    bodies = m.jnt_bodyid[joints]
    roots = m.body_rootid[bodies]
    in_tree = jnp.asarray(m.body_rootid[None, :] == roots[:, None], d.cinert.dtype)  # (n, nbody)
    composite = in_tree @ d.cinert  # about each tree's centre of mass, world axes
    inertia = composite[:, np.array([[0, 3, 4], [3, 1, 5], [4, 5, 2]])]
    offset = d.subtree_com[roots] - d.xanchor[joints]
    rot = d.xmat[bodies]
    omega = d.qvel[idx[:, 3:]]
    jac = jax.vmap(jax.jacfwd(_rigid_bias, argnums=4))(composite[:, 9], inertia, offset, rot, omega)
    bias = jnp.zeros(idx.shape + (6,), qacc.dtype).at[:, :, 3:].set(jac)
    block = idx[:, :, None], idx[:, None, :]
    a = d.qM[block] - m.timestep * (deriv[block] - bias)
    return qacc.at[idx].set(jnp.linalg.solve(a, qfrc[idx][..., None])[..., 0])
