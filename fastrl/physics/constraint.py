"""Constraint rows: equality constraints, dof friction loss, joint limits and contacts (pyramidal
or elliptic friction cone), with MuJoCo's soft model, in MuJoCo's row order (equality, friction
loss, limits, contacts).

A dof with ``frictionloss > 0`` owns one always-active row (``J = e_dof``, ``pos = 0``) whose
force the solver bounds to ``[-frictionloss, frictionloss]`` (``solver``: a Huber-like cost).

Every limited joint and every *contact slot* owns a fixed block of rows; a row whose distance is
beyond its margin is inactive (masked), so the row count is static. MuJoCo makes rows only for the
contacts within their margin (``mjData.ncon``, usually a handful), while collision here evaluates
every candidate of the static pair table (25 for the Ant). Rows for all candidates would make the
solver, which costs about rows x dofs^2 per Newton step, several times slower for rows that are
nearly always inactive, so the rows go to the ``Model.nconmax`` slots holding the deepest
candidates (smallest ``dist - margin``): exactly MuJoCo's rows whenever no more than ``nconmax``
contacts are within their margin (``Data.ncon`` counts them, see ``default_nconmax`` for the
rule and the measurements behind it). Each row carries MuJoCo's
soft-constraint quantities: the Jacobian ``J``, the violation ``pos``, the regulariser
``R`` (stored as ``D = 1/R``) and the reference acceleration ``aref`` (solref/solimp, see
``impedance``). ``solver.solve`` turns them into forces.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import equality, tree
from fastrl.physics.collision_driver import budgeted, candidate_pairs, contact_layout
from fastrl.physics.jacobian import point_jacobian_masked, rotation_jacobian
from fastrl.physics.math import matmul, matvec
from fastrl.physics.types import Data, JointType, Model

_DSBL = mujoco.mjtDisableBit
MIN_IMP, MAX_IMP = 1e-4, 0.9999  # MuJoCo's mjMINIMP, mjMAXIMP
# frictionless; a pyramid over two tangents (3), plus torsion (4), plus rolling (6); rows in
# this order
CONTACT_CONDIMS = (1, 3, 4, 6)
MIN_NCONMAX = 8
MAX_DEFAULT_NCONMAX = 64


def default_nconmax(ncand: int) -> int:
    """Contact slots for a model with ``ncand`` candidate contacts: a quarter of them, at least 8
    and at most 64.

    Measured with MuJoCo C (``mjData.ncon``, contacts within their margin) over 200k random-action
    steps of each Gymnasium model, episodes never cut short (so bodies also lie fallen): the
    largest counts were Ant 5 (25 candidates, so 8 slots), Hopper 5 (11, 8), Walker2d 8 (14, 8),
    HalfCheetah 6 (16, 8), Pusher 8 (13, 8), Humanoid 11 and HumanoidStandup 31 (138, 35). The
    Ant's median is 1 and 99.99% of its states have at most 4. ``<size nconmax>`` in the MJCF or
    ``load_mjcf(nconmax=...)`` overrides the rule: the Humanoid asset sets 12 (the rule's 35 gave
    168 rows where 77 hold every contact it makes; the step runs 1.9x faster).

    The cap: the Menagerie's full-collision scenes have hundreds to thousands of candidates (a
    Leap hand 12,244, so 3,061 slots by the quarter rule) but few contacts at once. Over 3 x 1,500
    MuJoCo C steps of random controls from each scene's keyframe the most were Franka Panda 60,
    the Unitree G1 with hands 49, G1 46, the Leap hands 40, every other scene 28 or fewer (the Spot
    with its arm, whose runs blow up, aside). Every slot costs constraint rows in every solver
    iteration, and a contact without a slot is counted (``Data.contact_overflow``), never dropped
    silently.
    """
    return max(MIN_NCONMAX, min(MAX_DEFAULT_NCONMAX, -(-ncand // 4)))


def friction_dofs(m: Model) -> np.ndarray:
    """(nfric,) the dof of every friction-loss row, in row order (they come first)."""
    return np.asarray(m.friction_dofs, np.int64)


def friction_tendons(m: Model) -> np.ndarray:
    """(nfric_ten,) the tendon of every tendon friction-loss row (after the dofs' rows)."""
    return np.asarray(m.friction_tendons, np.int64)


def limited_tendons(m: Model) -> np.ndarray:
    """(nlim_ten,) the tendon of every tendon-limit row (after the joints' limit rows)."""
    return np.flatnonzero(np.asarray(m.tendon_limited).astype(bool))


def nfriction(m: Model) -> int:
    """Friction-loss rows: dofs', then tendons'."""
    return friction_dofs(m).size + friction_tendons(m).size


def limited_joints(m: Model) -> np.ndarray:
    """Indices of hinge/slide joints with active limits."""
    scalar = (m.jnt_type == JointType.HINGE) | (m.jnt_type == JointType.SLIDE)
    return np.flatnonzero(m.jnt_limited.astype(bool) & scalar)


def limit_dofs(m: Model) -> np.ndarray:
    """(nlim,) the dof of every joint-limit row, in row order (they come first).

    One row per limited joint, for the nearer end of its range: MuJoCo's two ends can only be
    within the margin at once when the range is narrower than twice the margin, which
    ``io.load_mjcf`` refuses.
    """
    return m.jnt_dofadr[limited_joints(m)]


def contact_groups(m: Model) -> list[tuple[int, np.ndarray, int]]:
    """``(condim, candidates, nslot)`` for each condim present, in ``CONTACT_CONDIMS`` order.

    ``candidates`` are indices into the candidate contacts (``collision``'s output); the group's
    ``nslot = min(len(candidates), m.nconmax)`` slots hold its deepest candidates.
    """
    condim = m.pair_condim[contact_layout(m)]
    groups = []
    for dim in CONTACT_CONDIMS:
        sel = np.flatnonzero(condim == dim)
        if sel.size:
            groups.append((dim, sel, min(sel.size, m.nconmax)))
    return groups


def contact_budgeted(m: Model) -> bool:
    """Whether a step can drop contacts (``Data.contact_overflow`` above 0): a collision group's
    budget (``collision_driver.budgeted``) or fewer contact slots than candidates."""
    return budgeted(m) or any(nslot < sel.size for _, sel, nslot in contact_groups(m))


def contact_slots(m: Model) -> int:
    """The number of contact slots (contacts that can have rows at once); static for a model."""
    return sum(n for _, _, n in contact_groups(m))


def elliptic(m: Model) -> bool:
    """Whether frictional contacts use the elliptic cone (``<option cone="elliptic">``)."""
    return m.cone == int(mujoco.mjtCone.mjCONE_ELLIPTIC)


def condim_rows(m: Model, dim: int) -> int:
    """Rows of one contact of condim ``dim``: 1 frictionless, ``dim`` for an elliptic cone (normal,
    then each friction direction), ``2 (dim - 1)`` pyramid edges."""
    return 1 if dim == 1 else dim if elliptic(m) else 2 * (dim - 1)


def rows_per_slot(m: Model) -> np.ndarray:
    """(nslot,) rows of each contact slot (``condim_rows``)."""
    rows = [np.full(n, condim_rows(m, dim), np.int64) for dim, _, n in contact_groups(m)]
    return np.concatenate(rows) if rows else np.zeros(0, np.int64)


def elliptic_blocks(m: Model) -> list[tuple[int, int, int, int]]:
    """``(condim, first row, first slot, nslot)`` of each elliptic-cone contact group.

    Their rows come last (``CONTACT_CONDIMS`` order puts the frictionless group first), each slot
    a block of ``condim`` rows; every other row is a scalar row with a one-sided or friction-loss
    cost.
    """
    if not elliptic(m):
        return []
    out = []
    row = first_contact_row(m)
    slot = 0
    for dim, _, n in contact_groups(m):
        if dim > 1:
            out.append((dim, row, slot, n))
        row += n * condim_rows(m, dim)
        slot += n
    return out


def contact_efc_address(m: Model) -> np.ndarray:
    """(nslot,) the first ``efc`` row of every contact slot (MuJoCo's ``efc_address``).

    ``make_constraint`` emits the limit rows, then the slots grouped by condim in
    ``CONTACT_CONDIMS`` order; ``Data.contact_id`` names the candidate each slot holds.
    """
    rows = rows_per_slot(m)
    return first_contact_row(m) + np.cumsum(rows) - rows


def first_contact_row(m: Model) -> int:
    """Rows before the contacts': equality, friction-loss and limit rows."""
    return equality.nrows(m) + nfriction(m) + limited_joints(m).size + limited_tendons(m).size


def sizes(m: Model) -> tuple[int, int]:
    """(ncon, nefc): candidate contacts and constraint rows; static for a model."""
    nrows = first_contact_row(m) + int(rows_per_slot(m).sum())
    return contact_layout(m).size, nrows


def select_contacts(m: Model, d: Data, candidates: np.ndarray, nslot: int) -> jax.Array:
    """(nslot,) the ``candidates`` with the smallest ``dist - margin``, deepest first.

    Branch-free and static-shaped: a top-k over the group. A group with no more candidates than
    slots keeps them all, in candidate order, with no selection traced.
    """
    if nslot == candidates.size:
        return jnp.asarray(candidates, jnp.int32)
    r = d.contact_dist[candidates] - m.pair_margin[candidate_pairs(m, d)[candidates]]
    _, pick = jax.lax.top_k(-r, nslot)
    return jnp.asarray(candidates, jnp.int32)[pick]


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


def _elliptic_rows(m: Model, d: Data, jac, pair, common, tran, out) -> None:
    """Appends the rows of elliptic-cone contacts (MuJoCo's mjCNSTR_CONTACT_ELLIPTIC) to ``out``.

    ``jac`` (nslot, dim, nv): the normal, then each friction direction. Only the normal row has a
    distance; the friction rows have ``pos = 0``, no stiffness, and damping from the pair's
    ``solreffriction`` (else its ``solref``). All rows share the normal's impedance. The
    regulariser is ``R_0 = (1 - imp) / imp * tran`` on the normal, ``R_1 = R_0 / impratio`` and
    ``R_j = R_1 mu_1^2 / mu_j^2`` on the friction rows (MuJoCo's mj_makeImpedance).
    """
    jacs, poss, arefs, dees = out
    dist, margin, solref, solimp = common
    n, dim = jac.shape[:2]
    r = dist - margin
    imp = impedance(solimp, r)
    k, b = stiffness_damping(m, solref, solimp)
    ref_f = m.pair_solreffriction[pair]
    ref_f = jnp.where(jnp.any(ref_f != 0, -1, keepdims=True), ref_f, solref)
    _, b_f = stiffness_damping(m, ref_f, solimp)
    vel = matvec(jac, d.qvel)  # (nslot, dim)
    aref = jnp.concatenate([(-b * vel[:, 0] - k * imp * r)[:, None], -b_f[:, None] * vel[:, 1:]], 1)
    r0 = jnp.maximum(1e-15, (1 - imp) / imp * tran)
    r1 = r0 / jnp.maximum(1e-15, m.impratio)
    fric = m.pair_friction[pair, : dim - 1]
    reg = jnp.concatenate([r0[:, None], r1[:, None] * fric[:, :1] ** 2 / fric**2], 1)
    jacs.append(jac.reshape(n * dim, -1))
    poss.append(jnp.concatenate([dist[:, None], jnp.zeros((n, dim - 1), dist.dtype)], 1).reshape(-1))
    arefs.append(aref.reshape(-1))
    dees.append(jnp.where((r < 0)[:, None], 1 / reg, 0.0).reshape(-1))


def _equality_rows(m: Model, d: Data, out) -> None:
    """Appends the equality constraints' rows (``equality.rows``): always within their margin
    (0) while active, each constraint's impedance from the norm of its violation, and the
    reference acceleration less the Jacobian's rate times qvel (MuJoCo's mj_Jdotv)."""
    jacs, poss, arefs, dees = out
    eq = equality.rows(m, d)
    imp = impedance(eq.solimp, eq.block_pos)
    k, b = stiffness_damping(m, eq.solref, eq.solimp)
    vel = matvec(eq.jac, d.qvel)
    jacs.append(eq.jac)
    poss.append(eq.pos)
    arefs.append(-b * vel - k * imp * eq.pos - eq.jdotv)
    dees.append(jnp.where(eq.active, 1 / jnp.maximum(1e-15, (1 - imp) / imp * eq.diag), 0.0))


class _RowList:
    """The constraint rows being assembled: Jacobians, violations, reference accelerations and
    weights, appended block by block in MuJoCo's row order."""

    def __init__(self, m: Model, d: Data):
        self.m, self.d = m, d
        self.parts = ([], [], [], [])  # jac, pos, aref, D

    def add(self, jac, pos, margin, solref, solimp, diag, repeat=1, always=False):
        """Rows of constraints that each own ``repeat`` rows sharing pos, margin and impedance;
        ``always``: active whatever the distance (friction loss), else while ``pos < margin``."""
        jacs, poss, arefs, dees = self.parts
        r = pos - margin
        imp = impedance(solimp, r)
        k, b = stiffness_damping(self.m, solref, solimp)
        regulariser = jnp.maximum(1e-15, (1 - imp) / imp * diag)
        rep = lambda x: jnp.repeat(x, repeat)  # noqa: E731
        vel = matvec(jac, self.d.qvel)
        jacs.append(jac)
        poss.append(rep(pos))
        arefs.append(-rep(b) * vel - rep(k * imp * r))
        active = True if always else rep(r < 0)
        dees.append(jnp.where(active, 1 / rep(regulariser), 0.0))


def _friction_rows(m: Model, d: Data, rows: _RowList) -> None:
    """One always-active row per dof, then per tendon, with friction loss."""
    dtype = d.qvel.dtype
    fric = friction_dofs(m)
    if fric.size:
        zero = jnp.zeros(fric.size, dtype)
        jac = jnp.eye(m.nv, dtype=dtype)[fric]
        rows.add(jac, zero, zero, m.dof_solref[fric], m.dof_solimp[fric], m.dof_invweight0[fric], always=True)
    ften = friction_tendons(m)
    if ften.size:
        zero = jnp.zeros(ften.size, dtype)
        rows.add(d.ten_J[ften], zero, zero, m.tendon_solref_fri[ften], m.tendon_solimp_fri[ften],
                 m.tendon_invweight0[ften], always=True)  # fmt: skip


def _limit_rows(m: Model, d: Data, rows: _RowList) -> None:
    """One row per limited joint, then per limited tendon, for the nearer end of its range."""
    dtype = d.qvel.dtype
    lim = limited_joints(m)
    if lim.size:
        # MuJoCo's row for the lower end is (J = +1, pos = q - lo), for the upper (-1, hi - q).
        dof = m.jnt_dofadr[lim]
        q = d.qpos[m.jnt_qposadr[lim]]
        lo, hi = m.jnt_range[lim, 0], m.jnt_range[lim, 1]
        lower = q - lo <= hi - q
        sign = jnp.where(lower, 1.0, -1.0).astype(dtype)
        jac = jnp.eye(m.nv, dtype=dtype)[dof] * sign[:, None]  # (nlim, nv)
        pos = jnp.where(lower, q - lo, hi - q)
        rows.add(jac, pos, m.jnt_margin[lim], m.jnt_solref[lim], m.jnt_solimp[lim], m.dof_invweight0[dof])
    lten = limited_tendons(m)
    if lten.size:  # as joint limits, with the tendon's length and Jacobian
        length = d.ten_length[lten]
        lo, hi = m.tendon_range[lten, 0], m.tendon_range[lten, 1]
        lower = length - lo <= hi - length
        sign = jnp.where(lower, 1.0, -1.0).astype(dtype)
        pos = jnp.where(lower, length - lo, hi - length)
        rows.add(d.ten_J[lten] * sign[:, None], pos, m.tendon_margin[lten], m.tendon_solref_lim[lten],
                 m.tendon_solimp_lim[lten], m.tendon_invweight0[lten])  # fmt: skip


def _contact_rows(m: Model, d: Data, rows: _RowList) -> list[jax.Array]:
    """The contact slots' rows, condim group by condim group; returns each group's candidates."""
    dtype = d.qvel.dtype
    pairs = candidate_pairs(m, d)
    ids = []
    body1 = jnp.asarray(m.geom_bodyid[m.pair_geom1], jnp.int32)  # per pair
    body2 = jnp.asarray(m.geom_bodyid[m.pair_geom2], jnp.int32)
    ancestors = tree.body_dof_ancestors(m)
    moving1 = ancestors[m.geom_bodyid[m.pair_geom1]].any()  # geom1 is often the static floor: no motion
    ancestors, rootid = jnp.asarray(ancestors, dtype), jnp.asarray(m.body_rootid, jnp.int32)
    for dim, sel, nslot in contact_groups(m):
        idx = select_contacts(m, d, sel, nslot)  # (nslot,) candidate of each slot
        ids.append(idx)
        pair = pairs[idx]
        b1, b2 = body1[pair], body2[pair]
        pos = d.contact_pos[idx]

        def slot_jacobian(bodies, pos=pos):  # the slots' bodies -> their point Jacobians
            return point_jacobian_masked(d, ancestors[bodies], d.subtree_com[rootid[bodies]], pos)

        jac_p = slot_jacobian(b2)
        if moving1:
            jac_p = jac_p - slot_jacobian(b1)
        frame = d.contact_frame[idx]
        jac_c = matmul(frame, jac_p)  # rows: normal, tangent1, tangent2
        common = (d.contact_dist[idx], m.pair_margin[pair], m.pair_solref[pair], m.pair_solimp[pair])
        tran = m.body_invweight0[b1, 0] + m.body_invweight0[b2, 0]
        if dim == 1:
            rows.add(jac_c[:, 0], *common, tran)
            continue
        # The friction directions: the two tangents (translation), then for condim 4 the
        # rotation about the normal (torsion), for 6 also about the tangents (rolling).
        dirs = [jac_c[:, 1], jac_c[:, 2]]
        if dim > 3:
            jac_r = rotation_jacobian(d, ancestors[b2])
            if moving1:
                jac_r = jac_r - rotation_jacobian(d, ancestors[b1])
            jac_rc = matmul(frame, jac_r)  # rows: about the normal, tangent1, tangent2
            dirs += [jac_rc[:, 0]] if dim == 4 else [jac_rc[:, 0], jac_rc[:, 1], jac_rc[:, 2]]
        jn = jac_c[:, 0]
        if elliptic(m):
            _elliptic_rows(m, d, jnp.stack([jn, *dirs], 1), pair, common, tran, rows.parts)
            continue
        mu = m.pair_friction[pair, : dim - 1]
        edges = []  # MuJoCo's pyramid edges: J_n +- mu_i J_i for each friction direction i
        for i, ji in enumerate(dirs):
            edges += [jn + mu[:, i : i + 1] * ji, jn - mu[:, i : i + 1] * ji]
        edges = jnp.stack(edges, 1)
        mu0 = mu[:, 0]
        diag = 2 * mu0**2 * (1 + mu0**2) * tran / m.impratio
        rows.add(edges.reshape(-1, m.nv), *common, diag, repeat=2 * (dim - 1))
    return ids


def make_constraint(m: Model, d: Data) -> Data:
    """Assembles every constraint row (equality, friction loss, limits, contacts: MuJoCo's order).

    Fills ``efc_*``, ``contact_id`` (the candidate in each contact slot) and ``ncon`` (candidates
    within their margin; the rows are MuJoCo's exactly while ``ncon <= nconmax``), and adds the
    contacts within their margin that found no slot to ``contact_overflow``.
    """
    rows = _RowList(m, d)
    if m.eq_type.size:
        _equality_rows(m, d, rows.parts)
    _friction_rows(m, d, rows)
    _limit_rows(m, d, rows)
    layout = contact_layout(m)
    ids = _contact_rows(m, d, rows) if layout.size else []
    jacs, poss, arefs, dees = rows.parts
    if not jacs:
        return d
    out = d.replace(
        efc_J=jnp.concatenate(jacs), efc_pos=jnp.concatenate(poss), efc_aref=jnp.concatenate(arefs),
        efc_D=jnp.concatenate(dees),
    )  # fmt: skip
    if ids:
        within = d.contact_dist < m.pair_margin[candidate_pairs(m, d)]
        unslotted = sum(jnp.maximum(jnp.sum(within[sel]) - nslot, 0) for _, sel, nslot in contact_groups(m))
        out = out.replace(
            contact_id=jnp.concatenate(ids),
            ncon=jnp.sum(within).astype(jnp.int32),
            contact_overflow=(d.contact_overflow + unslotted).astype(jnp.int32),
        )
    return out
