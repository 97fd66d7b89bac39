"""Collision primitives, each written for one geom pair and vmapped by the driver.

Every function takes the two geoms' world poses and sizes and returns a fixed number of
candidate contacts ``(dist (n,), pos (n, 3), normal (n, 3), tangent (n, 3))``: ``dist`` is the
signed surface distance (negative in penetration), ``pos`` the point midway between the surfaces,
``normal`` the unit vector from geom1 to geom2, as in MuJoCo, and ``tangent`` a hint for the
contact frame's first tangent (zero: none, use ``make_frame``'s default). Whether a candidate
is active (``dist`` below the pair's margin) is decided by the caller with a mask, never a
branch.

Geom conventions (MuJoCo): a plane's normal is its local z axis; a sphere's size[0] is its
radius; a capsule has radius size[0] and half-length size[1] along its local z axis; a box has
half-sizes size[0:3].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.physics.math import cross, dot

_EPS = 1e-12


def _normalize(v: jax.Array) -> tuple[jax.Array, jax.Array]:
    n = jnp.sqrt(dot(v, v))
    safe = jnp.where(n > _EPS, n, 1.0)
    return v / safe[..., None], n


def _sphere_sphere(c1, r1, c2, r2, fallback):
    """Contact between two spheres; ``fallback`` is the normal used when the centres coincide."""
    normal, d = _normalize(c2 - c1)
    normal = jnp.where(d > _EPS, normal, fallback)
    dist = d - r1 - r2
    pos = c1 + normal * (r1 + 0.5 * dist)
    return dist, pos, normal


def _closest_on_segment(a, b, p):
    """The point of segment [a, b] nearest to p."""
    ab = b - a
    t = jnp.clip(dot(p - a, ab) / jnp.maximum(dot(ab, ab), _EPS), 0.0, 1.0)
    return a + t[..., None] * ab


def _segment_ends(pos, mat, half_length):
    axis = mat[:, 2]
    return pos - half_length * axis, pos + half_length * axis


def _one(dist, pos, normal):
    return dist[None], pos[None], normal[None], jnp.zeros_like(normal)[None]


def plane_sphere(p_pos, p_mat, p_size, s_pos, s_mat, s_size):
    """One contact: the sphere's lowest point against the plane."""
    del p_size, s_mat
    normal = p_mat[:, 2]
    dist = dot(s_pos - p_pos, normal) - s_size[0]
    pos = s_pos - normal * (s_size[0] + 0.5 * dist)
    return _one(dist, pos, normal)


def plane_capsule(p_pos, p_mat, p_size, c_pos, c_mat, c_size):
    """Two contacts: each end sphere of the capsule; the first tangent follows the capsule axis."""
    del p_size
    normal = p_mat[:, 2]
    ends = jnp.stack(_segment_ends(c_pos, c_mat, c_size[1]))
    dist = (ends - p_pos) @ normal - c_size[0]
    pos = ends - normal * (c_size[0] + 0.5 * dist)[:, None]
    return dist, pos, jnp.broadcast_to(normal, (2, 3)), jnp.broadcast_to(c_mat[:, 2], (2, 3))


# Corner i has +size along x, y, z where bits 0, 1, 2 of i are set (MuJoCo's order).
_BOX_CORNERS = [[1.0 if i & (1 << k) else -1.0 for k in range(3)] for i in range(8)]


def plane_box(p_pos, p_mat, p_size, b_pos, b_mat, b_size):
    """Four contacts: the first four corners (in MuJoCo's order) on the plane's side of the box."""
    del p_size
    normal = p_mat[:, 2]
    offsets = (jnp.asarray(_BOX_CORNERS, b_size.dtype) * b_size) @ b_mat.T
    facing = offsets @ normal <= 0  # corners on the lower half of the box, towards the plane
    order = jnp.argsort(jnp.arange(8) + 8 * (~facing))[:4]
    corners = b_pos + offsets[order]
    dist = (corners - p_pos) @ normal
    pos = corners - normal * (0.5 * dist)[:, None]
    normal4 = jnp.broadcast_to(normal, (4, 3))
    return dist, pos, normal4, jnp.zeros_like(normal4)


def sphere_sphere(pos1, mat1, size1, pos2, mat2, size2):
    """One contact between sphere centres."""
    return _one(*_sphere_sphere(pos1, size1[0], pos2, size2[0], mat1[:, 2]))


def sphere_capsule(s_pos, s_mat, s_size, c_pos, c_mat, c_size):
    """One contact: the sphere against the nearest point of the capsule's segment."""
    a, b = _segment_ends(c_pos, c_mat, c_size[1])
    nearest = _closest_on_segment(a, b, s_pos)
    return _one(*_sphere_sphere(s_pos, s_size[0], nearest, c_size[0], s_mat[:, 2]))


def _closest_between_segments(a1, b1, a2, b2):
    """Nearest points of two segments (clamped parameters), robust to parallel segments."""
    d1, d2, r = b1 - a1, b2 - a2, a1 - a2
    aa, ee, f = dot(d1, d1), dot(d2, d2), dot(d2, r)
    c, b = dot(d1, r), dot(d1, d2)
    denom = aa * ee - b * b
    s = jnp.where(denom > _EPS * aa * ee + _EPS, (b * f - c * ee) / jnp.maximum(denom, _EPS), 0.5)
    s = jnp.clip(s, 0.0, 1.0)
    t = jnp.clip((b * s + f) / jnp.maximum(ee, _EPS), 0.0, 1.0)
    s = jnp.clip((b * t - c) / jnp.maximum(aa, _EPS), 0.0, 1.0)
    return a1 + s * d1, a2 + t * d2


def capsule_capsule(pos1, mat1, size1, pos2, mat2, size2):
    """One contact between the nearest points of the two capsules' segments."""
    a1, b1 = _segment_ends(pos1, mat1, size1[1])
    a2, b2 = _segment_ends(pos2, mat2, size2[1])
    p1, p2 = _closest_between_segments(a1, b1, a2, b2)
    fallback, _ = _normalize(cross(mat1[:, 2], mat2[:, 2]) + 1e-9 * mat1[:, 0])
    return _one(*_sphere_sphere(p1, size1[0], p2, size2[0], fallback))


def sphere_box(s_pos, s_mat, s_size, b_pos, b_mat, b_size):
    """One contact: the sphere against the box's nearest surface point (or deepest face inside)."""
    local = b_mat.T @ (s_pos - b_pos)
    clamped = jnp.clip(local, -b_size, b_size)
    inside = jnp.all(jnp.abs(local) <= b_size)
    # Outside: nearest surface point. Inside: push out through the face of least penetration.
    gap = b_size - jnp.abs(local)
    axis = jnp.argmin(gap)
    face_sign = jnp.where(local[axis] >= 0, 1.0, -1.0)
    out_normal_local = jnp.zeros(3, local.dtype).at[axis].set(face_sign)
    delta, d = _normalize(local - clamped)  # from box surface towards the sphere centre
    normal_local = jnp.where(inside, -out_normal_local, -delta)  # geom1 (sphere) -> geom2 (box)
    dist = jnp.where(inside, -gap[axis], d) - s_size[0]
    normal = b_mat @ normal_local
    pos = s_pos + normal * (s_size[0] + 0.5 * dist)
    return _one(dist, pos, normal)
