"""Tendons: lengths, Jacobians and velocities (mj_tendon), and tendon armature (mj_tendonArmature,
mj_tendonBias).

A fixed tendon is a linear combination of scalar joint positions. A spatial tendon is a path of
sites, optionally wrapped around a sphere or cylinder geom between two sites, with pulleys
dividing what follows them. Without a side site a wrap takes the shorter way round where the
straight segment crosses the geom; a side site outside the geom sets the winding (MuJoCo 4.0's
rule, ``_wrap_homotopic``); one inside it makes the path touch the geom from within. Which sites and geoms
make up each segment is static (``wrap_type``, ``wrap_objid``, ``wrap_prm``), decided here with
numpy while tracing; the per-segment math is vectorised and branch-free (a wrap that does not
happen is a masked choice). As in MuJoCo, the Jacobian of a segment is its unit direction times
the difference of its end points' Jacobians, skipped when both ends lie on one body, and the arc
around a wrapping geom contributes to the length only.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import math, smooth, tree
from fastrl.physics.types import Data, JointType, Model

# MuJoCo's mjtWrap values (plain ints: numpy scalars do not compare equal to the enum in ``in``)
_JOINT, _PULLEY = int(mujoco.mjtWrap.mjWRAP_JOINT), int(mujoco.mjtWrap.mjWRAP_PULLEY)
_SPHERE, _CYLINDER = int(mujoco.mjtWrap.mjWRAP_SPHERE), int(mujoco.mjtWrap.mjWRAP_CYLINDER)
MINVAL = mujoco.mjMINVAL
# MuJoCo 3.x's wrap_inside: Newton iterations, starting point and tolerance. MuJoCo 4.0 changed
# that solver (its sources are not in the mirror): lengths still agree to 1e-14, the touching
# point and so ten_J to ~2e-8 (measured on test_tendon's arm).
_INSIDE_ITERATIONS, _INSIDE_Z0, _INSIDE_TOL = 20, 1.0 - 1e-7, 1e-6


class Layout(NamedTuple):
    """The static structure of a model's tendons (numpy, built while tracing).

    ``*_moves`` flag the segments whose two ends lie on different bodies (the others have no
    Jacobian); ``*_scale`` (ntendon, nsegments) holds 1/divisor in each segment's tendon row.
    """

    qpos_coef: np.ndarray  # (ntendon, nq) fixed tendons: length = qpos_coef @ qpos
    dof_coef: np.ndarray  # (ntendon, nv) fixed tendons: J = dof_coef
    straight: np.ndarray  # (2, nstraight) site0, site1
    straight_moves: np.ndarray  # (nstraight,)
    straight_scale: np.ndarray
    wrapped: np.ndarray  # (4, nwrapped) site0, geom, side site (-1: none), site1
    wrapped_sphere: np.ndarray  # (nwrapped,) the geom is a sphere (else a cylinder)
    wrapped_moves: np.ndarray  # (3, nwrapped) site0-geom, geom-site1, and site0-site1 unwrapped
    wrapped_scale: np.ndarray


def layout(m: Model) -> Layout:
    """Walks every tendon's wrap list as mj_tendon does and returns its static ``Layout``."""
    qpos_coef, dof_coef = np.zeros((m.ntendon, m.nq)), np.zeros((m.ntendon, m.nv))
    straight, wrapped, straight_of, wrapped_of = [], [], [], []
    for i in range(m.ntendon):
        adr, num = int(m.tendon_adr[i]), int(m.tendon_num[i])
        types = [int(t) for t in m.wrap_type[adr : adr + num]]
        ids, prm = m.wrap_objid[adr : adr + num], m.wrap_prm[adr : adr + num]
        if types[0] == _JOINT:
            for j, coef in zip(ids, prm, strict=True):
                qpos_coef[i, m.jnt_qposadr[j]] += coef
                dof_coef[i, m.jnt_dofadr[j]] += coef
            continue
        divisor, j = 1.0, 0
        while j < num - 1:
            if _PULLEY in (types[j], types[j + 1]):
                divisor = float(prm[j]) if types[j] == _PULLEY else divisor
                j += 1
            elif types[j + 1] in (_SPHERE, _CYLINDER):
                side = int(np.round(prm[j + 1]))
                wrapped.append((ids[j], ids[j + 1], side, ids[j + 2], types[j + 1] == _SPHERE))
                wrapped_of.append((i, 1.0 / divisor))
                j += 2
            else:
                straight.append((ids[j], ids[j + 1]))
                straight_of.append((i, 1.0 / divisor))
                j += 1
    straight = np.array(straight, np.int64).reshape(-1, 2).T
    wrapped_arr = np.array([w[:4] for w in wrapped], np.int64).reshape(-1, 4).T
    sb, gb = m.site_bodyid, m.geom_bodyid
    s0, g, s1 = wrapped_arr[0], wrapped_arr[1], wrapped_arr[3]
    wrapped_moves = np.stack([sb[s0] != gb[g], gb[g] != sb[s1], sb[s0] != sb[s1]])

    def scale(of):
        out = np.zeros((m.ntendon, len(of)))
        for k, (i, s) in enumerate(of):
            out[i, k] = s
        return out

    return Layout(
        qpos_coef=qpos_coef, dof_coef=dof_coef,
        straight=straight, straight_moves=sb[straight[0]] != sb[straight[1]],
        straight_scale=scale(straight_of),
        wrapped=wrapped_arr, wrapped_sphere=np.array([w[4] for w in wrapped], bool),
        wrapped_moves=wrapped_moves, wrapped_scale=scale(wrapped_of),
    )  # fmt: skip


def _normalize(v: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``v / |v|`` over the last axis, and ``|v|``; below mjMINVAL the first axis (mju_normalize)."""
    n = jnp.sqrt(jnp.sum(v * v, -1, keepdims=True))
    first = jnp.zeros_like(v).at[..., 0].set(1.0)
    return jnp.where(n < MINVAL, first, v / jnp.where(n < MINVAL, 1.0, n)), n[..., 0]


def _safe_div(a: jax.Array, b: jax.Array) -> jax.Array:
    return a / jnp.where(b == 0, 1.0, b)


def _intersect(p1, p2, p3, p4) -> jax.Array:
    """Whether 2D segments p1-p2 and p3-p4 cross (MuJoCo's is_intersect)."""
    det = (p4[1] - p3[1]) * (p2[0] - p1[0]) - (p4[0] - p3[0]) * (p2[1] - p1[1])
    a = _safe_div((p4[0] - p3[0]) * (p1[1] - p3[1]) - (p4[1] - p3[1]) * (p1[0] - p3[0]), det)
    b = _safe_div((p2[0] - p1[0]) * (p1[1] - p3[1]) - (p2[1] - p1[1]) * (p1[0] - p3[0]), det)
    return (jnp.abs(det) >= MINVAL) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)


def _arc(p0, p1, other_way, radius) -> jax.Array:
    """Length of the arc from p0 to p1 on the circle (MuJoCo's length_circle)."""
    u0, _ = _normalize(p0)
    u1, _ = _normalize(p1)
    angle = jnp.arccos(jnp.clip(jnp.dot(u0, u1), -1.0, 1.0))
    cross = p0[1] * p1[0] - p0[0] * p1[1]
    flip = jnp.where(other_way, cross > 0, cross < 0)
    return radius * jnp.where(flip, 2 * jnp.pi - angle, angle)


def _wrap_shorter(end, radius) -> tuple[jax.Array, jax.Array]:
    """The 2D wrap, without a side site, of segment end[:2]-end[2:] around the circle at the
    origin (MuJoCo's wrap_circle): where the segment crosses the circle, the shorter way round.

    Returns the arc length (-1: no wrap) and the two tangent points (4,).
    """
    e0, e1 = end[:2], end[2:]
    sqlen0, sqlen1, sqrad = jnp.dot(e0, e0), jnp.dot(e1, e1), radius * radius
    dif = e1 - e0
    dd = jnp.dot(dif, dif)
    a = jnp.clip(-_safe_div(jnp.dot(dif, e0), dd), 0.0, 1.0)
    near = a * dif + e0  # nearest point of the segment to the centre
    none = (sqlen0 < sqrad) | (sqlen1 < sqrad) | (radius < MINVAL) | (dd < MINVAL)
    none = none | (jnp.dot(near, near) > sqrad)
    r0 = jnp.sqrt(jnp.maximum(sqlen0 - sqrad, 0.0))
    r1 = jnp.sqrt(jnp.maximum(sqlen1 - sqrad, 0.0))
    sols, goods = [], []
    for sgn in (1.0, -1.0):
        s0 = jnp.stack([e0[0] * sqrad + sgn * radius * e0[1] * r0, e0[1] * sqrad - sgn * radius * e0[0] * r0])
        s1 = jnp.stack([e1[0] * sqrad - sgn * radius * e1[1] * r1, e1[1] * sqrad + sgn * radius * e1[0] * r1])
        s0, s1 = _safe_div(s0, sqlen0), _safe_div(s1, sqlen1)
        sols.append(jnp.concatenate([s0, s1]))
        goods.append(jnp.where(_intersect(e0, s0, e1, s1), -10000.0, -jnp.sum((s0 - s1) ** 2)))
    second = ~(goods[0] > goods[1])
    pnt = jnp.where(second, sols[1], sols[0])
    none = none | _intersect(e0, pnt[:2], e1, pnt[2:])
    return jnp.where(none, -1.0, _arc(pnt[:2], pnt[2:], second, radius)), pnt


def _wrap_homotopic(end, side, radius) -> tuple[jax.Array, jax.Array]:
    """The 2D wrap with a side site (MuJoCo >= 4.0): the shortest path from end[:2] to end[2:]
    around the circle at the origin with the winding angle of the polyline through ``side``.

    That winding ``W`` is the sum of the (signed, within +-pi) angles the two legs of the polyline
    subtend at the centre. The path leaves each endpoint along its tangent (the tangent point lies
    ``acos(r / |p|)`` round from the endpoint's direction), so it wraps, the way ``W`` turns, by
    ``|W| - acos(r / |p0|) - acos(r / |p1|)`` where that is positive; otherwise the straight
    segment is that path. Checked against MuJoCo 4.0 (whose sources are not in the mirror) on
    random spheres and cylinders to 1e-14. Returns the arc length (-1: no wrap) and the two
    tangent points (4,).
    """
    e0, e1 = end[:2], end[2:]
    len0, len1 = jnp.linalg.norm(e0), jnp.linalg.norm(e1)
    phi0, phi1 = jnp.arctan2(e0[1], e0[0]), jnp.arctan2(e1[1], e1[0])
    phis = jnp.arctan2(side[1], side[0])
    turn = lambda a: (a + jnp.pi) % (2 * jnp.pi) - jnp.pi  # noqa: E731
    winding = turn(phis - phi0) + turn(phi1 - phis)
    a0 = jnp.arccos(jnp.clip(_safe_div(radius, len0), -1.0, 1.0))
    a1 = jnp.arccos(jnp.clip(_safe_div(radius, len1), -1.0, 1.0))
    arc = jnp.abs(winding) - a0 - a1
    none = (len0 < radius) | (len1 < radius) | (radius < MINVAL) | (arc <= 0)
    sgn = jnp.sign(winding)
    t0, t1 = phi0 + sgn * a0, phi1 - sgn * a1
    pnt = radius * jnp.stack([jnp.cos(t0), jnp.sin(t0), jnp.cos(t1), jnp.sin(t1)])
    return jnp.where(none, -1.0, radius * arc), pnt


def _wrap_inside(end, radius) -> tuple[jax.Array, jax.Array]:
    """The wrap of a segment whose side site is inside the circle (MuJoCo's wrap_inside).

    The path touches the circle at one point, found by MuJoCo's Newton iteration (a fixed 20
    masked steps); where that fails, the point between the two ends. Returns 0 (-1: no wrap)
    and the touching point twice (4,).
    """
    e0, e1 = end[:2], end[2:]
    len0, len1 = jnp.linalg.norm(e0), jnp.linalg.norm(e1)
    dif = e1 - e0
    dd = jnp.dot(dif, dif)
    a = -_safe_div(jnp.dot(dif, e0), dd)
    crosses = (dd > MINVAL) & (a > 0) & (a < 1) & (jnp.linalg.norm(e0 + a * dif) <= radius)
    none = (len0 <= radius) | (len1 <= radius) | (radius < MINVAL) | (len0 < MINVAL) | (len1 < MINVAL)
    mid, _ = _normalize(0.5 * (e0 + e1))
    fallback = jnp.concatenate([mid * radius, mid * radius])
    # MuJoCo's names; capped at 1 where there is no wrap anyway, to keep arcsin finite
    A, B = jnp.minimum(_safe_div(radius, len0), 1.0), jnp.minimum(_safe_div(radius, len1), 1.0)  # noqa: N806
    cos_g = _safe_div(len0 * len0 + len1 * len1 - dd, 2 * len0 * len1)
    none = none | crosses | (cos_g < -1 + MINVAL)
    g = jnp.arccos(jnp.clip(cos_g, -1.0, 1.0))

    def f(z):
        return jnp.arcsin(A * z) + jnp.arcsin(B * z) - 2 * jnp.arcsin(z) + g

    def newton(_, carry):
        z, fz, iters, failed = carry
        run = ~failed & (jnp.abs(fz) > _INSIDE_TOL)
        root = lambda c: jnp.maximum(MINVAL, jnp.sqrt(jnp.maximum(1 - z * z * c * c, 0.0)))  # noqa: E731
        df = A / root(A) + B / root(B) - 2 / root(1.0)
        z1 = z - fz / jnp.where(df > -MINVAL, -1.0, df)
        f1 = f(z1)
        bad = (df > -MINVAL) | (z1 > z) | (f1 > _INSIDE_TOL)
        return (
            jnp.where(run & ~bad, z1, z), jnp.where(run & ~bad, f1, fz),
            iters + run, failed | (run & bad),
        )  # fmt: skip

    z0 = jnp.asarray(_INSIDE_Z0, end.dtype)
    # where f(z0) > 0 the root lies beyond z0, within 1e-7 of 1 (wrap onset): MuJoCo 4.0 then keeps
    # z0 (measured; 3.x fell back to the midpoint), and so do we
    z, _, iters, failed = jax.lax.fori_loop(
        0,
        _INSIDE_ITERATIONS,
        newton,
        (z0, jnp.minimum(f(z0), 0.0), jnp.zeros((), jnp.int32), jnp.array(False)),
    )
    ok = ~failed & (iters < _INSIDE_ITERATIONS) & (cos_g <= 1 - MINVAL)
    turn_first = e0[0] * e1[1] - e0[1] * e1[0] > 0
    vec, _ = _normalize(jnp.where(turn_first, e0, e1))
    ang = jnp.arcsin(z) - jnp.arcsin(jnp.where(turn_first, A, B) * z)
    c, s = jnp.cos(ang), jnp.sin(ang)
    pnt = radius * jnp.stack([c * vec[0] - s * vec[1], s * vec[0] + c * vec[1]])
    return jnp.where(none, -1.0, 0.0), jnp.where(ok, jnp.concatenate([pnt, pnt]), fallback)


def _wrap(x0, x1, gpos, gmat, radius, sphere, side, has_side, inside: bool):
    """A segment x0-x1 wrapped around a sphere or cylinder geom (mju_wrap), for one segment.

    Returns the wrapped length (-1: the straight segment does not touch the geom) and the two
    tangent points in world coordinates. ``inside`` (static) traces wrap_inside, for a side site
    inside the geom.
    """
    p0, p1 = gmat.T @ (x0 - gpos), gmat.T @ (x1 - gpos)
    degenerate = (jnp.linalg.norm(p0) < MINVAL) | (jnp.linalg.norm(p1) < MINVAL)
    # sphere: the plane through the centre and both points (another one if they are parallel)
    a0, _ = _normalize(p0)
    normal, nrm = _normalize(math.cross(p0, p1))
    ab = jnp.abs(a0)
    i = jnp.where((ab[1] > ab[0]) & (ab[1] > ab[2]), 1, 0)
    i = jnp.where((ab[2] > ab[0]) & (ab[2] > ab[1]), 2, i)
    other, _ = _normalize(math.cross(a0, jnp.ones(3, p0.dtype).at[i].set(0.0)))
    normal = jnp.where(nrm < MINVAL, other, normal)
    a1, _ = _normalize(math.cross(normal, a0))
    eye = jnp.eye(3, dtype=p0.dtype)
    a0, a1 = jnp.where(sphere, a0, eye[0]), jnp.where(sphere, a1, eye[1])
    end = jnp.stack([p0 @ a0, p0 @ a1, p1 @ a0, p1 @ a1])
    s = gmat.T @ (side - gpos)
    sd, _ = _normalize(jnp.stack([s @ a0, s @ a1]))
    wlen, pnt = _wrap_shorter(end, radius)
    side_len, side_pnt = _wrap_homotopic(end, sd * radius, radius)
    wlen, pnt = jnp.where(has_side, side_len, wlen), jnp.where(has_side, side_pnt, pnt)
    if inside:
        in_len, in_pnt = _wrap_inside(end, radius)
        within = has_side & (jnp.linalg.norm(s) < radius)
        wlen, pnt = jnp.where(within, in_len, wlen), jnp.where(within, in_pnt, pnt)
    res0, res1 = a0 * pnt[0] + a1 * pnt[1], a0 * pnt[2] + a1 * pnt[3]
    # cylinder: the tangent points' heights split the height change in proportion to the path
    l0 = jnp.linalg.norm(p0[:2] - res0[:2])
    l1 = jnp.linalg.norm(p1[:2] - res1[:2])
    total = l0 + wlen + l1
    z0 = p0[2] + (p1[2] - p0[2]) * _safe_div(l0, total)
    z1 = p0[2] + (p1[2] - p0[2]) * _safe_div(l0 + wlen, total)
    helix = jnp.sqrt(wlen * wlen + (z1 - z0) ** 2)
    none = degenerate | (wlen < 0)
    res0 = jnp.where(sphere, res0, res0.at[2].set(z0))
    res1 = jnp.where(sphere, res1, res1.at[2].set(z1))
    wlen = jnp.where(sphere, wlen, helix)
    return jnp.where(none, -1.0, wlen), gmat @ res0 + gpos, gmat @ res1 + gpos


def along(m: Model, d: Data, points: jax.Array, bodies: np.ndarray, direction: jax.Array) -> jax.Array:
    """(n, nv) ``direction . J(point)``: the velocity of each point along ``direction`` per unit
    velocity of each dof, for points fixed to ``bodies`` (mj_jac projected on a direction)."""
    offset = points - d.subtree_com[m.body_rootid[bodies]]
    rows = direction @ d.cdof[:, 3:].T + math.cross(offset, direction) @ d.cdof[:, :3].T
    return rows * jnp.asarray(tree.body_dof_ancestors(m)[bodies], rows.dtype)


def _segments(m: Model, d: Data, p0, b0, p1, b1, moves: np.ndarray):
    """Lengths (n,) and Jacobians (n, nv) of straight segments p0-p1 between points on bodies."""
    u, length = _normalize(p1 - p0)
    jac = along(m, d, p1, b1, u) - along(m, d, p0, b0, u)
    return length, jac * jnp.asarray(moves[:, None], jac.dtype)


def _spatial(m: Model, d: Data, lay: Layout) -> tuple[jax.Array, jax.Array]:
    """Lengths (ntendon,) and Jacobians (ntendon, nv) of the spatial tendons' paths."""
    dtype = d.qpos.dtype
    length, jac = jnp.zeros(m.ntendon, dtype), jnp.zeros((m.ntendon, m.nv), dtype)
    sb, gb = m.site_bodyid, m.geom_bodyid
    if lay.straight.size:
        s0, s1 = lay.straight
        seg_len, seg_jac = _segments(
            m, d, d.site_xpos[s0], sb[s0], d.site_xpos[s1], sb[s1], lay.straight_moves
        )
        scale = jnp.asarray(lay.straight_scale, dtype)
        length, jac = length + scale @ seg_len, jac + scale @ seg_jac
    if lay.wrapped.size:
        s0, g, side, s1 = lay.wrapped
        x0, x1 = d.site_xpos[s0], d.site_xpos[s1]
        has_side = side >= 0
        inside = bool(has_side.any())
        wrap = jax.vmap(lambda *a: _wrap(*a, inside=inside))
        wlen, t0, t1 = wrap(
            x0, x1, d.geom_xpos[g], d.geom_xmat[g], m.geom_size[g, 0], jnp.asarray(lay.wrapped_sphere),
            d.site_xpos[np.maximum(side, 0)], jnp.asarray(has_side),
        )  # fmt: skip
        mv = lay.wrapped_moves
        len_a, jac_a = _segments(m, d, x0, sb[s0], t0, gb[g], mv[0])
        len_c, jac_c = _segments(m, d, t1, gb[g], x1, sb[s1], mv[1])
        len_d, jac_d = _segments(m, d, x0, sb[s0], x1, sb[s1], mv[2])
        ok = wlen >= 0
        seg_len = jnp.where(ok, len_a + wlen + len_c, len_d)
        seg_jac = jnp.where(ok[:, None], jac_a + jac_c, jac_d)
        scale = jnp.asarray(lay.wrapped_scale, dtype)
        length, jac = length + scale @ seg_len, jac + scale @ seg_jac
    return length, jac


def lengths_and_jacobians(m: Model, d: Data) -> tuple[jax.Array, jax.Array]:
    """(ntendon,) ``ten_length`` and (ntendon, nv) ``ten_J`` of the current pose (mj_tendon).

    Expects ``com_pos`` to have run (site and geom poses, cdof, subtree_com).
    """
    lay = layout(m)
    length = jnp.asarray(lay.qpos_coef, d.qpos.dtype) @ d.qpos
    jac = jnp.asarray(lay.dof_coef, d.qpos.dtype)
    if lay.straight.size or lay.wrapped.size:
        spatial_len, spatial_jac = _spatial(m, d, lay)
        length, jac = length + spatial_len, jac + spatial_jac
    return length, jac


def tendon(m: Model, d: Data) -> Data:
    """Tendon lengths, Jacobians and velocities ``ten_J qvel`` (mj_tendon, as mj_fwdVelocity).

    Nothing is traced for a model without tendons. Expects ``com_pos`` to have run.
    """
    if not m.ntendon:
        return d
    length, jac = lengths_and_jacobians(m, d)
    return d.replace(ten_length=length, ten_J=jac, ten_velocity=jac @ d.qvel)


def tree_mask(m: Model) -> np.ndarray:
    """(nv, nv) 0/1: pairs of dofs on one path to the root, the sparsity of M and of MuJoCo's
    ``qDeriv``. MuJoCo adds ``J^T B J`` terms of tendons only inside it (mju_addToSclSparseInc)."""
    lower = tree.dof_ancestor_mask(m)
    return lower + lower.T - np.eye(m.nv)


def _qpos_rate(m: Model, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
    """(nq,) ``d qpos / dt`` at velocity ``qvel``: quaternions turn at ``q (0, w) / 2``."""
    rate = jnp.zeros_like(qpos)
    for j, t in enumerate(m.jnt_type):
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if t == JointType.FREE:
            rate = rate.at[qa : qa + 3].set(qvel[va : va + 3])
            qa, va = qa + 3, va + 3
        if t in (JointType.FREE, JointType.BALL):
            w = jnp.concatenate([jnp.zeros(1, qvel.dtype), qvel[va : va + 3]])
            rate = rate.at[qa : qa + 4].set(0.5 * math.quat_mul(qpos[qa : qa + 4], w))
        else:
            rate = rate.at[qa].set(qvel[va])
    return rate


def is_fixed(m: Model) -> np.ndarray:
    """(ntendon,) bool: fixed tendons (joint coefficients); the others are spatial."""
    return m.wrap_type[m.tendon_adr] == _JOINT


def _spatial_armature(m: Model) -> np.ndarray:
    """The tendons of ``armature_tendons`` that are spatial (fixed tendons have ``Jdot = 0``)."""
    ids = np.asarray(m.armature_tendons, np.int64)
    return ids[~is_fixed(m)[ids]]


def armature(m: Model, d: Data) -> Data:
    """Tendon armature: ``M += J^T a J`` (mj_tendonArmature) and the bias ``J a Jdot qvel``
    (mj_tendonBias), for the tendons of ``armature_tendons``.

    As in MuJoCo, ``J^T a J`` enters M only where M has room: between dofs on one path to the root
    (a tendon coupling two branches adds no inertia between them). ``Jdot qvel`` is the rate of
    ``J qvel`` along the motion, by forward-mode differentiation of the tendon Jacobian in time;
    fixed tendons have none. Expects ``tendon``, ``crb`` and ``rne`` to have run.
    """
    if not m.armature_tendons.size:
        return d
    inertia = (d.ten_J.T * m.tendon_armature) @ d.ten_J
    qm = d.qM + inertia * jnp.asarray(tree_mask(m), inertia.dtype)
    d = d.replace(qM=qm)
    spatial = _spatial_armature(m)
    if not spatial.size:
        return d

    def rate(qpos):
        dq = smooth.com_pos(m, smooth.kinematics(m, d.replace(qpos=qpos)))
        return lengths_and_jacobians(m, dq)[1][spatial] @ d.qvel

    _, jdot_qvel = jax.jvp(rate, (d.qpos,), (_qpos_rate(m, d.qpos, d.qvel),))
    bias = d.ten_J[spatial].T @ (m.tendon_armature[spatial] * jdot_qvel)
    return d.replace(qfrc_bias=d.qfrc_bias + bias)
