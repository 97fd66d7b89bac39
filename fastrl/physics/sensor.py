"""Contact forces read after the step, computed on demand (mj_contactForce, mj_rnePostConstraint).

MuJoCo fills ``cfrc_ext`` only when a sensor needs it; Gymnasium's MuJoCo environments call
``mj_rnePostConstraint`` after every ``mj_step`` to get it. Here these are plain functions of the
solved constraint that ``forward`` leaves in ``Data``, not a stage of ``step``: an environment
calls them on the data ``step`` returns, and training that never reads them does not pay for them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import constraint
from fastrl.physics.collision_driver import candidate_pairs, contact_layout
from fastrl.physics.math import cross
from fastrl.physics.types import Data, Model


def contact_force(m: Model, d: Data) -> jax.Array:
    """Every candidate contact's force in its own contact frame (mj_contactForce).

    The pyramid's edge forces ``f`` (rows ``n + mu_k t_k``, ``n - mu_k t_k``) decode as normal
    ``sum(f)`` and tangential ``mu_k (f_2k - f_2k+1)`` (mju_decodePyramid); an elliptic cone's
    rows are the components themselves; a frictionless
    contact's one row is its normal force. The force is exerted on geom2's body, along the frame's
    rows (normal from geom1 to geom2, then the tangents). Inactive contacts carry zero force.

    Candidates without a contact slot (``Data.contact_id``) have no rows and get zero force.

    Args:
      m: the model.
      d: data after ``forward`` (or ``step``).
    Returns:
      (ncon, 6) ``(normal, tangent1, tangent2, torsion, roll1, roll2)`` per candidate contact;
      the components beyond a contact's condim are zero.
    """
    layout = contact_layout(m)
    adr = constraint.contact_efc_address(m)
    slots = []
    start = 0
    for dim, _, nslot in constraint.contact_groups(m):
        a = adr[start : start + nslot]
        start += nslot
        if dim == 1:
            slots.append(jnp.pad(d.efc_force[a][:, None], ((0, 0), (0, 5))))
            continue
        if constraint.elliptic(m):  # the rows are the force's components
            slots.append(jnp.pad(d.efc_force[a[:, None] + np.arange(dim)], ((0, 0), (0, 6 - dim))))
            continue
        edges = d.efc_force[a[:, None] + np.arange(2 * (dim - 1))]  # (n, 2 (dim - 1))
        normal = jnp.sum(edges, -1, keepdims=True)
        pair = candidate_pairs(m, d)[d.contact_id[start - nslot : start]]
        tangent = (edges[:, 0::2] - edges[:, 1::2]) * m.pair_friction[pair, : dim - 1]
        slots.append(jnp.pad(jnp.concatenate([normal, tangent], -1), ((0, 0), (0, 6 - dim))))
    if not slots:
        return jnp.zeros((layout.size, 6), d.efc_force.dtype)
    force = jnp.concatenate(slots)  # (nslot, 6)
    # Back to candidates: a one-hot sum over slots (a handful), cheaper than a scatter on CPU.
    onehot = (d.contact_id[:, None] == jnp.arange(layout.size)).astype(force.dtype)
    return sum(onehot[k][:, None] * force[k][None, :] for k in range(force.shape[0]))


def cfrc_ext(m: Model, d: Data) -> jax.Array:
    """External spatial force on every body from its contacts (MuJoCo's ``mjData.cfrc_ext``).

    As mj_rnePostConstraint computes it: each contact's force, turned into world axes, pushes
    geom2's body and pulls geom1's (equal and opposite), applied at the contact point and expressed
    as a com-based spatial force, i.e. ``(torque, force)`` with the torque about the centre of mass
    of the body's whole tree, ``subtree_com[body_rootid[b]]``. The world body gets nothing (row 0
    is zero). fastrl has no ``xfrc_applied`` and no equality constraints, so contacts are the only
    external forces.

    It reads the contacts and ``efc_force`` the last ``forward`` left in ``d``: after ``step``, those
    of the state the step started from (Euler) or of RK4's last stage, exactly what
    ``mj_rnePostConstraint`` reads after ``mj_step`` (Gymnasium's ``cfrc_ext``).

    Args:
      m: the model.
      d: data after ``forward`` (or ``step``).
    Returns:
      (nbody, 6) world-oriented ``(torque, force)`` per body, torque about its tree's com.
    """
    out = jnp.zeros((m.nbody, 6), d.efc_force.dtype)
    layout = contact_layout(m)
    if not layout.size:
        return out
    local = contact_force(m, d)
    force = jnp.sum(d.contact_frame * local[:, :3, None], axis=-2)  # frame^T local: world axes
    torque = jnp.sum(d.contact_frame * local[:, 3:, None], axis=-2)  # torsion and rolling (condim 4/6)
    pairs = candidate_pairs(m, d)
    for sign, geoms in ((-1.0, m.pair_geom1), (1.0, m.pair_geom2)):
        if not m.geom_bodyid[geoms].any():  # this side is always the world (the floor): nothing to apply
            continue
        bodies = jnp.asarray(m.geom_bodyid[geoms], jnp.int32)[pairs]
        arm = d.contact_pos - d.subtree_com[jnp.asarray(m.body_rootid, jnp.int32)[bodies]]
        out = out.at[bodies].add(sign * jnp.concatenate([cross(arm, force) + torque, force], -1))
    return out.at[0].set(0.0)
