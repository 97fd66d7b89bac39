"""MuJoCo's multi-contact for boxes and meshes in penetration (its ``multicontact``): after EPA,
the touching features are read off EPA's final face and clipped against each other.

Each of EPA's three final points is a pair of vertices, one on each geom; the distinct vertices on
a geom (one, two or three) name the feature it touches with: a vertex, an edge or a face. The
hull polygons (box faces) around that feature are the candidate faces. If a face of one geom
turns to a face of the other (normals opposed within ``FACE_TOL``), the second face is clipped
by the first's side planes (Sutherland-Hodgman); otherwise, where one geom touches with an edge
lying in a face of the other (within ``EDGE_TOL``), that edge is clipped instead. The clipped
points below the clipping face are the contacts (at most four: the largest quadrilateral of
them, as MuJoCo's ``polygonQuad`` searches it; an edge keeps its two farthest points). Where no
faces line up, EPA's single contact stands.

Everything runs in fixed buffers sized by the largest hull polygon, without branches; the two
walks MuJoCo's code takes with data-dependent loops (the clip over the face's edges, the
quadrilateral search) are a ``fori_loop`` over the largest face and a ``while_loop`` of single
search steps.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import collision_gjk as gjk
from fastrl.physics.collision_primitive import _FAR
from fastrl.physics.types import GeomType

CONTACTS = 4
FACE_TOL = 0.996  # two face normals oppose when their dot product is below -FACE_TOL
EDGE_TOL = 0.0888  # an edge lies in a face when |edge . normal| is below this
_MINVAL = 1e-15
_BOX_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
# Each box face's corners (as multiples of the half sizes), in MuJoCo's order.
_BOX_FACES = np.array([
    [[1, 1, 1], [1, 1, -1], [1, -1, -1], [1, -1, 1]],
    [[-1, 1, -1], [-1, 1, 1], [-1, -1, 1], [-1, -1, -1]],
    [[-1, 1, -1], [1, 1, -1], [1, 1, 1], [-1, 1, 1]],
    [[-1, -1, 1], [1, -1, 1], [1, -1, -1], [-1, -1, -1]],
    [[-1, 1, 1], [1, 1, 1], [1, -1, 1], [-1, -1, 1]],
    [[1, 1, -1], [-1, 1, -1], [-1, -1, -1], [1, -1, -1]],
], np.float64)  # fmt: skip


def _unit(v):
    n = jnp.linalg.norm(v, axis=-1, keepdims=True)
    return v / jnp.where(n > _MINVAL, n, 1.0)


def _first(mask):
    """Index of the first True of a flat mask, and whether there is one."""
    return jnp.argmax(mask), jnp.any(mask)


def _feature(ids, points):
    """MuJoCo's ``simplexDim``: how many distinct vertices EPA's face touches on one geom (1-3),
    with the ids and points reordered so that the distinct ones come first."""
    same01, same02, same12 = ids[0] == ids[1], ids[0] == ids[2], ids[1] == ids[2]
    dim = jnp.where(same01, jnp.where(same02, 1, 2), jnp.where(same02 | same12, 2, 3))
    shift = same01 & ~same02  # the second distinct vertex is the third
    ids = jnp.where(shift, ids.at[1].set(ids[2]), ids)
    points = jnp.where(shift, points.at[1].set(points[2]), points)
    return dim, ids, points


def _box_normals(mat, dim, ids, direction):
    """MuJoCo's ``boxNormals``: candidate faces (3 slots: world normals, face ids, valid)."""
    bits = (ids[:, None] & jnp.array([1, 2, 4])) > 0  # (3 corners, 3 axes): on the + side
    count = jnp.array([1, 2, 3])[dim - 1]
    used = jnp.arange(3) < count
    plus = jnp.all(bits | ~used[:, None], axis=0)
    minus = jnp.all(~bits | ~used[:, None], axis=0)
    sign = plus.astype(mat.dtype) - minus.astype(mat.dtype)  # (3,) per axis: +1, -1 or 0
    axes_face = jnp.array([0, 2, 4]) + (sign < 0)
    eye = jnp.eye(3, dtype=mat.dtype)
    nonzero = sign != 0
    # dim 1: the three faces at the corner; dim 2: the two shared by the edge; dim 3: the one face.
    order = jnp.argsort(~nonzero, stable=True)  # the nonzero axes first, in x, y, z order
    normals = (mat @ (eye * sign[None, :]))[:, order].T  # (3, 3): row k the k-th nonzero axis
    faces = axes_face[order]
    n_nonzero = jnp.sum(nonzero)
    expected = jnp.array([3, 2, 1])[dim - 1]
    valid = (jnp.arange(3) < n_nonzero) & (n_nonzero == expected)
    # Otherwise (an edge or face that is not one of the box's): the face closest to ``direction``.
    local = mat.T @ direction
    local = local / jnp.sqrt(jnp.maximum(local @ local, 1e-300))
    near, found = _first(jnp.asarray(_BOX_NORMALS, mat.dtype) @ local > FACE_TOL)
    fallback = n_nonzero != expected
    normals = jnp.where(
        fallback, jnp.zeros_like(normals).at[0].set(mat @ jnp.asarray(_BOX_NORMALS, mat.dtype)[near]), normals
    )
    faces = jnp.where(fallback, jnp.zeros_like(faces).at[0].set(near), faces)
    valid = jnp.where(fallback, (jnp.arange(3) == 0) & found, valid)
    return normals, faces, valid


def _common(row, other):
    """Entries of ``row`` (-1 padded) also in ``other``, in ``row``'s order: a mask."""
    return (row >= 0) & jnp.any((row[:, None] == other[None, :]) & (other[None, :] >= 0), axis=1)


def _mesh_normals(mat, mesh, tables, dim, ids):
    """MuJoCo's ``meshNormals``: candidate polygons (M slots) of the feature ``ids``."""
    _, vadr, padr = mesh
    polymap, _, polynormal = tables
    rows = polymap[vadr + ids]  # (3, M) each vertex's polygons (mesh-local ids)
    one = rows[0] >= 0
    two = _common(rows[0], rows[1])
    two = two & (jnp.cumsum(two) <= 2)  # the first two shared polygons: the edge's
    three = two & _common(rows[0], rows[2])
    three = three & (jnp.cumsum(three) <= 1)
    mask = jnp.where(dim == 1, one, jnp.where(dim == 2, two, three))
    slot = jnp.argsort(~mask, stable=True)  # the chosen polygons first, in order
    faces = jnp.where(mask[slot], rows[0][slot], 0)
    return polynormal[padr + faces] @ mat.T, faces, mask[slot]


def _box_edges(pos, mat, size, dim, ids, points):
    """MuJoCo's ``boxEdgeNormals``: edges from the touching corner (3 slots)."""
    corner = jnp.where((ids[0] & jnp.array([1, 2, 4])) > 0, size, -size)
    ends = pos + (corner[None, :] * (1.0 - 2.0 * jnp.eye(3, dtype=size.dtype))) @ mat.T
    ends = jnp.where(dim == 2, jnp.zeros_like(ends).at[0].set(points[1]), ends)
    valid = jnp.where(dim == 2, jnp.arange(3) == 0, jnp.full(3, dim == 1))
    return _unit(ends - points[0]), ends, valid


def _mesh_edges(pos, mat, mesh, tables, dim, ids, points):
    """MuJoCo's ``meshEdgeNormals``: from the touching vertex, along each of its polygons to the
    vertex before it (M slots); or the one edge EPA touched."""
    verts, vadr, padr = mesh
    polymap, polyvert, _ = tables
    polys = polymap[vadr + ids[0]]  # (M,)
    ring = polyvert[padr + jnp.maximum(polys, 0)]  # (M, K)
    count = jnp.sum(ring >= 0, axis=1)
    at = jnp.argmax(ring == ids[0], axis=1)
    before = ring[jnp.arange(ring.shape[0]), jnp.where(at == 0, count - 1, at - 1)]
    ends = pos + verts[jnp.maximum(before, 0)] @ mat.T
    ends = jnp.where(dim == 2, jnp.zeros_like(ends).at[0].set(points[1]), ends)
    valid = jnp.where(dim == 2, jnp.arange(polys.shape[0]) == 0, (polys >= 0) & (dim == 1))
    return _unit(ends - points[0]), ends, valid


def _box_face(pos, mat, size, face, width):
    corners = pos + (jnp.asarray(_BOX_FACES, size.dtype)[face] * size) @ mat.T
    return jnp.zeros((width, 3), size.dtype).at[:4].set(corners), jnp.asarray(4)


def _mesh_face(pos, mat, mesh, tables, face, width):
    """A hull polygon's corners in world coordinates, in reverse of their stored order."""
    verts, _, padr = mesh
    ring = tables[1][padr + face]
    count = jnp.sum(ring >= 0)
    k = jnp.arange(ring.shape[0])
    ids = ring[jnp.where(k < count, count - 1 - k, 0)]
    corners = pos + verts[jnp.maximum(ids, 0)] @ mat.T
    out = jnp.zeros((width, 3), corners.dtype).at[: corners.shape[0]].set(corners)
    return out, count


def _clip(face, nface, poly, npoly, normal):
    """MuJoCo's ``polygonClip`` walk: ``poly`` clipped by each edge's side plane of ``face``, then
    the points on or below ``face`` kept; compacted, with their count."""
    width = poly.shape[0]
    nxt = lambda i, n: jnp.where(i + 1 < n, i + 1, 0)  # noqa: E731
    k = jnp.arange(width)

    def edge(e, state):
        poly, npoly = state
        a, b = face[e], face[nxt(e, nface)]
        pn = _unit(jnp.cross(b - a, normal))
        pd = pn @ a
        p, q = poly, poly[nxt(k, npoly)]
        in1 = (p - a) @ pn > -_MINVAL
        in2 = (q - a) @ pn > -_MINVAL
        live = k < npoly
        pq = q - p
        tmp = pq @ pn
        t = (pd - p @ pn) / jnp.where(tmp != 0, tmp, 1.0)
        cross = (in1 != in2) & (tmp != 0) & (t >= 0) & (t <= 1)
        first = jnp.where((in1 & in2)[:, None], q, p + t[:, None] * pq)
        emit1 = live & ((in1 & in2) | cross)
        emit2 = live & (in1 != in2) & in2
        cand = jnp.stack([first, q], 1).reshape(2 * width, 3)
        emit = jnp.stack([emit1, emit2], 1).reshape(2 * width)
        slot = jnp.where(emit, jnp.cumsum(emit) - 1, 2 * width)
        out = jnp.zeros_like(poly).at[slot].set(cand, mode="drop")
        new = (out, jnp.minimum(jnp.sum(emit), width))
        return jax.tree.map(lambda x, y: jnp.where(e < nface, x, y), new, state)

    poly, npoly = jax.lax.fori_loop(0, face.shape[0], edge, (poly, npoly))
    below = (k < npoly) & ((poly - face[0]) @ normal <= 0)
    slot = jnp.where(below, jnp.cumsum(below) - 1, width)
    return jnp.zeros_like(poly).at[slot].set(poly, mode="drop"), jnp.sum(below)


def _area4(a, b, c, d):
    """``polygonQuad``'s measure of the quadrilateral abcd."""
    return 0.5 * jnp.linalg.norm(jnp.cross(d - a, b - d) + jnp.cross(c - b, a - c))


def _diagonals(a, b, c, d):
    """``mjc_PlaneConvex``'s: half the cross product of the diagonals."""
    return 0.5 * jnp.linalg.norm(jnp.cross(a - c, b - d))


def quad(poly, n, first=None):
    """A large-area quadrilateral of the convex polygon's ``n`` points (4 ids), by MuJoCo's walk:
    from a first corner, advance the last, third and second corners while the area grows
    (``polygonQuad`` tries every first corner, for more than four points; with ``first`` given,
    ``mjc_PlaneConvex`` keeps that one and walks once, ``(first, first+1, ...)`` when ``n <= 4``).
    Each measures the area its own way. One walk step per ``while_loop`` pass."""
    nxt = lambda i: jnp.where(i + 1 < n, i + 1, 0)  # noqa: E731
    measure = _area4 if first is None else _diagonals
    area = lambda a, b, c, d: measure(poly[a], poly[b], poly[c], poly[d])  # noqa: E731
    if first is None:
        a0, corners = jnp.where(n > 4, 0, n), jnp.arange(4)
    else:
        a0, corners = jnp.asarray(first), (first + jnp.arange(4)) % jnp.maximum(n, 1)
    # state: a, b, c, d, best area, phase (0 advance d, 1 advance c, 2 advance b), result, stop
    start = (a0, corners[1], corners[2], corners[3], area(*corners), jnp.asarray(0), corners, n <= 4)

    def step(s):
        a, b, c, d, m, phase, res, _ = s
        trial = jnp.where(
            phase == 0,
            area(a, b, c, nxt(d)),
            jnp.where(phase == 1, area(a, b, nxt(c), d), area(a, nxt(b), c, d)),
        )
        grows = trial > m
        d2 = jnp.where(grows & (phase == 0), nxt(d), d)
        c2 = jnp.where(grows & (phase == 1), nxt(c), c)
        b2 = jnp.where(grows & (phase == 2), nxt(b), b)
        res2 = jnp.where(grows, jnp.stack([a, b2, c2, d2]), res)
        m2 = jnp.where(grows, trial, m)
        # d grew: try c; c stopped: try b; b stopped: try d again; d stopped: next first corner
        phase2 = jnp.where(phase == 0, jnp.where(grows, 1, 0), jnp.where(grows, phase, (phase + 1) % 3))
        done_a = (phase == 0) & ~grows
        if first is not None:  # one walk from the given corner
            return (a, b2, c2, d2, m2, phase2, res2, done_a)
        # the first corner moves on, pushing the others off it
        b3 = jnp.where(done_a & (b2 == a), nxt(b2), b2)
        c3 = jnp.where(done_a & (b2 == a) & (c2 == b3), nxt(c2), c2)
        d3 = jnp.where(done_a & (b2 == a) & (c2 == b3) & (d2 == c3), nxt(d2), d2)
        a3 = jnp.where(done_a, a + 1, a)
        return (a3, b3, c3, d3, m2, phase2, res2, a3 >= n)

    return jax.lax.while_loop(lambda s: ~s[-1], step, start)[-2]


def _contacts(face, nface, poly, npoly, normal, direction, edge_subject):
    """The clipped points as contacts: (4,) dists, witness points on the clipping face's plane
    and level with the clipped points, and how many (MuJoCo's choice of at most four)."""
    poly, n = _clip(face, nface, poly, npoly, normal)
    # more than four: the quadrilateral; an edge: its two farthest points; else all of them
    corners = quad(poly, n)
    # the farthest pair is only used for 2 < n <= 4 points, so only the first four are compared
    # (comparing all would hold a width x width table per pair, 30 GB for a batch of 1024 Alohas)
    head = poly[:4]
    diff = head[:, None, :] - head[None, :, :]
    d2 = jnp.sum(diff * diff, -1)
    k = jnp.arange(4)
    pairs = (k[:, None] < k[None, :]) & (k[None, :] < n)
    flat = jnp.argmax(jnp.where(pairs, d2, -1.0).reshape(-1))
    far = jnp.array([flat // 4, flat % 4, 0, 0])
    far = jnp.where(jnp.max(jnp.where(pairs, d2, -1.0)) > 0, far, jnp.array([0, 1, 0, 0]))
    pick = jnp.where(n > 4, corners, jnp.where(edge_subject & (n > 2), far, jnp.arange(4)))
    count = jnp.where(n > 4, 4, jnp.where(edge_subject & (n > 2), 2, jnp.minimum(n, 4)))
    v = poly[pick]
    # MuJoCo 4.0's witnesses: the point's foot on the clipping face's plane, and from there along
    # ``direction`` level with the point; the distance between them (negative: penetration).
    foot = v - ((v - face[0]) @ normal)[:, None] * normal
    t = (v - foot) @ direction
    return -t, foot, foot + t[:, None] * direction, count


def _normals(t, pos, mat, size, mesh, tables, dim, ids, direction):
    if t == GeomType.BOX:
        return _box_normals(mat, dim, ids, direction)
    return _mesh_normals(mat, mesh, tables, dim, ids)


def _edges(t, pos, mat, size, mesh, tables, dim, ids, points):
    if t == GeomType.BOX:
        return _box_edges(pos, mat, size, dim, ids, points)
    return _mesh_edges(pos, mat, mesh, tables, dim, ids, points)


def _face(t, pos, mat, size, mesh, tables, face, width):
    if t == GeomType.BOX:
        return _box_face(pos, mat, size, face, width)
    return _mesh_face(pos, mat, mesh, tables, face, width)


def faces_pair(type1: int, type2: int):
    """Collision of a box or mesh with a mesh (box-box has its own primitive): EPA's contact and
    MuJoCo's face-clipping multi-contact (see module doc), ``CONTACTS`` candidates. For pairs
    whose margin is zero (MuJoCo searches others by perturbation: ``collision_ccd.convex_pair``).

    Signature as the driver's shaped functions: poses and sizes, each geom's hull (its vertices
    and where its rows start in ``Model.mesh_polymap`` and ``mesh_polyvert``), the margin and the
    smaller bounding radius; keyword ``tables``: those two tables and ``mesh_polynormal``, shared
    by every pair."""
    if not {type1, type2} <= {GeomType.BOX, GeomType.MESH}:
        raise ValueError("face clipping is for boxes and meshes")

    def collide(pos1, mat1, size1, pos2, mat2, size2, mesh1, mesh2, margin, rbound, *, tables):
        del margin, rbound  # zero margin only; no perturbation
        return clipped(pos1, mat1, size1, pos2, mat2, size2, mesh1, mesh2, tables)

    @gjk.stops_when_done
    def clipped(loop):
        return lambda *args: _clipped_contacts(type1, type2, *args, loop=loop)

    return collide


def _single(type1: int, type2: int, pos1, mat1, size1, pos2, mat2, size2, mesh1, mesh2, loop):
    """GJK and EPA on one pair: whether it is apart, its single contact ``(dist, pos, normal)``,
    the contact's points on geom 1 and on geom 2 (3,), and EPA's final face (``gjk.epa``)."""
    support1 = lambda d: gjk.support_vertex(type1, pos1, mat1, size1, mesh1[0], d)  # noqa: E731
    support2 = lambda d: gjk.support_vertex(type2, pos2, mat2, size2, mesh2[0], d)  # noqa: E731
    dist, w1, w2, simplex, _ = gjk.gjk(support1, support2, pos1 - pos2, gjk.GJK_ITERATIONS, loop)
    apart = dist > 0
    depth, n_deep, d1, d2, face = gjk.epa(support1, support2, simplex, gjk.EPA_ITERATIONS, apart, loop)
    gap = w2 - w1
    normal = jnp.where(apart, gap / jnp.where(apart, gjk.nonzero_norm(gap, 0.0)[0], 1.0), n_deep)
    x1, x2 = jnp.where(apart, w1, d1), jnp.where(apart, w2, d2)
    return apart, (jnp.where(apart, dist, -depth), 0.5 * (x1 + x2), normal), x1, x2, face


def _clipped_contacts(type1, type2, pos1, mat1, size1, pos2, mat2, size2, mesh1, mesh2, tables, loop):
    """``faces_pair``'s ``CONTACTS`` candidates of one pair (its arguments, GJK's and EPA's
    ``loop``): EPA's contact, or where the cores overlap and a face of one geom turns to a face
    of the other, or an edge lies in one, the contacts clipped from them (see module doc)."""
    geoms = (pos1, mat1, size1, pos2, mat2, size2, mesh1, mesh2)
    apart, single, x1, x2, (va, vb, ia, ib) = _single(type1, type2, *geoms, loop)
    width = max(4, tables[1].shape[1])
    dim1, ids1, pts1 = _feature(ia, va)
    dim2, ids2, pts2 = _feature(ib, vb)

    g1 = (type1, pos1, mat1, size1, mesh1, tables)
    g2 = (type2, pos2, mat2, size2, mesh2, tables)
    n1, f1, ok1 = _normals(*g1, dim1, ids1, x1 - x2)
    n2, f2, ok2 = _normals(*g2, dim2, ids2, x2 - x1)
    # faces facing each other: the first (i, j) in MuJoCo's order
    facing = (n1 @ n2.T < -FACE_TOL) & ok1[:, None] & ok2[None, :]
    ff, aligned = _first(facing.reshape(-1))
    fi, fj = ff // n2.shape[0], ff % n2.shape[0]
    # else an edge of the geom touching with fewer vertices lying in a face of the other
    e1, end1, eok1 = _edges(*g1, dim1, ids1, pts1)
    e2, end2, eok2 = _edges(*g2, dim2, ids2, pts2)
    try1 = ~aligned & (dim1 < 3) & (dim1 <= dim2)
    try2 = ~aligned & ~try1 & (dim2 < 3)
    lie1 = (jnp.abs(n2 @ e1.T) < EDGE_TOL) & ok2[:, None] & eok1[None, :]  # (faces of 2, edges of 1)
    lie2 = (jnp.abs(n1 @ e2.T) < EDGE_TOL) & ok1[:, None] & eok2[None, :]
    fe1, found1 = _first(lie1.reshape(-1))
    fe2, found2 = _first(lie2.reshape(-1))
    edge1, edge2 = try1 & found1, try2 & found2
    # the clipping face (a face), the clipped polygon (a face or an edge), normal, direction
    face_a1 = _face(*g1, f1[jnp.where(edge2, fe2 // e2.shape[0], fi)], width)
    face_a2 = _face(*g2, f2[jnp.where(edge1, fe1 // e1.shape[0], fj)], width)
    seg1 = jnp.zeros((width, 3), pos1.dtype).at[0].set(pts1[0]).at[1].set(end1[fe1 % e1.shape[0]])
    seg2 = jnp.zeros((width, 3), pos1.dtype).at[0].set(pts2[0]).at[1].set(end2[fe2 % e2.shape[0]])
    na, nb = n1[jnp.where(edge2, fe2 // e2.shape[0], fi)], n2[jnp.where(edge1, fe1 // e1.shape[0], fj)]
    face, nface = (jnp.where(edge1, a2, a1) for a1, a2 in zip(face_a1, face_a2, strict=True))
    poly = jnp.where(edge1, seg1, jnp.where(edge2, seg2, face_a2[0]))
    poly = jnp.concatenate([poly, jnp.zeros_like(poly)])  # clipping can add a point per edge
    npoly = jnp.where(edge1 | edge2, 2, face_a2[1])
    plane = jnp.where(edge1, nb, na)
    direction = jnp.where(edge1, -nb, jnp.where(edge2, -na, nb))
    dist, wa, wb, count = _contacts(face, nface, poly, npoly, plane, direction, edge1 | edge2)
    xa, xb = jnp.where(edge1, wb, wa), jnp.where(edge1, wa, wb)  # geom 1's, geom 2's
    multi = ~apart & (aligned | edge1 | edge2) & (count > 0)
    slots = jnp.arange(CONTACTS)
    dists = jnp.where(multi, jnp.where(slots < count, dist, _FAR), jnp.where(slots == 0, single[0], _FAR))
    poss = jnp.where(multi, 0.5 * (xa + xb), jnp.broadcast_to(single[1], (CONTACTS, 3)))
    normals_out = jnp.where(multi, _unit(xa - xb), jnp.broadcast_to(single[2], (CONTACTS, 3)))
    return dists, poss, normals_out, jnp.zeros((CONTACTS, 3), pos1.dtype)
