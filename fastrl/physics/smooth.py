"""Smooth dynamics: kinematics, com-based quantities, mass matrix, bias forces, solving with M.

Each stage is a pure ``(model, data) -> data`` function written for one environment; batches come
from ``jax.vmap``. Per-joint-type code is chosen while tracing from the static joint types.
Recursions over the tree are either one pass per tree depth (kinematics, which composes rotations;
a ``lax.scan`` over the depths for a deep tree) or products with constant ancestor matrices (every
sum over a subtree or a path). ``solve_mass`` solves with M by its factor (``factor.solve``) or,
for a deep tree in float32, through its articulated inertias, a scan from the leaves and one from
the roots.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import factor, math, tree
from fastrl.physics.types import Data, JointType, Model


def _const(x: np.ndarray, like: jax.Array) -> jax.Array:
    return jnp.asarray(x, dtype=like.dtype)


def _joint_local(m: Model, qpos: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Each joint's transform in its body frame: translation (njnt, 3) and rotation (njnt, 4)."""
    dtype = qpos.dtype
    trans = jnp.zeros((m.njnt, 3), dtype)
    quat = jnp.zeros((m.njnt, 4), dtype).at[:, 0].set(1.0)
    jt, adr = m.jnt_type, m.jnt_qposadr
    hinge = np.flatnonzero(jt == JointType.HINGE)
    if hinge.size:
        angle = qpos[adr[hinge]] - m.qpos0[adr[hinge]]
        q = math.axis_angle_to_quat(m.jnt_axis[hinge], angle)
        p = m.jnt_pos[hinge]
        trans = trans.at[hinge].set(p - math.quat_rotate(q, p))
        quat = quat.at[hinge].set(q)
    slide = np.flatnonzero(jt == JointType.SLIDE)
    if slide.size:
        disp = qpos[adr[slide]] - m.qpos0[adr[slide]]
        trans = trans.at[slide].set(m.jnt_axis[slide] * disp[:, None])
    ball = np.flatnonzero(jt == JointType.BALL)
    if ball.size:
        q = math.quat_normalize(qpos[adr[ball][:, None] + np.arange(4)])
        p = m.jnt_pos[ball]
        trans = trans.at[ball].set(p - math.quat_rotate(q, p))
        quat = quat.at[ball].set(q)
    free = np.flatnonzero(jt == JointType.FREE)
    if free.size:
        trans = trans.at[free].set(qpos[adr[free][:, None] + np.arange(3)])
        quat = quat.at[free].set(math.quat_normalize(qpos[adr[free][:, None] + np.arange(3, 7)]))
    return trans, quat


def _compose(t1, q1, t2, q2):
    """Frame composition (t1, q1) o (t2, q2)."""
    return t1 + math.quat_rotate(q1, t2), math.quat_mul(q1, q2)


def _body_local(m: Model, jtrans, jquat):
    """Body frames relative to their parents, and each joint's frame just before it acts.

    A body's frame is its ``pos/quat`` offset followed by its joints in order (a free joint replaces
    the offset). Returns body (nbody, 3), (nbody, 4) and joint-prefix (njnt, 3), (njnt, 4).
    """
    dtype = jtrans.dtype
    has_free = np.zeros(m.nbody, bool)
    has_free[m.jnt_bodyid[m.jnt_type == JointType.FREE]] = True
    keep = jnp.asarray(~has_free, dtype)[:, None]
    t = m.body_pos * keep
    q = m.body_quat * keep + jnp.asarray(has_free, dtype)[:, None] * jnp.array([1.0, 0, 0, 0], dtype)
    # Joint slots: slot s of body b is joint jntadr[b]+s, or the identity (index njnt) if absent.
    jtrans = jnp.concatenate([jtrans, jnp.zeros((1, 3), dtype)])
    jquat = jnp.concatenate([jquat, jnp.array([[1.0, 0, 0, 0]], dtype)])
    pre_t = jnp.zeros((m.njnt, 3), dtype)
    pre_q = jnp.zeros((m.njnt, 4), dtype)
    for s in range(int(m.body_jntnum.max(initial=0))):
        present = m.body_jntnum > s
        idx = np.where(present, m.body_jntadr + s, m.njnt)
        bodies = np.flatnonzero(present)
        pre_t = pre_t.at[idx[bodies]].set(t[bodies])
        pre_q = pre_q.at[idx[bodies]].set(q[bodies])
        t, q = _compose(t, q, jtrans[idx], jquat[idx])
    return t, q, pre_t, pre_q


def _world_frames(m: Model, levels: list[np.ndarray], lt: jax.Array, lq: jax.Array):
    """Body poses (nbody, 3), (nbody, 4) in the world from those relative to their parents, one
    unrolled pass per tree depth: rows of (pos, quat) are appended level by level."""
    pos = jnp.zeros((1, 3), lt.dtype)
    quat = jnp.array([[1.0, 0, 0, 0]], lt.dtype)
    row = np.zeros(m.nbody, np.int64)
    n = 1
    for level in levels:
        parent = row[m.body_parentid[level]]
        p, q = _compose(pos[parent], quat[parent], lt[level], lq[level])
        pos = jnp.concatenate([pos, p])
        quat = jnp.concatenate([quat, math.quat_normalize(q)])
        row[level] = n + np.arange(level.size)
        n += level.size
    return pos[row], quat[row]


# From this many bodies deep, kinematics composes the poses in a ``lax.scan`` over the depths
# instead of unrolling them: unrolled, a 200-hinge chain's passes take 24 s of its step's 29 s
# compile (XLA:CPU, optimisation level 0); scanned, the step compiles in 2.4 s. Shallower trees
# (fastrl's environments are at most 10 bodies deep) keep the unrolled passes, which run no loop.
SCANNED_KINEMATICS_MIN_DEPTH = 32


def _world_frames_scanned(m: Model, levels: list[np.ndarray], lt: jax.Array, lq: jax.Array):
    """``_world_frames`` as a ``lax.scan`` over the depths, each level padded to the widest one
    (padding slots read the world's row and write a spare row past the last body)."""
    ids = np.full((len(levels), max(level.size for level in levels)), m.nbody, np.int64)
    for i, level in enumerate(levels):
        ids[i, : level.size] = level
    parent = np.append(m.body_parentid, 0)[ids]
    spare = lambda x: jnp.concatenate([x, x[:1]])  # noqa: E731
    lt, lq = spare(lt), spare(lq)
    start = (jnp.zeros((m.nbody + 1, 3), lt.dtype), jnp.zeros((m.nbody + 1, 4), lt.dtype).at[:, 0].set(1.0))

    def level(frames, rows):
        pos, quat = frames
        k, p = rows
        t, q = _compose(pos[p], quat[p], lt[k], lq[k])
        return (pos.at[k].set(t), quat.at[k].set(math.quat_normalize(q))), None

    (pos, quat), _ = jax.lax.scan(level, start, (ids, parent))
    return pos[: m.nbody], quat[: m.nbody]


def kinematics(m: Model, d: Data) -> Data:
    """Body, joint, geom and site poses in the world frame (mj_kinematics)."""
    jtrans, jquat = _joint_local(m, d.qpos)
    lt, lq, pre_t, pre_q = _body_local(m, jtrans, jquat)
    if m.mocap_bodies.size:  # children of the world, placed by Data.mocap_pos/mocap_quat
        lt = lt.at[m.mocap_bodies].set(d.mocap_pos)
        lq = lq.at[m.mocap_bodies].set(math.quat_normalize(d.mocap_quat))
    levels = tree.body_levels(m)
    if len(levels) >= SCANNED_KINEMATICS_MIN_DEPTH:
        xpos, xquat = _world_frames_scanned(m, levels, lt, lq)
    else:
        xpos, xquat = _world_frames(m, levels, lt, lq)
    xmat = math.quat_to_mat(xquat)
    xipos = xpos + math.quat_rotate(xquat, m.body_ipos)
    ximat = math.quat_to_mat(math.quat_mul(xquat, m.body_iquat))
    # Joint axes and anchors from the frame just before each joint acts.
    jb = m.jnt_bodyid
    ft, fq = _compose(xpos[m.body_parentid[jb]], xquat[m.body_parentid[jb]], pre_t, pre_q)
    xanchor = ft + math.quat_rotate(fq, m.jnt_pos)
    xaxis = math.quat_rotate(fq, m.jnt_axis)
    free = m.jnt_type == JointType.FREE
    if free.any():
        xanchor = jnp.where(free[:, None], xpos[jb], xanchor)
        xaxis = jnp.where(free[:, None], m.jnt_axis, xaxis)
    gb, sb = m.geom_bodyid, m.site_bodyid
    return d.replace(
        xpos=xpos, xquat=xquat, xmat=xmat, xipos=xipos, ximat=ximat, xanchor=xanchor, xaxis=xaxis,
        geom_xpos=xpos[gb] + math.quat_rotate(xquat[gb], m.geom_pos),
        geom_xmat=math.quat_to_mat(math.quat_mul(xquat[gb], m.geom_quat)),
        site_xpos=xpos[sb] + math.quat_rotate(xquat[sb], m.site_pos),
        site_xmat=math.quat_to_mat(math.quat_mul(xquat[sb], m.site_quat)),
    )  # fmt: skip


def _dof_axes(m: Model, d: Data) -> tuple[jax.Array, np.ndarray, jax.Array]:
    """Each dof's world axis, whether it rotates, and its anchor point."""
    # Source rows: joint axes, then the columns of every body frame, then the world axes.
    cols = jnp.swapaxes(d.xmat, -1, -2).reshape(m.nbody * 3, 3)
    src = jnp.concatenate([d.xaxis, cols, jnp.eye(3, dtype=cols.dtype)])
    index = np.zeros(m.nv, np.int64)
    rot = np.ones(m.nv, bool)
    for j, jt in enumerate(m.jnt_type):
        a, b = m.jnt_dofadr[j], m.jnt_bodyid[j]
        if jt == JointType.HINGE:
            index[a] = j
        elif jt == JointType.SLIDE:
            index[a], rot[a] = j, False
        else:  # ball, and the rotational half of free: the body frame's axes
            if jt == JointType.FREE:
                index[a : a + 3] = m.njnt + 3 * m.nbody + np.arange(3)
                rot[a : a + 3] = False
                a += 3
            index[a : a + 3] = m.njnt + 3 * b + np.arange(3)
    return src[index], rot, d.xanchor[m.dof_jntid]


def com_pos(m: Model, d: Data) -> Data:
    """Subtree centres of mass, com-based inertias and motion dofs (mj_comPos)."""
    dtype = d.xpos.dtype
    sub = _const(tree.body_ancestors(m).T, d.xpos)  # [i, j] = 1 iff j in subtree(i)
    mass = m.body_mass
    msum = sub @ mass
    com_all = (sub @ (mass[:, None] * d.xipos)) / jnp.where(msum > 0, msum, 1.0)[:, None]
    subtree_com = jnp.where((msum > 0)[:, None], com_all, d.xipos)
    world_mass = jnp.sum(mass)
    world_com = jnp.sum(mass[:, None] * d.xipos, 0) / jnp.where(world_mass > 0, world_mass, 1.0)
    subtree_com = subtree_com.at[0].set(world_com)
    # Inertia of each body about its tree's centre of mass, in world axes.
    off = d.xipos - subtree_com[m.body_rootid]
    inertia = math.matmul(d.ximat * m.body_inertia[:, None, :], jnp.swapaxes(d.ximat, -1, -2))
    inertia = inertia + mass[:, None, None] * (
        jnp.sum(off * off, -1)[:, None, None] * jnp.eye(3, dtype=dtype) - off[:, :, None] * off[:, None, :]
    )
    sym = inertia[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    cinert = jnp.concatenate([sym, mass[:, None] * off, mass[:, None]], axis=-1)
    axis, rot, anchor = _dof_axes(m, d)
    offset = subtree_com[m.body_rootid[m.dof_bodyid]] - anchor
    rotc = _const(rot[:, None], axis)
    cdof = jnp.concatenate([axis * rotc, rotc * math.cross(axis, offset) + (1 - rotc) * axis], -1)
    return d.replace(subtree_com=subtree_com, cinert=cinert, cdof=cdof)


def com_vel(m: Model, d: Data) -> Data:
    """Body spatial velocities and the time derivative of the motion dofs (mj_comVel)."""
    qv = d.cdof * d.qvel[:, None]
    cvel = _const(tree.body_dof_ancestors(m), qv) @ qv
    before = _const(tree.dof_velocity_before(m), qv) @ qv
    moving = _const(~tree.is_free_translation(m)[:, None], qv)  # world-fixed axes: zero derivative
    cdof_dot = math.cross_motion(before, d.cdof) * moving
    return d.replace(cvel=cvel, cdof_dot=cdof_dot)


def crb(m: Model, d: Data) -> Data:
    """Joint-space mass matrix by the composite-rigid-body algorithm (mj_crb), armature included."""
    composite = _const(tree.body_ancestors(m).T, d.cinert) @ d.cinert
    force = math.mul_inert_vec(composite[m.dof_bodyid], d.cdof)  # (nv, 6)
    full = jnp.sum(force[:, None, :] * d.cdof[None, :, :], -1)  # [i, j] = cdof_j . I_i cdof_i
    lower = full * _const(tree.dof_ancestor_mask(m), full)
    qm = lower + lower.T - jnp.diag(jnp.diag(lower)) + jnp.diag(m.dof_armature)
    return d.replace(qM=qm)


def rne(m: Model, d: Data) -> Data:
    """Bias forces: Coriolis, centrifugal and gravity, by recursive Newton-Euler (mj_rne)."""
    dtype = d.cvel.dtype
    gravity_acc = jnp.concatenate([jnp.zeros(3, dtype), -m.gravity])
    cacc = gravity_acc + _const(tree.body_dof_ancestors(m), d.cvel) @ (d.cdof_dot * d.qvel[:, None])
    body_force = math.mul_inert_vec(d.cinert, cacc) + math.cross_force(
        d.cvel, math.mul_inert_vec(d.cinert, d.cvel)
    )
    cfrc = _const(tree.body_ancestors(m).T, body_force) @ body_force
    bias = jnp.sum(d.cdof * cfrc[m.dof_bodyid], -1)
    return d.replace(qfrc_bias=bias)


# From this many dofs deep a float32 solve with M goes through the articulated inertias
# (``solve_mass``) instead of M's entries. The mass matrix of a long chain is ill-conditioned (a
# chain of capsules: scaled condition number 4e4 at 10 links, 2e7 at 40, 1e10 at 200), and float32
# entries lose its small eigenvalues: M^-1 f with MuJoCo's own M rounded to float32 is off by 1e-3
# of the largest acceleration at depth 20, 1e-2 at 40 and 0.1 at 60, and from about 100 links the
# rounded M is not positive definite (NaN). The articulated form is off by 4e-5 to 1e-4 up to 90
# links and 2e-3 at 200. fastrl's environments (the Humanoid's tree is 13 dofs deep) keep M.
ARTICULATED_MIN_DEPTH = 32


def articulated(m: Model, dtype: jnp.dtype) -> bool:
    """Whether ``solve_mass`` factorises M from the articulated inertias: in float32 (or
    narrower) for a dof tree at least ``ARTICULATED_MIN_DEPTH`` deep without tendon armature
    (whose ``J^T a J`` has no articulated form)."""
    deep = len(tree.dof_levels(m)) >= ARTICULATED_MIN_DEPTH
    return deep and jnp.finfo(dtype).bits < 64 and not m.armature_tendons.size


class _Articulated(typing.NamedTuple):
    """``M + diag(extra)`` factorised from the leaves up in articulated-body form: ``M = L^T D L``
    with ``L[k, i] = motion_i . u_k / pivot_k`` for each ancestor i of dof k (Featherstone's
    articulated-body algorithm). Each dof's quantities are about its own anchor, so no float32
    number holds a lever arm across the whole tree, as the com-based ``cinert`` does.

    Fields (per dof): ``motion`` (nv, 6) its motion axis; ``u`` (nv, 6) its articulated inertia
    times ``motion``; ``pivot`` (nv,) ``motion . u`` plus armature and extra: the diagonal D;
    ``shift`` (nv, 6, 6) the motion transform from its parent dof's anchor to its own.
    """

    motion: jax.Array
    u: jax.Array
    pivot: jax.Array
    shift: jax.Array


def _skew(v: jax.Array) -> jax.Array:
    """(..., 3, 3) cross-product matrices: ``_skew(v) @ x = v x x``."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2)


def _blocks(a: jax.Array, b: jax.Array, c: jax.Array, e: jax.Array) -> jax.Array:
    """(..., 6, 6) from the 3 x 3 blocks ``[[a, b], [c, e]]``."""
    return jnp.concatenate([jnp.concatenate([a, b], -1), jnp.concatenate([c, e], -1)], -2)


def _transform(d: jax.Array) -> jax.Array:
    """(n, 6, 6) ``T``: ``T x`` is the motion ``x`` (rotation, velocity at a point q) seen at
    ``q + d``; ``T^T f`` moves a force from ``q + d`` to q, and ``T^T A T`` an inertia."""
    eye = jnp.broadcast_to(jnp.eye(3, dtype=d.dtype), d.shape[:-1] + (3, 3))
    return _blocks(eye, jnp.zeros_like(eye), -_skew(d), eye)


def _inertia_at(m: Model, d: Data, bodies: np.ndarray, point: jax.Array) -> jax.Array:
    """(n, 6, 6) the spatial inertias of ``bodies`` about ``point`` (n, 3), in world axes."""
    r = d.xipos[bodies] - point
    mass = m.body_mass[bodies][:, None, None]
    rot = d.ximat[bodies]
    eye = jnp.eye(3, dtype=r.dtype)
    inertia = math.matmul(rot * m.body_inertia[bodies][:, None, :], jnp.swapaxes(rot, -1, -2))
    inertia = inertia + mass * (jnp.sum(r * r, -1)[:, None, None] * eye - r[:, :, None] * r[:, None, :])
    coupling = mass * _skew(r)
    return _blocks(inertia, coupling, jnp.swapaxes(coupling, -1, -2), mass * eye)


def _level_table(m: Model) -> tuple[np.ndarray, np.ndarray]:
    """(depth, width) dof ids of each level of the dof tree (``tree.dof_levels``) and their parents.

    Padding slots hold ``nv + 1``, a sink row that stays zero; a root's parent is ``nv``, a row
    the passes from the roots only read (zero) and the passes from the leaves only write.
    """
    levels = tree.dof_levels(m)
    ids = np.full((len(levels), max(level.size for level in levels)), m.nv + 1, np.int64)
    for i, level in enumerate(levels):
        ids[i, : level.size] = level
    parent = np.append(np.where(m.dof_parentid >= 0, m.dof_parentid, m.nv), [m.nv, m.nv + 1])
    return ids, parent[ids]


def _padded(x: jax.Array, fill: float = 0.0) -> jax.Array:
    """``x`` with the rows ``nv`` and ``nv + 1`` of ``_level_table`` appended."""
    return jnp.concatenate([x, jnp.full((2,) + x.shape[1:], fill, x.dtype)])


def _articulated_factor(m: Model, d: Data, extra: jax.Array) -> _Articulated:
    """The articulated factor of ``M + diag(extra)`` at the poses of ``d``: a ``lax.scan`` over
    the depths from the leaves, so that the program does not grow with the depth."""
    axis, rot, anchor = _dof_axes(m, d)
    rotc = _const(rot[:, None], axis)
    motion = _padded(jnp.concatenate([axis * rotc, axis * (1 - rotc)], -1))
    parent = np.where(m.dof_parentid >= 0, m.dof_parentid, np.arange(m.nv))
    shift = _padded(_transform(anchor - anchor[parent]))
    owner = tree.body_inertia_dof(m)
    bodies = np.flatnonzero(owner >= 0)
    own = jnp.zeros((m.nv + 2, 6, 6), axis.dtype)
    own = own.at[owner[bodies]].add(_inertia_at(m, d, bodies, anchor[owner[bodies]]))
    pivot_extra = _padded(m.dof_armature + extra, 1.0)

    def level(passed, ids):
        k, p = ids
        inertia = own[k] + passed[k]  # with the children's articulated inertias, less their axis
        u = jnp.sum(inertia * motion[k][:, None, :], -1)
        pivot = jnp.sum(motion[k] * u, -1) + pivot_extra[k]
        rest = inertia - u[:, :, None] * u[:, None, :] / pivot[:, None, None]
        t = shift[k]
        return passed.at[p].add(math.matmul(jnp.swapaxes(t, -1, -2), math.matmul(rest, t))), (u, pivot)

    ids, par = _level_table(m)
    _, (u, pivot) = jax.lax.scan(level, jnp.zeros_like(own), (ids, par), reverse=True)
    flat = ids.reshape(-1)
    u = jnp.zeros((m.nv + 2, 6), u.dtype).at[flat].set(u.reshape(-1, 6))
    pivot = jnp.ones(m.nv + 2, pivot.dtype).at[flat].set(pivot.reshape(-1))
    return _Articulated(motion, u, pivot, shift)


def _articulated_solve(m: Model, f: _Articulated, vec: jax.Array) -> jax.Array:
    """``x = L^-1 D^-1 L^-T vec`` for the articulated factor ``f``: a pass from the leaves (the
    force each subtree passes to its parent), then one from the roots (the accelerations)."""
    ids, par = _level_table(m)
    flat = ids.reshape(-1)
    vec = _padded(vec)

    def up(force, ids):  # L^-T, then D^-1
        k, p = ids
        y = (vec[k] - jnp.sum(f.motion[k] * force[k], -1)) / f.pivot[k]
        passed = force[k] + f.u[k] * y[:, None]
        return force.at[p].add(jnp.sum(f.shift[k] * passed[:, :, None], -2)), y  # T^T passed

    _, y = jax.lax.scan(up, jnp.zeros((m.nv + 2, 6), vec.dtype), (ids, par), reverse=True)
    z = jnp.zeros_like(vec).at[flat].set(y.reshape(-1))

    def down(acc, ids):  # L^-1: less what the ancestors' accelerations ask of each dof
        k, p = ids
        base = jnp.sum(f.shift[k] * acc[p][:, None, :], -1)
        x = z[k] - jnp.sum(f.u[k] * base, -1) / f.pivot[k]
        return acc.at[k].set(base + f.motion[k] * x[:, None]), x

    _, x = jax.lax.scan(down, jnp.zeros((m.nv + 2, 6), vec.dtype), (ids, par))
    return jnp.zeros_like(vec).at[flat].set(x.reshape(-1))[: m.nv]


def solve_mass(m: Model, d: Data, vec: jax.Array, extra: jax.Array | None = None) -> jax.Array:
    """``(M + diag(extra))^-1 vec`` with the mass matrix of ``d`` (after ``crb``).

    Float32 trees at least ``ARTICULATED_MIN_DEPTH`` deep (``articulated``) factorise from each
    dof's articulated inertia, about its own anchor, rather than from ``d.qM``, whose float32
    entries cannot hold a long chain's smallest eigenvalues; the rest ``factor.solve(m, d.qM +
    diag(extra), vec)``.

    Args:
      m: the model.
      d: the data, with ``qM`` and the poses it was computed at.
      vec: (nv,) the right-hand side.
      extra: (nv,) added to M's diagonal (implicit damping's ``h B``); None for none.
    Returns:
      (nv,) the solution.
    """
    if not articulated(m, vec.dtype):
        return factor.solve(m, d.qM if extra is None else d.qM + jnp.diag(extra), vec)
    extra = jnp.zeros_like(vec) if extra is None else extra
    return _articulated_solve(m, _articulated_factor(m, d, extra), vec)
