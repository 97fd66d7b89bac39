"""Box against box as MuJoCo's ``mjc_BoxBox``: a separating-axis test, then one edge-edge contact
or a face manifold, written without branches for one pair (the driver vmaps it).

1. **Separating axes.** The three face normals of each box and the nine cross products of their
   edges. Any axis separating the boxes by more than the margin (plus a rounding slack scaled by
   the boxes' size) means no contact. Otherwise the axis of largest separation wins; an edge axis
   must beat the faces by a small relative bias, and one nearly parallel (cosine above 0.99) to
   the best face axis gives way to that face unless it is five percent better, so that resting
   boxes keep a face manifold instead of flipping between the two by rounding.
2. **Edge-edge.** The two supporting edges' closest points (both sign choices where an axis
   component is too small to choose a corner); one contact midway, along the axis.
3. **Face.** The winning face is the reference; the incident box's face most opposed to it is
   clipped against the reference face's four side planes (Sutherland-Hodgman, in fixed buffers
   of at most eight vertices). Each clipped vertex within the margin of the reference plane is a
   contact (near-duplicates from clipping at corners dropped), with the face normal, placed
   midway between the reference plane and the incident vertex.

All contacts of a pair share the winning axis as their normal, from box 1 to box 2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.physics.collision_primitive import _FAR

CONTACTS = 8  # a quad clipped by four half-planes has at most eight vertices
_EDGE_BIAS = 1e-6
_MINVAL = 1e-15
# (separation slack per unit size, sin^2 of a negligible edge-cross axis, axis component too small
# to choose a corner, squared relative radius of a duplicate clip vertex): float64, float32
_EPS = {8: (1e-13, 1e-16, 1e-9, 1e-14), 4: (1e-6, 1e-7, 1e-5, 1e-10)}
_CORNER_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))


def _edge_axis(rot, i, j):
    """Unit cross product of box 1's axis ``i`` with box 2's axis ``j``, in box 1's frame, and
    its squared norm before normalising (``i``, ``j`` may be traced)."""
    i1, i2 = (i + 1) % 3, (i + 2) % 3
    axis = jnp.zeros(3, rot.dtype).at[i1].set(-rot[i2, j]).at[i2].set(rot[i1, j])
    norm2 = jnp.sum(axis * axis)
    return axis / jnp.sqrt(jnp.where(norm2 > 0, norm2, 1.0)), norm2


def _separation(rot, pos21, pos12, size1, size2, septol, pareps):
    """The winning axis code (0-2 box 1's faces, 3-5 box 2's, 6 + 3i + j the edge pair), its
    separation, the best face code and separation, and whether any axis separates the boxes."""
    rotabs = jnp.abs(rot)
    faces = jnp.concatenate(
        [jnp.abs(pos21) - size1 - rotabs @ size2, jnp.abs(pos12) - size2 - rotabs.T @ size1]
    )
    code = jnp.argmax(faces)
    sep_face = faces[code]
    code_face, separated = code, jnp.any(faces > septol)

    def edge(carry, ij):
        best, code, separated = carry
        i, j = ij // 3, ij % 3
        axis, norm2 = _edge_axis(rot, i, j)
        i1, i2, j1, j2 = (i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3
        radius1 = size1[i1] * jnp.abs(axis[i1]) + size1[i2] * jnp.abs(axis[i2])
        in2 = rot.T @ axis
        radius2 = size2[j1] * jnp.abs(in2[j1]) + size2[j2] * jnp.abs(in2[j2])
        sep = jnp.abs(axis @ pos21) - radius1 - radius2
        usable = norm2 >= pareps
        separated = separated | (usable & (sep > septol))
        wins = usable & (sep - _EDGE_BIAS * jnp.abs(sep) > best) & (sep > sep_face)
        return (jnp.where(wins, sep, best), jnp.where(wins, 6 + ij, code), separated), None

    # A loop, not nine unrolled steps: XLA:CPU fused the unrolled chain of running maxima into
    # each of its readers, recomputing the axis tests ~20 times (box_box 2.2x slower, vmapped)
    (best, code, separated), _ = jax.lax.scan(edge, (sep_face, code, separated), jnp.arange(9))
    # An edge axis within ~8 degrees of the best face axis gives way to it unless 5% better.
    axis, _ = _edge_axis(rot, jnp.maximum(code - 6, 0) // 3, jnp.maximum(code - 6, 0) % 3)
    face_axis = jnp.where(code_face < 3, jnp.eye(3, dtype=rot.dtype)[code_face % 3], rot[:, code_face % 3])
    aliased = (jnp.abs(axis @ face_axis) > 0.99) & (best < sep_face + 0.05 * jnp.abs(sep_face) + _MINVAL)
    code = jnp.where((code >= 6) & aliased, code_face, code)
    return code, separated


def _edge_contact(rot, pos21, size1, size2, code, sgneps):
    """The edge-edge contact of axis ``code`` (box 1's frame): distance, midpoint and axis."""
    i, j = jnp.maximum(code - 6, 0) // 3, jnp.maximum(code - 6, 0) % 3
    i1, i2, j1, j2 = (i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3
    axis, _ = _edge_axis(rot, i, j)
    axis = jnp.where(axis @ pos21 < 0, -axis, axis)
    a2 = rot.T @ axis
    # At most one ambiguous corner sign per box: both choices are tried.
    amb1 = jnp.where(jnp.abs(axis[i1]) < sgneps, i1, jnp.where(jnp.abs(axis[i2]) < sgneps, i2, -1))
    amb2 = jnp.where(jnp.abs(a2[j1]) < sgneps, j1, jnp.where(jnp.abs(a2[j2]) < sgneps, j2, -1))
    d2 = rot[:, j]
    b = d2[i]
    denom = 1.0 - b * b
    zero = jnp.zeros(3, rot.dtype)
    corner1 = zero.at[i1].set(jnp.where(axis[i1] >= 0, size1[i1], -size1[i1]))
    corner1 = corner1.at[i2].set(jnp.where(axis[i2] >= 0, size1[i2], -size1[i2]))
    corner2 = zero.at[j1].set(jnp.where(a2[j1] >= 0, -size2[j1], size2[j1]))
    corner2 = corner2.at[j2].set(jnp.where(a2[j2] >= 0, -size2[j2], size2[j2]))
    best, w1, w2 = jnp.inf, zero, zero
    for flip1 in (False, True):
        for flip2 in (False, True):
            c1 = corner1.at[jnp.maximum(amb1, 0)].multiply(-1.0) if flip1 else corner1
            cc = corner2.at[jnp.maximum(amb2, 0)].multiply(-1.0) if flip2 else corner2
            c2 = rot @ cc + pos21
            e = c2 - c1
            d1e, d2e = e[i], d2 @ e
            s = jnp.where(denom < _MINVAL, 0.0, (d1e - b * d2e) / jnp.where(denom < _MINVAL, 1.0, denom))
            s = jnp.clip(s, -size1[i], size1[i])
            t = jnp.clip(b * s - d2e, -size2[j], size2[j])
            s = jnp.clip(d1e + b * t, -size1[i], size1[i])
            p1, p2 = c1.at[i].add(s), c2 + t * d2
            gap2 = jnp.sum((p2 - p1) ** 2)
            take = (gap2 < best) & (amb1 >= 0 if flip1 else True) & (amb2 >= 0 if flip2 else True)
            best = jnp.where(take, gap2, best)
            w1, w2 = jnp.where(take, p1, w1), jnp.where(take, p2, w2)
    return (w2 - w1) @ axis, 0.5 * (w1 + w2), axis


def _clip(poly, count, coord, sign, limit):
    """Sutherland-Hodgman: the first ``count`` vertices of ``poly`` (N, 3) clipped to
    ``sign * v[coord] <= limit``, compacted into a new (N, 3) buffer, and its count."""
    n = poly.shape[0]
    k = jnp.arange(n)
    valid = k < count
    d = sign * poly[:, coord] - limit
    nxt = jnp.where(k + 1 < count, k + 1, 0)
    dq = d[nxt]
    t = d / jnp.where(d != dq, d - dq, 1.0)
    cross = poly + t[:, None] * (poly[nxt] - poly)
    keep = valid & (d <= 0)
    crossing = valid & (((d < 0) & (dq > 0)) | ((d > 0) & (dq < 0)))
    cand = jnp.stack([poly, cross], 1).reshape(2 * n, 3)
    emit = jnp.stack([keep, crossing], 1).reshape(2 * n)
    slot = jnp.where(emit, jnp.cumsum(emit) - 1, 2 * n)
    out = jnp.zeros((n, 3), poly.dtype).at[slot].set(cand, mode="drop")
    return out, jnp.minimum(jnp.sum(emit), n)


def _face_contacts(rot, pos21, pos12, size1, size2, code, margin, dupeps):
    """The face manifold of face axis ``code`` (0-5): ``CONTACTS`` candidates in the reference
    box's frame (distance, position) with the reference box, its face axis and side."""
    ref1 = code < 3
    a = jnp.where(ref1, code, code - 3) % 3
    sizeref, sizeinc = jnp.where(ref1, size1, size2), jnp.where(ref1, size2, size1)
    posoi = jnp.where(ref1, pos21, pos12)  # the incident box's centre, reference frame
    rinc = jnp.where(ref1, rot, rot.T)  # the incident box's axes (columns), reference frame
    sgn = jnp.where(posoi[a] >= 0, 1.0, -1.0)
    binc = jnp.argmax(jnp.abs(rinc[a]))
    tinc = jnp.where(sgn * rinc[a, binc] > 0, -1.0, 1.0)
    ax, ay = (a + 1) % 3, (a + 2) % 3
    bu, bv = (binc + 1) % 3, (binc + 2) % 3
    rows = jnp.stack([ax, ay, a])
    centre = posoi[rows] + tinc * sizeinc[binc] * rinc[rows, binc]
    du, dv = sizeinc[bu] * rinc[rows, bu], sizeinc[bv] * rinc[rows, bv]
    side = jnp.array([1.0, 1.0, 0.0], rot.dtype) + sgn * jnp.array([0.0, 0.0, 1.0], rot.dtype)
    centre = centre * side - jnp.zeros(3, rot.dtype).at[2].set(sizeref[a])
    du, dv = du * side, dv * side
    signs = jnp.asarray(_CORNER_SIGNS, rot.dtype)
    poly = jnp.zeros((CONTACTS, 3), rot.dtype).at[:4].set(centre + signs[:, :1] * du + signs[:, 1:] * dv)
    count = jnp.asarray(4)
    for coord, sign, limit in (
        (0, 1.0, sizeref[ax]),
        (0, -1.0, sizeref[ax]),
        (1, 1.0, sizeref[ay]),
        (1, -1.0, sizeref[ay]),
    ):
        poly, count = _clip(poly, count, coord, sign, limit)
    dupe2 = dupeps * (sizeref[ax] ** 2 + sizeref[ay] ** 2)
    accepted = []
    for k in range(CONTACTS):
        ok = (k < count) & (poly[k, 2] <= margin)
        for q in range(k):
            ok = ok & ~(accepted[q] & (jnp.sum((poly[q, :2] - poly[k, :2]) ** 2) < dupe2))
        accepted.append(ok)
    # Midway between the reference plane and the incident vertex, along the face axis.
    local = jnp.zeros((CONTACTS, 3), rot.dtype).at[:, ax].set(poly[:, 0]).at[:, ay].set(poly[:, 1])
    local = local.at[:, a].set(sgn * (sizeref[a] + 0.5 * poly[:, 2]))
    return jnp.where(jnp.stack(accepted), poly[:, 2], _FAR), local, ref1, a, sgn


def box_box(pos1, mat1, size1, pos2, mat2, size2, margin):
    """Up to ``CONTACTS`` contacts of two boxes (see module doc): dist, pos, normal, tangent."""
    sepeps, pareps, sgneps, dupeps = _EPS[size1.dtype.itemsize]
    rot = mat1.T @ mat2  # box 2's axes (columns) in box 1's frame
    pos21, pos12 = mat1.T @ (pos2 - pos1), mat2.T @ (pos1 - pos2)
    septol = margin + sepeps * (jnp.sum(size1) + jnp.sum(size2))
    code, separated = _separation(rot, pos21, pos12, size1, size2, septol, pareps)
    edge = code >= 6
    e_dist, e_mid, e_axis = _edge_contact(rot, pos21, size1, size2, code, sgneps)
    f_dist, f_local, ref1, a, sgn = _face_contacts(
        rot, pos21, pos12, size1, size2, jnp.minimum(code, 5), margin, dupeps
    )
    matref, posref = jnp.where(ref1, mat1, mat2), jnp.where(ref1, pos1, pos2)
    f_pos = posref + f_local @ matref.T
    f_normal = jnp.where(ref1, sgn, -sgn) * matref[:, a]
    e_dist = jnp.where(e_dist > septol, _FAR, e_dist)
    first = jnp.arange(CONTACTS) == 0
    dist = jnp.where(edge, jnp.where(first, e_dist, _FAR), f_dist)
    dist = jnp.where(separated, _FAR, dist)
    pos = jnp.where(edge, pos1 + mat1 @ e_mid, f_pos)
    normal = jnp.broadcast_to(jnp.where(edge, mat1 @ e_axis, f_normal), (CONTACTS, 3))
    return dist, pos, normal, jnp.zeros((CONTACTS, 3), pos1.dtype)
