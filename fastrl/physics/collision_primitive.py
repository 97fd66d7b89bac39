"""Collision primitives, each written for one geom pair and vmapped by the driver.

Every function takes the two geoms' world poses and sizes and returns a fixed number of
candidate contacts ``(dist (n,), pos (n, 3), normal (n, 3), tangent (n, 3))``: ``dist`` is the
signed surface distance (negative in penetration), ``pos`` the point midway between the surfaces,
``normal`` the unit vector from geom1 to geom2, as in MuJoCo, and ``tangent`` a hint for the
contact frame's first tangent (zero: none, use ``make_frame``'s default). Whether a candidate
is active (``dist`` below the pair's margin) is decided by the caller with a mask, never a
branch.

Geom conventions (MuJoCo): a plane's normal is its local z axis; a sphere's size[0] is its
radius; a capsule has radius size[0] and half-length size[1] along its local z axis, a cylinder
radius size[0] and half-height size[1] along it; a box has half-sizes size[0:3].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics.math import cross, dot

_EPS = 1e-12


def _safe_sqrt(x: jax.Array) -> jax.Array:
    """sqrt with a zero (not NaN) gradient at zero, where contacts often sit (a point on an axis)."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def _normalize(v: jax.Array) -> tuple[jax.Array, jax.Array]:
    n = _safe_sqrt(dot(v, v))
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


def plane_cylinder(p_pos, p_mat, p_size, c_pos, c_mat, c_size):
    """Four contacts (mjc_PlaneCylinder): the rim point nearest the plane, the same point on the
    far rim, and two more on the near rim completing an equilateral triangle with the first.

    MuJoCo emits the far-rim and triangle points only when they are within the margin; here they
    are always candidates and the margin mask drops them: the first point is the deepest of all
    four, so MuJoCo's early exit when it lies beyond the margin changes nothing.
    """
    del p_size
    normal = p_mat[:, 2]
    radius, half = c_size[0], c_size[1]
    # The axis, flipped to point towards the plane: its end there is the near rim's centre.
    axis_dot = dot(normal, c_mat[:, 2])
    axis = jnp.where(axis_dot > 0, -1.0, 1.0) * c_mat[:, 2]
    axis_dot = -jnp.abs(axis_dot)
    dist0 = dot(c_pos - p_pos, normal)
    # Radial direction of the rim point nearest the plane: -normal without its axis component.
    # A disk parallel to the plane has none; MuJoCo then takes the cylinder's x axis.
    vec = axis * axis_dot - normal
    length = _safe_sqrt(dot(vec, vec))
    tilted = length >= 1e-15  # MuJoCo's mjMINVAL
    vec = jnp.where(tilted, vec / jnp.where(tilted, length, 1.0), c_mat[:, 0]) * radius
    vec_dot = dot(vec, normal)
    side, _ = _normalize(cross(vec, axis))
    side = side * radius * jnp.sqrt(3.0) / 2
    near, far = c_pos + axis * half, c_pos - axis * half
    points = jnp.stack([near + vec, far + vec, near + side - 0.5 * vec, near - side - 0.5 * vec])
    dist = dist0 + jnp.stack(
        [axis_dot * half + vec_dot, -axis_dot * half + vec_dot] + [axis_dot * half - 0.5 * vec_dot] * 2
    )
    pos = points - normal * (0.5 * dist)[:, None]
    normal4 = jnp.broadcast_to(normal, (4, 3))
    return dist, pos, normal4, jnp.zeros_like(normal4)


def _sphere_sphere_mj(c1, r1, z1, c2, r2, z2):
    """``_sphere_sphere`` with MuJoCo's fallback normal for coincident centres: the cross
    product of the geoms' z axes, or +x when those are parallel."""
    fallback, n = _normalize(cross(z1, z2))
    fallback = jnp.where(n > _EPS, fallback, jnp.array([1.0, 0.0, 0.0], c1.dtype))
    return _sphere_sphere(c1, r1, c2, r2, fallback)


def sphere_cylinder(s_pos, s_mat, s_size, c_pos, c_mat, c_size):
    """One contact (mjc_SphereCylinder): against the side, a cap or the rim, by the sphere centre's
    position; a centre inside the cylinder leaves through the nearer of the side and the cap."""
    radius, half = c_size[0], c_size[1]
    axis = c_mat[:, 2]
    rel = s_pos - c_pos
    x = dot(axis, rel)
    radial = rel - axis * x
    radial_sq = dot(radial, radial)
    side = jnp.abs(x) < half
    cap = radial_sq < radius**2
    # Centre inside: keep whichever of side and cap is nearer (the side on a tie, as MuJoCo).
    prefer_side = half - jnp.abs(x) >= radius - _safe_sqrt(radial_sq)
    side, cap = side & (~cap | prefer_side), cap & (~side | ~prefer_side)
    # Side: a sphere of the cylinder's radius at the centre's projection on the axis.
    side_c = _sphere_sphere_mj(s_pos, s_size[0], s_mat[:, 2], c_pos + axis * x, radius, axis)
    # Cap: the sphere against the cap's plane; the normal points from the sphere into the cap.
    cap_n = jnp.where(x > 0, 1.0, -1.0) * axis
    cap_dist = dot(rel, cap_n) - half - s_size[0]
    cap_c = (cap_dist, s_pos - cap_n * (s_size[0] + 0.5 * cap_dist), -cap_n)
    # Rim: a point sphere at the rim point nearest the centre (outside both side and cap, so the
    # radial part is at least the radius and never zero).
    rim = c_pos + radial * (radius / jnp.sqrt(jnp.maximum(radial_sq, _EPS))) + cap_n * half
    rim_c = _sphere_sphere_mj(s_pos, s_size[0], s_mat[:, 2], rim, 0.0, axis)
    pick = lambda i: jnp.where(side, side_c[i], jnp.where(cap, cap_c[i], rim_c[i]))  # noqa: E731
    return _one(pick(0), pick(1), pick(2))


def _cylinder_rate(p, d, radius, half):
    """Rate of change of a solid cylinder's signed distance at local points p (..., 3) moving
    with velocity d (3,). The signed distance is convex, so this rate never decreases along a
    line: the segment search below bisects on its sign."""
    rho = jnp.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2)
    radial_rate = (p[..., 0] * d[0] + p[..., 1] * d[1]) / jnp.where(rho > 0, rho, 1.0)
    axial_rate = jnp.where(p[..., 2] >= 0, d[2], -d[2])
    dr, dz = rho - radius, jnp.abs(p[..., 2]) - half
    out_r, out_z = jnp.maximum(dr, 0.0), jnp.maximum(dz, 0.0)
    out = jnp.sqrt(out_r**2 + out_z**2)  # distance from outside; zero inside
    outside_rate = (out_r * radial_rate + out_z * axial_rate) / jnp.where(out > 0, out, 1.0)
    inside_rate = jnp.where(dr > dz, radial_rate, axial_rate)  # the nearer of side and cap
    return jnp.where(out > 0, outside_rate, inside_rate)


def _section_search(descending, lo, hi, points=15):
    """Where a monotone test flips in the bracket [lo, hi] (any shape): the point at which
    ``descending(t)`` (t of shape lo.shape + (points,)) stops being True.

    Each round tests ``points`` evenly spaced points as one vector op and keeps the
    (points + 1)-th of the bracket where the test flips: log2(points + 1) bits a round, a
    quarter of bisection's sequential rounds. Rounds continue to float32's resolution, or to
    1e-12 of the bracket in float64, far below MuJoCo's own GJK/EPA tolerance (they are
    unrolled, and each costs compile and run time).
    """
    bits = min(int(jnp.finfo(lo.dtype).nmant) + 2, 40)
    splits = points + 1
    frac = jnp.arange(1, splits, dtype=lo.dtype) / splits
    for _ in range(-(-bits // int(np.log2(splits)))):
        width = hi - lo
        below = jnp.sum(descending(lo[..., None] + width[..., None] * frac), axis=-1)
        lo, hi = lo + width * below / splits, lo + width * (below + 1) / splits
    return 0.5 * (lo + hi)


def _segment_cylinder_nearest(a, d, radius, half):
    """Parameter t in [0, 1] of the point of segment ``a + t d`` (cylinder frame) with the least
    signed distance to the cylinder, by section search on the sign of its rate.

    Where the minimum is flat (a segment parallel to a cap or to the axis), two brackets find
    both ends of the flat stretch and t is its middle: one contact in the middle of a line
    contact, rather than at whichever end rounding favours.
    """
    flat = 100 * jnp.finfo(a.dtype).eps * jnp.sqrt(dot(d, d))
    threshold = jnp.stack([-flat, flat])[:, None]  # left end: stop descending; right: start rising

    def descending(t):
        return _cylinder_rate(a + t[..., None] * d, d, radius, half) < threshold

    return jnp.mean(_section_search(descending, jnp.zeros(2, a.dtype), jnp.ones(2, a.dtype)))


def _overlap(n, a, b, radius, half):
    """How far segment [a, b] reaches into the cylinder along unit directions n (..., 3): the
    segment's support plus the cylinder's (symmetric about its centre, the frame's origin)."""
    cyl = radius * _safe_sqrt(n[..., 0] ** 2 + n[..., 1] ** 2) + half * jnp.abs(n[..., 2])
    return jnp.maximum(n @ a, n @ b) + cyl


def _least_overlap_across(a, b, radius, half, samples=32):
    """The unit direction orthogonal to the segment [a, b] of least overlap (see ``_overlap``).

    On that circle of directions the whole segment supports, and the overlap is the distance
    to the boundary of an elliptic stadium (the cylinder seen along the segment), which can have
    several local minima: the best of ``samples`` directions is refined by section search on the
    derivative along the arc to its two neighbours. The arc is parametrised by the chord between
    them (no trigonometry in the loop: it would make XLA's compile time explode).
    """
    dtype = a.dtype
    along, _ = _normalize(b - a)
    e1, n1 = _normalize(cross(jnp.array([0.0, 0.0, 1.0], dtype), along))
    e1 = jnp.where(n1 > 1e-9, e1, jnp.array([1.0, 0.0, 0.0], dtype))  # segment along the axis
    e2 = cross(along, e1)
    mid = 0.5 * (a + b)
    angle = 2 * np.pi * np.arange(samples) / samples
    ring = jnp.asarray(np.cos(angle), dtype)[:, None] * e1 + jnp.asarray(np.sin(angle), dtype)[:, None] * e2
    best = jnp.argmin(_overlap(ring, mid, mid, radius, half))
    n_lo, n_hi = ring[(best - 1) % samples], ring[(best + 1) % samples]
    chord = n_hi - n_lo

    def descending(t):
        n = n_lo + t[..., None] * chord  # not unit: the overlap is homogeneous of degree one
        n_xy = jnp.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2)
        radial = radius / jnp.where(n_xy > 0, n_xy, 1.0)
        grad = mid + jnp.stack([radial * n[..., 0], radial * n[..., 1], half * jnp.sign(n[..., 2])], -1)
        # d/dt of overlap(n / |n|), times |n|^3: Euler's identity gives overlap(n) = grad . n.
        return dot(grad, chord) * dot(n, n) - dot(grad, n) * dot(n, chord) < 0

    t = _section_search(descending, jnp.zeros((), dtype), jnp.ones((), dtype))
    return _normalize(n_lo + t * chord)[0]


def _least_overlap(a, b, radius, half):
    """(overlap, direction): the least overlap of segment [a, b] and the cylinder over all
    directions, i.e. how deep the segment is in the cylinder and which way it leaves (EPA's
    minimum translation, less the capsule's radius).

    Any direction's overlap bounds the least one from above, and the least is attained either
    where a single segment end supports, and then only at a cap's normal or sideways (the local
    minima of a point's overlap with a cylinder, the best sideways one being away from the
    segment's point nearest the axis), or at a direction orthogonal to the segment: the least of
    those four candidates is exact.
    """
    dtype = a.dtype
    d_xy, a_xy = (b - a)[:2], a[:2]
    # Sideways: away from the segment's point nearest the axis, seen along the axis.
    t = jnp.clip(-dot(a_xy, d_xy) / jnp.maximum(dot(d_xy, d_xy), _EPS), 0.0, 1.0)
    away, n_away = _normalize(-(a_xy + t * d_xy))
    across, n_across = _normalize(jnp.stack([-d_xy[1], d_xy[0]]))
    side = jnp.where(n_away > _EPS, away, jnp.where(n_across > _EPS, across, jnp.eye(2, dtype=dtype)[0]))
    up = jnp.array([0.0, 0.0, 1.0], dtype)
    candidates = jnp.stack([up, -up, jnp.append(side, 0.0), _least_overlap_across(a, b, radius, half)])
    overlap = _overlap(candidates, a, b, radius, half)
    k = jnp.argmin(overlap)
    return overlap[k], candidates[k]


def _flat_support_point(n, a, b, radius, half):
    """Where a segment lying flat against the cylinder's side (n sideways) or cap (n along the
    axis) touches it: sideways, its point nearest the axis seen along the axis (the middle of its
    part within the cylinder's height if it is parallel to the axis); against a cap, the middle of
    its chord over the cap. GJK/EPA would return an arbitrary point of such a line contact."""
    d = b - a
    d_sq, ad = dot(d[:2], d[:2]), dot(a[:2], d[:2])
    inv = 1.0 / jnp.maximum(d_sq, _EPS)
    low = jnp.maximum(-half, jnp.minimum(a[2], b[2]))
    high = jnp.minimum(half, jnp.maximum(a[2], b[2]))
    along_axis = jnp.append(a[:2], 0.5 * (low + high))
    side = jnp.where(d_sq > _EPS, a + jnp.clip(-ad * inv, 0.0, 1.0) * d, along_axis)
    root = _safe_sqrt(ad**2 - d_sq * (dot(a[:2], a[:2]) - radius**2))
    chord = jnp.clip((-ad + jnp.stack([-root, root])) * inv, 0.0, 1.0)
    return jnp.where(jnp.abs(n[2]) > 0.5, a + 0.5 * jnp.sum(chord) * d, side)


def _deep_contact_pos(n, depth, a, b, capsule_radius, radius, half):
    """Contact point of a penetration ``depth`` along n (cylinder frame): half-way back from the
    capsule's deepest point (a segment end, or where a flat-lying segment touches), or, where the
    whole segment supports against a single rim point, half-way out from that rim point."""
    tie = jnp.sqrt(jnp.finfo(a.dtype).eps)
    d = b - a
    reach = dot(d, n) / jnp.maximum(jnp.sqrt(dot(d, d)), _EPS)  # > 0: b reaches deeper
    one_end = jnp.abs(reach) > tie
    segment_point = jnp.where(one_end, jnp.where(reach > 0, b, a), _flat_support_point(n, a, b, radius, half))
    n_xy = _safe_sqrt(n[0] ** 2 + n[1] ** 2)
    on_rim = (n_xy > tie) & (jnp.abs(n[2]) > tie)
    rim = -jnp.append(radius * n[:2] / jnp.where(on_rim, n_xy, 1.0), half * jnp.sign(n[2]))
    return jnp.where(
        one_end | ~on_rim,
        segment_point + (capsule_radius - 0.5 * depth) * n,
        rim + 0.5 * depth * n,
    )


def capsule_cylinder(c_pos, c_mat, c_size, y_pos, y_mat, y_size):
    """One contact between a capsule and a cylinder, as MuJoCo's GJK/EPA converges to it.

    MuJoCo 4.0 has no primitive for this pair: mjc_Convex runs GJK on the capsule's segment and
    the cylinder, and while they are apart the contact is their closest points, inflated by the
    capsule's radius; once the segment reaches the cylinder (within half the margin), EPA on the
    full shapes gives the minimum translation. Both are computed here exactly, in the cylinder's
    frame: the closest point by section search along the segment (the cylinder's signed distance is
    convex), the translation from a few candidate directions (``_least_overlap``). MuJoCo's own
    answer is only as exact as its ``ccd_tolerance`` (at the default 1e-6 its normals err by up
    to 1e-3 when deep). Unlike MuJoCo, this never adds contacts: MuJoCo's multi-CCD (on by
    default) sometimes gives a capsule passing nearly parallel to a cap two contacts on the cap's
    plane instead. Gradients treat the searched parameters as constants, exact for the distance.
    """
    radius, half, cap_r = y_size[0], y_size[1], c_size[0]
    a, b = ((p - y_pos) @ y_mat for p in _segment_ends(c_pos, c_mat, c_size[1]))
    d = b - a
    s = a + _segment_cylinder_nearest(a, d, radius, half) * d
    rho = _safe_sqrt(s[0] ** 2 + s[1] ** 2)
    clamp = jnp.minimum(1.0, radius / jnp.where(rho > 0, rho, 1.0))
    nearest = jnp.append(s[:2] * clamp, jnp.clip(s[2], -half, half))  # on the cylinder
    n_apart, gap = _normalize(nearest - s)
    apart = gap > jnp.sqrt(jnp.finfo(a.dtype).eps) * (radius + half)
    overlap, n_deep = _least_overlap(a, b, radius, half)
    depth = overlap + cap_r
    pos = jnp.where(
        apart,
        0.5 * (s + cap_r * n_apart + nearest),
        _deep_contact_pos(n_deep, depth, a, b, cap_r, radius, half),
    )
    normal = jnp.where(apart, n_apart, n_deep)
    dist = jnp.where(apart, gap - cap_r, -depth)
    return _one(dist, y_pos + y_mat @ pos, y_mat @ normal)


_FAR = 1e6  # a candidate's dist when it is dropped: beyond any margin, so masked as inactive


def _box_sdf_slope(local, d, half):
    """Slope along ``d`` of a box's signed distance at the box-frame point ``local``."""
    q = jnp.abs(local) - half
    sign = jnp.where(local >= 0, 1.0, -1.0)
    out = jnp.maximum(q, 0.0)
    outward, n = _normalize(out * sign)
    face = jnp.zeros(3, local.dtype).at[jnp.argmax(q)].set(1.0) * sign
    return dot(jnp.where(n > 0, outward, face), d)


def capsule_box(c_pos, c_mat, c_size, b_pos, b_mat, b_size):
    """Three contacts: each end sphere of the capsule against the box, and the capsule's deepest
    point along its segment (the box's signed distance is convex along a line, so a section
    search on its slope finds it; a tiny pull towards the segment's middle picks one point where
    a face is parallel to the segment).

    A capsule lying on a face gets the two end contacts MuJoCo's mjc_CapsuleBox gives it; the
    middle candidate is dropped (dist set far beyond any margin) when it repeats an end, i.e.
    both ends are as deep as it or it sits at an end. A capsule across an edge (a finger over a
    cube's edge) keeps the middle one there. One known difference: a capsule lying along a
    face and reaching past its edge gets from MuJoCo a second, shallower contact where the
    segment leaves the face; here it has the deepest point only (until an end reaches the face),
    so such a touch holds a little less firmly.
    """
    a, b = ((p - b_pos) @ b_mat for p in _segment_ends(c_pos, c_mat, c_size[1]))
    d = b - a
    pull = 1e-3 * dot(d, d)

    def descending(t):
        pts = a + t[..., None] * d
        slope = jax.vmap(lambda p: _box_sdf_slope(p, d, b_size))(pts.reshape(-1, 3)).reshape(t.shape)
        return slope + pull * (t - 0.5) < 0

    zero = jnp.zeros((), a.dtype)
    t = jax.lax.stop_gradient(_section_search(descending, zero, zero + 1.0))
    world = lambda p: b_pos + b_mat @ p  # noqa: E731
    centres = jnp.stack([world(a), world(b), world(a + t * d)])
    dist, pos, normal, tangent = jax.vmap(lambda s: sphere_box(s, c_mat, c_size, b_pos, b_mat, b_size))(
        centres
    )
    dist, pos, normal, tangent = dist[:, 0], pos[:, 0], normal[:, 0], tangent[:, 0]
    tol = 1e-6 + 1e-4 * c_size[0]
    repeats = (
        ((jnp.abs(dist[2] - dist[0]) < tol) & (jnp.abs(dist[2] - dist[1]) < tol))
        | (t < 1e-2)
        | (t > 1 - 1e-2)
    )
    dist = dist.at[2].set(jnp.where(repeats, _FAR, dist[2]))
    return dist, pos, normal, tangent
