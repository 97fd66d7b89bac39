"""Equality constraints (connect, weld, joint, tendon): their rows, as MuJoCo's
mj_instantiateEquality.

Every equality owns a fixed block of rows (connect 3, weld 6, joint and tendon 1), in model order; one that
is switched off (``Data.eq_active``) keeps its rows with zero weight. Each kind is computed for all
of its constraints at once. ``rows`` gives what ``constraint.make_constraint`` turns into soft rows:
the Jacobian, the violation, the Jacobian's rate ``Jdot v`` (MuJoCo >= 3.12 removes it from the
reference acceleration of connect and weld rows) and the inverse-inertia estimate of each row.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import jacobian, math
from fastrl.physics.types import Data, Model

EQ = mujoco.mjtEq
ROWS = {int(EQ.mjEQ_CONNECT): 3, int(EQ.mjEQ_WELD): 6, int(EQ.mjEQ_JOINT): 1, int(EQ.mjEQ_TENDON): 1}


def row_counts(m: Model) -> np.ndarray:
    """(neq,) rows of each equality constraint."""
    return np.array([ROWS[int(t)] for t in m.eq_type], np.int64)


def nrows(m: Model) -> int:
    return int(row_counts(m).sum())


def couples_branches(m: Model, moving: np.ndarray) -> bool:
    """Whether a row may span two moving branches (then the Newton Hessian is factorised
    densely): a connect/weld with both bodies moving, a coupling of two joints, or any tendon
    coupling (a tendon spans branches)."""
    if not m.eq_type.size:
        return False
    joint = (m.eq_type == int(EQ.mjEQ_JOINT)) | (m.eq_type == int(EQ.mjEQ_TENDON))
    b1, b2 = _bodies(m, np.flatnonzero(~joint))
    tendon = m.eq_type == int(EQ.mjEQ_TENDON)
    return bool(np.any(moving[b1] & moving[b2]) or np.any(joint & (m.eq_obj2id >= 0)) or tendon.any())


class Rows(typing.NamedTuple):
    """The equality rows in model order (see the module docstring)."""

    jac: jax.Array  # (ne, nv)
    pos: jax.Array  # (ne,) the violation
    jdotv: jax.Array  # (ne,) d/dt(J) qvel
    diag: jax.Array  # (ne,) MuJoCo's diagApprox
    block_pos: jax.Array  # (ne,) the norm of each constraint's violation (its impedance input)
    active: jax.Array  # (ne,) bool
    solref: jax.Array  # (ne, 2)
    solimp: jax.Array  # (ne, 5)


def _sites(x, ids: np.ndarray, site: np.ndarray):
    """``x[ids]`` where ``site``, zeros elsewhere (and for a model without sites)."""
    if not x.shape[0]:
        return (
            np.zeros((ids.size, *x.shape[1:]), x.dtype)
            if isinstance(x, np.ndarray)
            else jnp.zeros((ids.size, *x.shape[1:]), x.dtype)
        )
    return x[np.where(site, ids, 0)]


def _is_site(m: Model, idx: np.ndarray) -> np.ndarray:
    return m.eq_objtype[idx] == int(mujoco.mjtObj.mjOBJ_SITE)


def _bodies(m: Model, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two bodies of equalities ``idx`` (a site's body under site semantics)."""
    site = _is_site(m, idx)
    b1 = np.where(site, _sites(m.site_bodyid, m.eq_obj1id[idx], site), m.eq_obj1id[idx])
    b2 = np.where(site, _sites(m.site_bodyid, m.eq_obj2id[idx], site), m.eq_obj2id[idx])
    return b1, b2


def _anchors(m: Model, d: Data, idx: np.ndarray, weld: bool) -> tuple[jax.Array, jax.Array]:
    """World anchor points of both sides (mj_equalityAnchors): a body's local anchor from
    ``eq_data`` (connect: side 1 at data[0:3], side 2 at data[3:6]; weld swapped), or the site."""
    data = m.eq_data[idx]
    o1, o2 = m.eq_obj1id[idx], m.eq_obj2id[idx]
    local1, local2 = (data[:, 3:6], data[:, 0:3]) if weld else (data[:, 0:3], data[:, 3:6])
    by_body1 = jnp.einsum("nij,nj->ni", d.xmat[o1], local1) + d.xpos[o1]
    by_body2 = jnp.einsum("nij,nj->ni", d.xmat[o2], local2) + d.xpos[o2]
    site = _is_site(m, idx)
    if not site.any():
        return by_body1, by_body2
    s1, s2 = _sites(d.site_xpos, o1, site), _sites(d.site_xpos, o2, site)
    site = jnp.asarray(site)[:, None]
    return jnp.where(site, s1, by_body1), jnp.where(site, s2, by_body2)


def _axis_quat(q: jax.Array, axis: jax.Array) -> jax.Array:
    """``q * (0, axis)`` (mju_mulQuatAxis)."""
    return math.quat_mul(q, jnp.concatenate([jnp.zeros_like(axis[..., :1]), axis], -1))


def _quat_axis(axis: jax.Array, q: jax.Array) -> jax.Array:
    """``(0, axis) * q``: twice the rate of ``q`` turning at world angular velocity ``axis``."""
    return math.quat_mul(jnp.concatenate([jnp.zeros_like(axis[..., :1]), axis], -1), q)


def _connect(m: Model, d: Data, idx: np.ndarray):
    b1, b2 = _bodies(m, idx)
    p1, p2 = _anchors(m, d, idx, weld=False)
    j1, _ = jacobian.point_and_rotation(m, d, b1, p1)
    j2, _ = jacobian.point_and_rotation(m, d, b2, p2)
    v1, _ = jacobian.point_jac_dot_v(m, d, b1, p1)
    v2, _ = jacobian.point_jac_dot_v(m, d, b2, p2)
    tran = m.body_invweight0[b1, 0] + m.body_invweight0[b2, 0]
    return j1 - j2, p1 - p2, v1 - v2, jnp.repeat(tran[:, None], 3, 1)


def _weld(m: Model, d: Data, idx: np.ndarray):
    """Weld rows: the anchors' offset, then ``torquescale`` times the axis part of
    ``neg(q1) q0 relpose`` (the relative rotation's error), with its Jacobian and rate."""
    b1, b2 = _bodies(m, idx)
    data = m.eq_data[idx]
    scale = data[:, 10:11]
    p1, p2 = _anchors(m, d, idx, weld=True)
    jp1, jr1 = jacobian.point_and_rotation(m, d, b1, p1)
    jp2, jr2 = jacobian.point_and_rotation(m, d, b2, p2)
    vp1, vr1 = jacobian.point_jac_dot_v(m, d, b1, p1)
    vp2, vr2 = jacobian.point_jac_dot_v(m, d, b2, p2)
    is_site = _is_site(m, idx)
    s1 = _sites(m.site_quat, m.eq_obj1id[idx], is_site)
    s2 = _sites(m.site_quat, m.eq_obj2id[idx], is_site)
    site = jnp.asarray(is_site)[:, None]
    q0 = jnp.where(site, math.quat_mul(d.xquat[b1], s1), d.xquat[b1])
    q1 = jnp.where(site, math.quat_mul(d.xquat[b2], s2), d.xquat[b2])
    q0r = jnp.where(site, q0, math.quat_mul(q0, data[:, 6:10]))
    neg1 = math.quat_conj(q1)
    err = math.quat_mul(neg1, q0r)[:, 1:] * scale
    jr = jnp.swapaxes(jr1 - jr2, 1, 2)  # (n, nv, 3): each dof's relative rotation axis
    jrot = 0.5 * math.quat_mul(_axis_quat(neg1[:, None], jr), q0r[:, None])[..., 1:]  # (n, nv, 3)
    jrot = jnp.swapaxes(jrot, 1, 2) * scale[..., None]
    # The rotation rows' rate: the product rule on 0.5 neg(q1) (w0 - w1) q0 relpose, with w the
    # bodies' world angular velocities (cvel) and quaternion rates 0.5 (0, w) q (as MuJoCo 4.0:
    # the exact rate, checked against central differences).
    w0, w1 = d.cvel[b1, :3], d.cvel[b2, :3]
    dw = w0 - w1
    qd0 = 0.5 * _quat_axis(w0, q0)
    qd0r = jnp.where(site, qd0, math.quat_mul(qd0, data[:, 6:10]))
    neg_qd1 = math.quat_conj(0.5 * _quat_axis(w1, q1))
    rate = (
        math.quat_mul(_axis_quat(neg_qd1, dw), q0r)
        + math.quat_mul(_axis_quat(neg1, vr1 - vr2), q0r)
        + math.quat_mul(_axis_quat(neg1, dw), qd0r)
    )
    jdotv_rot = 0.5 * rate[:, 1:] * scale
    inv = m.body_invweight0
    diag = jnp.concatenate(
        [
            jnp.repeat((inv[b1, 0] + inv[b2, 0])[:, None], 3, 1),
            jnp.repeat((inv[b1, 1] + inv[b2, 1])[:, None], 3, 1),
        ],
        1,
    )
    jac = jnp.concatenate([jp1 - jp2, jrot], 1)
    return jac, jnp.concatenate([p1 - p2, err], 1), jnp.concatenate([vp1 - vp2, jdotv_rot], 1), diag


def _joint(m: Model, d: Data, idx: np.ndarray):
    """Joint couplings ``q1 - q1_0 = data[0] + sum_k data[k] (q2 - q2_0)^k`` (k = 1..4); a
    constraint with no second joint fixes the first at ``q1_0 + data[0]``."""
    j1, j2 = m.eq_obj1id[idx], m.eq_obj2id[idx]
    two = j2 >= 0
    j2s = np.where(two, j2, 0)
    eye = jnp.eye(m.nv, dtype=d.qpos.dtype)
    value = lambda j: d.qpos[m.jnt_qposadr[j]] - m.qpos0[m.jnt_qposadr[j]]  # noqa: E731
    return _coupling(m, idx, value(j1), value(j2s), eye[m.jnt_dofadr[j1]], eye[m.jnt_dofadr[j2s]],
                     m.dof_invweight0[m.jnt_dofadr[j1]], m.dof_invweight0[m.jnt_dofadr[j2s]])  # fmt: skip


def _tendon(m: Model, d: Data, idx: np.ndarray):
    """Tendon couplings: as joint couplings, on lengths from ``tendon_length0``."""
    t1, t2 = m.eq_obj1id[idx], m.eq_obj2id[idx]
    t2s = np.where(t2 >= 0, t2, 0)
    value = lambda t: d.ten_length[t] - m.tendon_length0[t]  # noqa: E731
    return _coupling(m, idx, value(t1), value(t2s), d.ten_J[t1], d.ten_J[t2s],
                     m.tendon_invweight0[t1], m.tendon_invweight0[t2s])  # fmt: skip


def _coupling(m: Model, idx: np.ndarray, q1, q2, jac1, jac2, inv1, inv2):
    """Rows of ``q1 = data[0] + sum_k data[k] q2^k`` (k = 1..4), or ``q1 = data[0]`` where the
    constraint has no second object, given both values, Jacobians and inverse weights."""
    data = m.eq_data[idx]
    two = jnp.asarray(m.eq_obj2id[idx] >= 0)
    dif = jnp.where(two, q2, 0.0)
    poly = data[:, 1] * dif + data[:, 2] * dif**2 + data[:, 3] * dif**3 + data[:, 4] * dif**4
    deriv = data[:, 1] + 2 * data[:, 2] * dif + 3 * data[:, 3] * dif**2 + 4 * data[:, 4] * dif**3
    jac = jac1 - jnp.where(two[:, None], deriv[:, None] * jac2, 0.0)
    pos = q1 - data[:, 0] - jnp.where(two, poly, 0.0)
    diag = inv1 + jnp.where(two, inv2, 0.0)
    return jac[:, None], pos[:, None], jnp.zeros_like(pos)[:, None], diag[:, None]


_KINDS = {
    int(EQ.mjEQ_CONNECT): _connect,
    int(EQ.mjEQ_WELD): _weld,
    int(EQ.mjEQ_JOINT): _joint,
    int(EQ.mjEQ_TENDON): _tendon,
}


def rows(m: Model, d: Data) -> Rows:
    """Every equality row, in model order (each kind computed for all its constraints at once)."""
    ne = nrows(m)
    dtype = d.qpos.dtype
    start = np.concatenate([[0], np.cumsum(row_counts(m))[:-1]])
    jac, pos, jdotv, diag = (
        jnp.zeros((ne, m.nv), dtype),
        jnp.zeros(ne, dtype),
        jnp.zeros(ne, dtype),
        jnp.zeros(ne, dtype),
    )
    block = jnp.zeros(ne, dtype)
    for kind, fn in _KINDS.items():
        idx = np.flatnonzero(m.eq_type == kind)
        if not idx.size:
            continue
        j, p, v, g = fn(m, d, idx)  # (n, k, nv), (n, k), (n, k), (n, k)
        k = p.shape[1]
        at = (start[idx][:, None] + np.arange(k)).reshape(-1)
        norm = jnp.sqrt(jnp.sum(p**2, 1)) if k > 1 else p[:, 0]
        jac = jac.at[at].set(j.reshape(-1, m.nv))
        pos = pos.at[at].set(p.reshape(-1))
        jdotv = jdotv.at[at].set(v.reshape(-1))
        diag = diag.at[at].set(g.reshape(-1))
        block = block.at[at].set(jnp.repeat(norm, k))
    each = row_counts(m)
    active = jnp.repeat(d.eq_active, each, total_repeat_length=ne)
    solref = jnp.repeat(m.eq_solref, each, axis=0, total_repeat_length=ne)
    solimp = jnp.repeat(m.eq_solimp, each, axis=0, total_repeat_length=ne)
    return Rows(jac, pos, jdotv, diag, block, active, solref, solimp)
