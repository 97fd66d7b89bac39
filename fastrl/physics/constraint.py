"""Constraint rows: contacts (pyramidal friction cone) and joint limits, with MuJoCo's soft model.

Every candidate contact and every limited joint owns a fixed block of rows; a row whose distance
is beyond its margin is inactive (masked), so the row count is static. Each row carries MuJoCo's
soft-constraint quantities: the Jacobian ``J``, the violation ``pos``, the regulariser
``R`` (stored as ``D = 1/R``) and the reference acceleration ``aref`` (solref/solimp, see
``impedance``). ``solver.solve`` turns them into forces.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import tree
from fastrl.physics.collision_driver import contact_layout
from fastrl.physics.math import cross, matmul, matvec
from fastrl.physics.types import Data, JointType, Model

_DSBL = mujoco.mjtDisableBit
MIN_IMP, MAX_IMP = 1e-4, 0.9999  # MuJoCo's mjMINIMP, mjMAXIMP
CONTACT_CONDIMS = (1, 3)  # frictionless, and a pyramid with two tangents; rows in this order


def limited_joints(m: Model) -> np.ndarray:
    """Indices of hinge/slide joints with active limits."""
    scalar = (m.jnt_type == JointType.HINGE) | (m.jnt_type == JointType.SLIDE)
    return np.flatnonzero(m.jnt_limited.astype(bool) & scalar)


def rows_per_contact(m: Model) -> np.ndarray:
    """(ncon,) rows of each candidate contact: 1 frictionless, 2 (condim - 1) for a pyramid."""
    condim = m.pair_condim[contact_layout(m)]
    return np.where(condim == 1, 1, 2 * (condim - 1))


def contact_efc_address(m: Model) -> np.ndarray:
    """(ncon,) the first ``efc`` row of every candidate contact (MuJoCo's ``efc_address``).

    ``make_constraint`` emits the limit rows, then the contacts grouped by condim in
    ``CONTACT_CONDIMS`` order, each group in contact order.
    """
    rows = rows_per_contact(m)
    condim = m.pair_condim[contact_layout(m)]
    adr = np.zeros(rows.size, np.int64)
    start = 2 * limited_joints(m).size
    for dim in CONTACT_CONDIMS:
        sel = np.flatnonzero(condim == dim)
        adr[sel] = start + np.cumsum(rows[sel]) - rows[sel]
        start += int(rows[sel].sum())
    return adr


def sizes(m: Model) -> tuple[int, int]:
    """(ncon, nefc): candidate contacts and constraint rows; static for a model."""
    ncon = contact_layout(m).size
    return ncon, int(rows_per_contact(m).sum()) + 2 * limited_joints(m).size


def point_jacobian(m: Model, d: Data, bodies: np.ndarray, points: jax.Array) -> jax.Array:
    """Translational Jacobians (n, 3, nv) of world points rigidly attached to ``bodies`` (n,).

    From the com-based motion dofs: a point p moves with ``lin_d + ang_d x (p - c)`` per unit
    velocity of every dof d that moves its body, c being its tree's centre of mass.
    """
    mask = jnp.asarray(tree.body_dof_ancestors(m)[bodies], points.dtype)  # (n, nv)
    offset = points - d.subtree_com[m.body_rootid[bodies]]  # (n, 3)
    ang, lin = d.cdof[:, :3], d.cdof[:, 3:]  # (nv, 3)
    jac = lin[None] + cross(ang[None], offset[:, None, :])  # (n, nv, 3)
    return jnp.swapaxes(jac * mask[:, :, None], 1, 2)


def impedance(solimp: jax.Array, r: jax.Array) -> jax.Array:
    """MuJoCo's impedance d(r) in (0, 1) from ``solimp = (dmin, dmax, width, midpoint, power)``.

    ``r`` is the violation ``pos - margin``; d rises from dmin at r = 0 to dmax at |r| >= width
    along two power-law pieces that meet at the midpoint.
    """
    dmin = jnp.clip(solimp[..., 0], MIN_IMP, MAX_IMP)
    dmax = jnp.clip(solimp[..., 1], MIN_IMP, MAX_IMP)
    width = jnp.maximum(solimp[..., 2], 0.0)
    mid = jnp.clip(solimp[..., 3], MIN_IMP, MAX_IMP)
    power = jnp.maximum(solimp[..., 4], 1.0)
    flat = (dmin == dmax) | (width <= 1e-15)
    x = jnp.clip(jnp.abs(r) / jnp.where(flat, 1.0, width), 0.0, 1.0)
    low = x**power / mid ** (power - 1)
    high = 1 - (1 - x) ** power / (1 - mid) ** (power - 1)
    y = jnp.where(power == 1, x, jnp.where(x <= mid, low, high))
    return jnp.where(flat, 0.5 * (dmin + dmax), dmin + y * (dmax - dmin))


def stiffness_damping(m: Model, solref: jax.Array, solimp: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(K, B) of the reference acceleration ``aref = -B v - K d r`` from solref (MuJoCo's rule).

    Standard ``solref = (timeconst, dampratio)`` (timeconst at least two timesteps unless refsafe
    is disabled) or direct ``(-stiffness, -damping)``; both scaled by ``dmax``.
    """
    dmax = jnp.clip(solimp[..., 1], MIN_IMP, MAX_IMP)
    timeconst, dampratio = solref[..., 0], solref[..., 1]
    if not m.disableflags & _DSBL.mjDSBL_REFSAFE:
        timeconst = jnp.where(timeconst > 0, jnp.maximum(timeconst, 2 * m.timestep), timeconst)
    standard = solref[..., 0] > 0
    k = jnp.where(
        standard,
        1 / jnp.maximum(1e-15, (dmax * timeconst * dampratio) ** 2),
        -solref[..., 0] / jnp.maximum(1e-15, dmax**2),
    )
    b_standard = 2 / jnp.maximum(1e-15, dmax * timeconst)
    b = jnp.where(standard, b_standard, -solref[..., 1] / jnp.maximum(1e-15, dmax))
    return k, b


def make_constraint(m: Model, d: Data) -> Data:
    """Assembles every constraint row (limits first, then contacts, as MuJoCo orders them)."""
    dtype = d.qvel.dtype
    jacs, poss, arefs, dees = [], [], [], []

    def add(jac, pos, margin, solref, solimp, diag, repeat=1):
        """Rows of constraints that each own ``repeat`` rows sharing pos, margin and impedance."""
        r = pos - margin
        imp = impedance(solimp, r)
        k, b = stiffness_damping(m, solref, solimp)
        regulariser = jnp.maximum(1e-15, (1 - imp) / imp * diag)
        rep = lambda x: jnp.repeat(x, repeat)  # noqa: E731
        vel = matvec(jac, d.qvel)
        jacs.append(jac)
        poss.append(rep(pos))
        arefs.append(-rep(b) * vel - rep(k * imp * r))
        active = rep(r < 0)
        dees.append(jnp.where(active, 1 / rep(regulariser), 0.0))

    lim = limited_joints(m)
    if lim.size:
        dof = m.jnt_dofadr[lim]
        q = d.qpos[m.jnt_qposadr[lim]]
        lo, hi = m.jnt_range[lim, 0], m.jnt_range[lim, 1]
        eye = jnp.eye(m.nv, dtype=dtype)[dof]  # (nlim, nv)
        jac = jnp.stack([eye, -eye], 1).reshape(-1, m.nv)
        pos = jnp.stack([q - lo, hi - q], 1).reshape(-1)
        two = lambda x: jnp.repeat(x, 2, axis=0)  # noqa: E731
        add(jac, pos, two(m.jnt_margin[lim]), two(m.jnt_solref[lim]), two(m.jnt_solimp[lim]),
            two(m.dof_invweight0[dof]))  # fmt: skip

    layout = contact_layout(m)
    if layout.size:
        g1, g2 = m.pair_geom1[layout], m.pair_geom2[layout]
        b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
        jac_p = point_jacobian(m, d, b2, d.contact_pos)
        if tree.body_dof_ancestors(m)[b1].any():  # geom1 is often the static floor: no motion
            jac_p = jac_p - point_jacobian(m, d, b1, d.contact_pos)
        jac_c = matmul(d.contact_frame, jac_p)  # rows: normal, tangent1, tangent2
        tran = m.body_invweight0[b1, 0] + m.body_invweight0[b2, 0]
        fric = m.pair_friction[layout]
        condim = m.pair_condim[layout]
        for dim in CONTACT_CONDIMS:
            sel = np.flatnonzero(condim == dim)
            if not sel.size:
                continue
            pair = layout[sel]
            common = (d.contact_dist[sel], m.pair_margin[pair], m.pair_solref[pair],
                      m.pair_solimp[pair])  # fmt: skip
            if dim == 1:
                add(jac_c[sel, 0], *common, tran[sel])
                continue
            mu = fric[sel, :2]
            jn = jac_c[sel, 0]
            t1, t2 = mu[:, :1] * jac_c[sel, 1], mu[:, 1:] * jac_c[sel, 2]
            edges = jnp.stack([jn + t1, jn - t1, jn + t2, jn - t2], 1)  # MuJoCo's pyramid edges
            mu0 = fric[sel, 0]
            diag = 2 * mu0**2 * (1 + mu0**2) * tran[sel] / m.impratio
            add(edges.reshape(-1, m.nv), *common, diag, repeat=4)
    if not jacs:
        return d
    return d.replace(
        efc_J=jnp.concatenate(jacs), efc_pos=jnp.concatenate(poss), efc_aref=jnp.concatenate(arefs),
        efc_D=jnp.concatenate(dees),
    )  # fmt: skip
