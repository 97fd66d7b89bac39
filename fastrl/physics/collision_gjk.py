"""GJK and EPA for any two convex geoms, written for a fixed number of iterations (no branches).

Shapes are described by support functions (``support``): the point of the shape farthest along a
direction. GJK walks a simplex of at most four points of the Minkowski difference ``A - B`` towards
the origin; its closest point gives the distance and the witness points. Each step finds the
simplex's closest point by trying all fifteen of its faces (vertices, edges, triangles and the
tetrahedron) as small constrained least-squares problems and keeping the nearest whose barycentric
weights are all non-negative: no case analysis, the same work every step. If the origin ends up
inside, the shapes overlap and EPA expands a polytope inside ``A - B`` towards its boundary to find
the penetration depth and direction.

As in MuJoCo (``mjc_ccd``), spheres and capsules collide by their core (centre point, axis segment)
and are inflated by their radius afterwards; they go through EPA only when the cores overlap.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics.collision_primitive import _FAR
from fastrl.physics.math import dot
from fastrl.physics.types import GeomType

# The simplex's fifteen faces: as masks over its four slots, and as their slots (padded with the
# first) with their point counts.
_COMBOS = [c for k in range(1, 5) for c in itertools.combinations(range(4), k)]
_FACES = np.array([np.isin(range(4), c) for c in _COMBOS])
_FACE_POINTS = np.array([list(c) + [c[0]] * (4 - len(c)) for c in _COMBOS])
_FACE_COUNT = np.array([len(c) for c in _COMBOS])


def support(gtype, pos, mat, size, verts, direction, code=None):
    """The point of geom ``gtype`` (world pose ``pos``, ``mat``) farthest along ``direction``;
    spheres and capsules by their core (radius left out). ``verts``: a mesh's vertices (local).
    ``gtype`` may be a tuple of types, with ``code`` saying which (``support_vertex``)."""
    return support_vertex(gtype, pos, mat, size, verts, direction, code)[0]


def _one_type(gtype, code):
    """``gtype`` as one static type where it is one (an int or a 1-tuple); else ``None``, and
    ``code`` must say which of the tuple each pair's geom is."""
    if not isinstance(gtype, tuple):
        return gtype
    if len(gtype) == 1:
        return gtype[0]
    if code is None:
        raise ValueError(f"geom types {gtype} need a per-pair type code")
    return None


def _pick(types, code, values):
    """Of ``values`` (one per geom type in ``types``), the one for type ``code``: exact values,
    no arithmetic between them."""
    out = values[-1]
    for t, v in zip(types[:-1][::-1], values[:-1][::-1], strict=True):
        out = jax.tree.map(lambda a, b: jnp.where(code == t, a, b), v, out)  # noqa: B023
    return out


def support_vertex(gtype, pos, mat, size, verts, direction, code=None):
    """``support`` and the vertex it is: a mesh's vertex id, a box's corner as MuJoCo numbers
    them (bit 1, 2, 4 set where the corner lies on the +x, +y, +z side), 0 for other geoms.

    ``gtype`` is one geom type, or a tuple of the types a group of pairs holds on this side with
    ``code`` (traced) the geom's own: every type's support is found and the geom's is kept, so
    pairs of several type pairs share one compiled GJK/EPA."""
    one = _one_type(gtype, code)
    local = mat.T @ direction
    if one is None:
        point, index = _pick(gtype, code, [_local_support(t, local, size, verts) for t in gtype])
    else:
        point, index = _local_support(one, local, size, verts)
    return pos + mat @ point, index


def _local_support(gtype: int, local, size, verts):
    """A geom's support point along ``local`` (a direction in its frame), in its frame, and
    its vertex id (``support_vertex``)."""
    index = jnp.zeros((), jnp.int32)
    if gtype == GeomType.SPHERE:
        point = jnp.zeros(3, local.dtype)
    elif gtype == GeomType.CAPSULE:
        point = jnp.array([0.0, 0.0, 1.0], local.dtype) * jnp.where(local[2] >= 0, size[1], -size[1])
    elif gtype == GeomType.BOX:
        point = jnp.where(local >= 0, size, -size)
        index = jnp.sum(jnp.where(local >= 0, jnp.array([1, 2, 4], jnp.int32), 0)).astype(jnp.int32)
    elif gtype == GeomType.CYLINDER:
        radial = local.at[2].set(0.0)
        norm = jnp.linalg.norm(radial)
        radial = jnp.where(norm > 1e-15, radial / jnp.where(norm > 1e-15, norm, 1.0), 0.0) * size[0]
        point = radial.at[2].set(jnp.where(local[2] >= 0, size[1], -size[1]))
    elif gtype == GeomType.ELLIPSOID:
        scaled = size * local
        point = size * scaled / jnp.maximum(jnp.linalg.norm(scaled), 1e-30)
    elif gtype == GeomType.MESH:
        index = jnp.argmax(verts @ local).astype(jnp.int32)
        point = verts[index]
    else:
        raise ValueError(f"no support function for geom type {gtype}")
    return point, index


def core_radius(gtype, size, code=None):
    """The radius GJK leaves out of a sphere or capsule (0 for other geoms); ``gtype`` and
    ``code`` as in ``support_vertex``."""
    one = _one_type(gtype, code)
    if one is None:
        return _pick(gtype, code, [core_radius(t, size) for t in gtype])
    return size[0] if one in (GeomType.SPHERE, GeomType.CAPSULE) else jnp.zeros((), size.dtype)


def _solve3(g, r):
    """Solves the symmetric 3x3 systems ``g x = r`` (batched) by cofactors; ``ok`` where the
    determinant is not zero (a nearly flat face's weights are then checked by the caller)."""
    c00 = g[..., 1, 1] * g[..., 2, 2] - g[..., 1, 2] * g[..., 2, 1]
    c01 = g[..., 1, 2] * g[..., 2, 0] - g[..., 1, 0] * g[..., 2, 2]
    c02 = g[..., 1, 0] * g[..., 2, 1] - g[..., 1, 1] * g[..., 2, 0]
    c11 = g[..., 0, 0] * g[..., 2, 2] - g[..., 0, 2] * g[..., 2, 0]
    c12 = g[..., 0, 1] * g[..., 2, 0] - g[..., 0, 0] * g[..., 2, 1]
    c22 = g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] * g[..., 1, 0]
    adj = jnp.stack(
        [jnp.stack([c00, c01, c02], -1), jnp.stack([c01, c11, c12], -1), jnp.stack([c02, c12, c22], -1)], -2
    )
    det = g[..., 0, 0] * c00 + g[..., 0, 1] * c01 + g[..., 0, 2] * c02
    ok = det != 0
    x = jnp.einsum("...ij,...j->...i", adj, r) / jnp.where(ok, det, 1.0)[..., None]
    return x, ok & jnp.all(jnp.isfinite(x), axis=-1)


def _closest(points, used):
    """Barycentric weights (4,) of the point of the simplex ``points[used]`` nearest the origin.

    Each of the fifteen faces: the origin's projection on its affine hull (a 3x3 system in the
    edge vectors from its first point, unused directions pinned), kept if inside the face."""
    idx, count = jnp.asarray(_FACE_POINTS), jnp.asarray(_FACE_COUNT)
    base = points[idx[:, 0]]  # (15, 3)
    edges = points[idx[:, 1:]] - base[:, None, :]  # (15, 3, 3)
    real = jnp.arange(3)[None, :] < (count - 1)[:, None]  # (15, 3)
    edges = jnp.where(real[..., None], edges, 0.0)
    gram = jnp.einsum("fid,fjd->fij", edges, edges) + jnp.where(real, 0.0, 1.0)[:, :, None] * jnp.eye(
        3, dtype=points.dtype
    )
    mu, ok = _solve3(gram, -jnp.einsum("fid,fd->fi", edges, base))
    mu = jnp.where(real, mu, 0.0)
    lam = jnp.concatenate([1.0 - jnp.sum(mu, -1, keepdims=True), mu], -1)  # (15, 4), by face point
    weights = (
        jnp.zeros((15, 4), points.dtype)
        .at[jnp.arange(15)[:, None], idx]
        .add(jnp.where(jnp.concatenate([jnp.ones((15, 1), bool), real], -1), lam, 0.0))
    )
    inside = jnp.all(weights >= -1e-12, -1) & ok & jnp.all(~jnp.asarray(_FACES) | used, -1)
    point = weights @ points
    dist2 = jnp.where(inside, jnp.sum(point * point, -1), jnp.inf)
    best = jnp.clip(weights[jnp.argmin(dist2)], 0.0, None)
    return best / jnp.sum(best)


def _tolerance(dtype) -> float:
    """GJK's and EPA's relative stopping tolerance: 1e-12 in float64 (the exact contact, to
    rounding); in float32, whose rounding is 1e-7, MuJoCo's default ``ccd_tolerance`` of 1e-6 (at
    1e-12 a seventh of the pairs in a Franka Panda scene never stopped before the iteration cap)."""
    return 1e-12 if jnp.dtype(dtype) == jnp.float64 else 1e-6


def _until_done(iterations: int, step, state: tuple) -> tuple:
    """``fori_loop(0, iterations, step, state)`` for a ``step`` that changes nothing once the last
    entry of its state (``done``) is set: it stops when ``done`` is (under ``vmap``, when every
    element's is), with the same result."""

    def body(carry):
        k, state = carry
        return k + 1, step(k, state)

    def more(carry):
        k, state = carry
        return (k < iterations) & ~state[-1]

    return jax.lax.while_loop(more, body, (jnp.zeros((), jnp.int32), state))[1]


def _fixed(iterations: int, step, state: tuple) -> tuple:
    """``_until_done`` as a loop of fixed count, which reverse-mode differentiation can run."""
    return jax.lax.fori_loop(0, iterations, step, state)


def stops_when_done(make):
    """``make(loop)``'s function (of arrays only) with its GJK/EPA loops stopping when converged
    (``_until_done``), differentiated as ``make(_fixed)``: the same values, from loops that
    reverse-mode differentiation can run (a ``while_loop`` has no transpose)."""
    fast, fixed = jax.custom_jvp(make(_until_done)), make(_fixed)
    fast.defjvp(lambda primals, tangents: jax.jvp(fixed, primals, tangents))
    return fast


def gjk(support_a, support_b, start, iterations: int, loop=_until_done):
    """Distance between shapes A and B (support functions of a world direction) by GJK.

    Returns ``(dist, witness_a, witness_b, simplex, used)``: ``dist`` 0 when the origin lies in
    ``A - B`` (overlap), else the distance between the witness points; the final simplex (points
    of ``A - B``, with their A and B halves and those halves' vertex ids) seeds EPA. Support
    functions return ``(point, vertex id)``.
    """
    dtype = start.dtype
    zero3, zero = jnp.zeros((4, 3), dtype), jnp.zeros(4, jnp.int32)
    (a0, i0), (b0, j0) = support_a(-start), support_b(start)
    first = jnp.array([True, False, False, False])
    state = (zero3.at[0].set(a0 - b0), zero3.at[0].set(a0), zero3.at[0].set(b0), zero.at[0].set(i0),
             zero.at[0].set(j0), first, first.astype(dtype), jnp.array(False))  # fmt: skip

    def step(_, state):
        points, sa, sb, ia, ib, used, weights, done = state
        x = weights @ points
        (a, i), (b, j) = support_a(-x), support_b(x)
        w = a - b
        gap = dot(x, x) - dot(x, w)
        converged = gap <= _tolerance(dtype) * jnp.maximum(dot(x, x), 1e-30)
        done = done | converged | (dot(x, x) < 1e-30) | jnp.all(used)  # all four: origin enclosed
        slot = jnp.argmin(used)  # a free slot (the simplex never holds four while outside)
        new_points = points.at[slot].set(w)
        new_used = used.at[slot].set(True)
        new_weights = _closest(new_points, new_used)
        new_used = new_weights > 0
        # no nearer than before: rounding has made GJK cycle (float32), so it stops where it is
        x_new = new_weights @ new_points
        done = done | ((dot(x_new, x_new) >= dot(x, x)) & ~jnp.all(new_used))
        keep = lambda new, old: jnp.where(done, old, new)  # noqa: E731
        return (keep(new_points, points), keep(sa.at[slot].set(a), sa), keep(sb.at[slot].set(b), sb),
                keep(ia.at[slot].set(i), ia), keep(ib.at[slot].set(j), ib),
                keep(new_used, used), keep(new_weights, weights), done)  # fmt: skip

    points, sa, sb, ia, ib, used, weights, _ = loop(iterations, step, state)
    x = weights @ points
    dist = jnp.linalg.norm(x)
    inside = (jnp.sum(used) == 4) | (dist < 1e-15)
    return jnp.where(inside, 0.0, dist), weights @ sa, weights @ sb, (points, sa, sb, ia, ib), used


def nonzero_norm(x, floor: float):
    """``|x|`` along the last axis (kept), or 1 where it is at most ``floor``: a divisor that
    leaves a degenerate ``x`` as it is, with a finite derivative there too (``jnp.linalg.norm``'s
    is NaN at zero, which a ``where`` downstream does not mask in reverse mode)."""
    sq = jnp.sum(x * x, axis=-1, keepdims=True)
    big = sq > floor * floor
    return jnp.where(big, jnp.sqrt(jnp.where(big, sq, 1.0)), 1.0)


def _face_plane(v, faces):
    """Unit outward normals (F, 3) and origin distances (F,) of triangles ``faces`` of points ``v``."""
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    n = jnp.cross(b - a, c - a)
    n = n / nonzero_norm(n, 1e-30)
    return n, jnp.sum(n * a, axis=-1)


def epa(support_a, support_b, simplex, iterations: int, skip=False, loop=_until_done):
    """Penetration of overlapping shapes from GJK's enclosing tetrahedron: ``(depth, normal,
    witness_a, witness_b, face)``, the normal pointing from A to B (moving B by ``depth * normal``
    separates them); ``face``: the final nearest face's three points on A and on B (3, 3) and
    their vertex ids (3,), for the multi-contact search.

    The polytope lives in fixed buffers: ``4 + iterations`` vertices and ``4 + 3 * iterations``
    face slots, each face with its three neighbours (across each edge). Each step takes the face
    nearest the origin, adds the support point along its normal, drops the faces that point sees
    and closes the hole with a fan of new faces over the horizon (the seen faces' edges whose
    neighbour is unseen), reusing the dropped faces' slots. Every step costs the same, linear in
    the number of faces. ``skip``: GJK found the shapes apart, so there is no penetration to find
    (the outputs are then meaningless) and no step is taken.
    """
    points, sa, sb, sia, sib = simplex
    dtype = points.dtype
    nv, nf = 4 + iterations, 4 + 3 * iterations
    v = jnp.zeros((nv, 3), dtype).at[:4].set(points)
    va = jnp.zeros((nv, 3), dtype).at[:4].set(sa)
    vb = jnp.zeros((nv, 3), dtype).at[:4].set(sb)
    ia = jnp.zeros(nv, jnp.int32).at[:4].set(sia)
    ib = jnp.zeros(nv, jnp.int32).at[:4].set(sib)
    # The tetrahedron, faces outward whichever way its points wind (a mirror image swaps two).
    n0, d0 = _face_plane(points, jnp.asarray([[0, 1, 2]]))
    mirrored = jnp.sum(n0[0] * points[3]) > d0[0]
    tet = jnp.where(mirrored, jnp.asarray(_TET[:, ::-1]), jnp.asarray(_TET)).astype(jnp.int32)
    adj0 = jnp.where(mirrored, jnp.asarray(_TET_ADJ_MIRRORED), jnp.asarray(_TET_ADJ)).astype(jnp.int32)
    faces = jnp.zeros((nf, 3), jnp.int32).at[:4].set(tet)
    adj = jnp.zeros((nf, 3), jnp.int32).at[:4].set(adj0)
    alive = jnp.zeros(nf, bool).at[:4].set(True)
    nxt = jnp.asarray([1, 2, 0])

    def step(k, state):
        v, va, vb, ia, ib, faces, adj, alive, done = state
        n, dist = _face_plane(v, faces)
        best = jnp.argmin(jnp.where(alive, dist, jnp.inf))
        (a, i), (b, j) = support_a(n[best]), support_b(-n[best])
        w = a - b
        done = done | (dot(n[best], w) - dist[best] <= _tolerance(dtype) * (1.0 + dist[best]))
        seen = alive & (jnp.sum(n * (w - v[faces[:, 0]]), axis=-1) > 1e-14)
        seen = seen.at[best].set(True)
        horizon = seen[:, None] & ~seen[adj]  # (nf, 3): edge e of a seen face, its neighbour unseen
        free = ~alive | seen
        slots = jnp.argsort(~free, stable=True)  # free slots first
        flat = horizon.reshape(-1)
        slot = jnp.where(flat, slots[jnp.cumsum(flat) - 1], nf).reshape(nf, 3).astype(jnp.int32)
        start, end = faces, faces[:, nxt]  # each edge's two vertices
        new = (k + 4).astype(jnp.int32)
        first = jnp.full(nv, nf, jnp.int32).at[jnp.where(horizon, start, nv)].set(slot, mode="drop")
        last = jnp.full(nv, nf, jnp.int32).at[jnp.where(horizon, end, nv)].set(slot, mode="drop")
        outside = adj  # the unseen neighbour across each horizon edge
        new_faces = jnp.stack([start, end, jnp.full_like(start, new)], axis=-1)  # (nf, 3, 3)
        new_adj = jnp.stack([outside, first[end], last[start]], axis=-1)
        target = slot.reshape(-1)
        faces2 = faces.at[target].set(new_faces.reshape(-1, 3), mode="drop")
        adj2 = adj.at[target].set(new_adj.reshape(-1, 3), mode="drop")
        # The unseen neighbours now border the new faces.
        back = jnp.argmax(adj[outside] == jnp.arange(nf)[:, None, None], axis=-1)  # (nf, 3)
        rows = jnp.where(horizon, outside, nf).reshape(-1)
        adj2 = adj2.at[rows, back.reshape(-1)].set(target, mode="drop")
        alive2 = (alive & ~seen).at[target].set(True, mode="drop")
        keep = lambda new, old: jnp.where(done, old, new)  # noqa: E731
        return (keep(v.at[new].set(w), v), keep(va.at[new].set(a), va), keep(vb.at[new].set(b), vb),
                keep(ia.at[new].set(i), ia), keep(ib.at[new].set(j), ib),
                keep(faces2, faces), keep(adj2, adj), keep(alive2, alive), done)  # fmt: skip

    state = (v, va, vb, ia, ib, faces, adj, alive, jnp.asarray(skip))
    v, va, vb, ia, ib, faces, _, alive, _ = loop(iterations, step, state)
    n, dist = _face_plane(v, faces)
    best = jnp.argmin(jnp.where(alive, dist, jnp.inf))
    tri = faces[best]
    weights = _triangle_weights(v[tri], dist[best] * n[best])
    face = (va[tri], vb[tri], ia[tri], ib[tri])
    return dist[best], n[best], weights @ va[tri], weights @ vb[tri], face


def _tetrahedron_adjacency(faces: np.ndarray) -> np.ndarray:
    """Neighbour of each face across each edge (edge e runs from vertex e to vertex e+1)."""
    adj = np.zeros((4, 3), np.int64)
    for f in range(4):
        for e in range(3):
            a, b = faces[f, e], faces[f, (e + 1) % 3]
            adj[f, e] = next(g for g in range(4) if g != f and a in faces[g] and b in faces[g])
    return adj


# Faces of the tetrahedron 0123, outward when point 3 lies behind face 012; mirrored: reversed.
_TET = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
_TET_ADJ = _tetrahedron_adjacency(_TET)
_TET_ADJ_MIRRORED = _tetrahedron_adjacency(_TET[:, ::-1])


def _triangle_weights(tri, point):
    """Barycentric weights of ``point`` (in the triangle's plane) in triangle ``tri`` (3, 3)."""
    e1, e2, p = tri[1] - tri[0], tri[2] - tri[0], point - tri[0]
    d11, d12, d22 = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    d1p, d2p = dot(e1, p), dot(e2, p)
    den = d11 * d22 - d12 * d12
    den = jnp.where(jnp.abs(den) > 1e-30, den, 1.0)
    w1 = (d22 * d1p - d12 * d2p) / den
    w2 = (d11 * d2p - d12 * d1p) / den
    return jnp.stack([1.0 - w1 - w2, w1, w2])


GJK_ITERATIONS = 32
# EPA converges in a few steps on polytopes (meshes, boxes, and sphere/capsule cores against them);
# on a curved surface (cylinder, ellipsoid) the depth is flat near its minimum, so the normal needs
# more: at 24 steps 1% of the contacts in tests/physics/test_mesh_hfield.py were 0.07 off in their
# normal, at 64 1% are 3e-4 off and the worst (two cylinders 1 mm apart) 0.024.
EPA_ITERATIONS = 24
EPA_ITERATIONS_CURVED = 64
_CURVED = (GeomType.CYLINDER, GeomType.ELLIPSOID)


# Pairs whose surfaces can meet along a face or an edge get MuJoCo's multi-contact search:
# MULTI_CONTACTS candidates per pair, the first the plain contact.
_FLAT = (GeomType.CAPSULE, GeomType.CYLINDER, GeomType.BOX, GeomType.MESH)
MULTI_CONTACTS = 5
_PERTURBATION = 1e-3  # radians (MuJoCo's multiccd perturbation angle)
_SIN, _COS = float(np.sin(_PERTURBATION)), float(np.cos(_PERTURBATION))
_DISTINCT = 1e-3  # a new contact counts if this far (times the smaller rbound) from the others


def contacts_per_pair(type1: int, type2: int) -> int:
    """Candidate contacts of a GJK/EPA pair: several where both shapes can rest on a face."""
    return MULTI_CONTACTS if type1 in _FLAT and type2 in _FLAT else 1


def _types(gtype) -> tuple[int, ...]:
    return gtype if isinstance(gtype, tuple) else (gtype,)


def program(type1: int, type2: int) -> tuple[int, int]:
    """What a pair's compiled GJK/EPA depends on beyond its geoms' types: EPA's iterations and
    the candidate contacts. Pairs of several type pairs with the same ``program`` can share one
    (``support_vertex`` with a type code)."""
    curved = {type1, type2} & set(_CURVED)
    return (EPA_ITERATIONS_CURVED if curved else EPA_ITERATIONS), contacts_per_pair(type1, type2)


def _program(types1, types2, shared) -> tuple[int, int]:
    """The ``program`` of a pair of single types, or ``shared``: the one the type pairs of a
    mixed group (tuples of types, ``support_vertex``) have in common."""
    if shared is not None:
        return shared
    if len(_types(types1)) * len(_types(types2)) != 1:
        raise ValueError(f"geom types {types1} x {types2}: a mixed group needs its shared program")
    return program(_types(types1)[0], _types(types2)[0])


def _rotation(axis, sin, cos):
    """Rotation matrix about unit ``axis`` by the angle of ``sin`` and ``cos`` (Rodrigues)."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]], axis.dtype)
    return jnp.eye(3, dtype=axis.dtype) + sin * k + (1.0 - cos) * (k @ k)


def _tangents(normal):
    """Two unit tangents completing ``normal`` to a right-handed frame."""
    other = jnp.where(jnp.abs(normal[1]) < 0.5, jnp.array([0.0, 1.0, 0.0], normal.dtype),
                      jnp.array([0.0, 0.0, 1.0], normal.dtype))  # fmt: skip
    t1 = jnp.cross(other, normal)
    t1 = t1 / jnp.linalg.norm(t1)
    return t1, jnp.cross(normal, t1)


def single_contact(type1, type2, shared=None):
    """``contact(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes=None) -> (dist, pos,
    normal)``: the one contact of two convex geoms by GJK on their cores and, where the cores
    overlap, EPA; the normal from the first to the second. A type may be a tuple of types
    (``support_vertex``); ``codes`` (2,) then gives the pair's own, and ``shared`` the
    ``program`` the group's type pairs share."""
    epa_iterations = _program(type1, type2, shared)[0]

    @stops_when_done
    def make(loop):
        return lambda *args: contact(*args, loop=loop)

    def contact(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes=None, *, loop):
        code1, code2 = (None, None) if codes is None else (codes[0], codes[1])
        support1 = lambda d: support_vertex(type1, pos1, mat1, size1, verts1, d, code1)  # noqa: E731
        support2 = lambda d: support_vertex(type2, pos2, mat2, size2, verts2, d, code2)  # noqa: E731
        dist, w1, w2, simplex, _ = gjk(support1, support2, pos1 - pos2, GJK_ITERATIONS, loop)
        apart = dist > 0
        depth, n_deep, d1, d2, _ = epa(support1, support2, simplex, epa_iterations, apart, loop)
        gap = w2 - w1
        n_apart = gap / jnp.where(apart, nonzero_norm(gap, 0.0)[0], 1.0)
        normal = jnp.where(apart, n_apart, n_deep)
        r1, r2 = core_radius(type1, size1, code1), core_radius(type2, size2, code2)
        x1 = jnp.where(apart, w1, d1) + r1 * normal
        x2 = jnp.where(apart, w2, d2) - r2 * normal
        dist = jnp.where(apart, dist, -depth) - r1 - r2
        return dist, 0.5 * (x1 + x2), normal

    return make


def separation(type1, type2):
    """``separation(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes=None) -> dist``
    (types and ``codes`` as in ``single_contact``): GJK alone:
    the distance ``convex_pair``'s first contact reports when the cores are apart, minus infinity
    when they overlap. A pair whose separation is at least its margin gets no contact, so the
    driver runs EPA and the multi-contact search only when some pair is closer."""

    @stops_when_done
    def make(loop):
        return lambda *args: dist(*args, loop=loop)

    def dist(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes=None, *, loop):
        code1, code2 = (None, None) if codes is None else (codes[0], codes[1])
        support1 = lambda d: support_vertex(type1, pos1, mat1, size1, verts1, d, code1)  # noqa: E731
        support2 = lambda d: support_vertex(type2, pos2, mat2, size2, verts2, d, code2)  # noqa: E731
        gap = gjk(support1, support2, pos1 - pos2, GJK_ITERATIONS, loop)[0]
        radii = core_radius(type1, size1, code1) + core_radius(type2, size2, code2)
        return jnp.where(gap > 0, gap - radii, -jnp.inf)

    return make


def convex_pair(type1, type2, multi: bool = True, shared=None):
    """The collision function of two convex geom types (see module doc): GJK on their cores and,
    where the cores overlap, EPA. Signature as the driver's shaped functions: poses and sizes,
    then each geom's mesh vertices (ignored unless a mesh), the pair's type codes (used where a
    type is a tuple: ``single_contact``), the margin and the smaller bounding radius.

    Where both shapes can rest on a face or an edge (boxes, meshes, cylinders, capsules), one
    contact cannot hold a face up, so the pair also searches for more as MuJoCo's multi-contact
    (multiccd) does: the two geoms turned by +-1e-3 rad in opposite senses about each tangent of
    the first contact, around its point, and each contact found there, if distinct from those
    before it, joins with the first's distance. MuJoCo searches this way for pairs with a
    margin and for capsules and cylinders; a mesh against a mesh or box with no margin clips the
    touching faces instead (``collision_manifold``)."""
    extra = _program(type1, type2, shared)[1] - 1 if multi else 0  # multi=False: multiccd disabled
    contact = single_contact(type1, type2, shared)

    def collide(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes, margin, rbound):
        if not extra:
            dist, pos, normal = contact(pos1, mat1, size1, pos2, mat2, size2, verts1, verts2, codes)
            return dist[None], pos[None], normal[None], jnp.zeros((1, 3), pos1.dtype)

        def search(k, found):
            """The k-th contact: the plain one (k = 0), then the turned ones, which turn about the
            first's tangents around its point. One loop body, so GJK/EPA compiles once."""
            dists, poss, normals = found
            first, point = k == 0, poss[0]
            turn = jnp.maximum(k - 1, 0)
            t1, t2 = _tangents(jnp.where(first, jnp.array([0.0, 0.0, 1.0], pos1.dtype), normals[0]))
            axis = jnp.where(turn < 2, t1, t2)
            sin = jnp.where(turn % 2 == 0, -_SIN, _SIN).astype(pos1.dtype)
            rot = _rotation(axis, sin, jnp.asarray(_COS, pos1.dtype))
            p1 = jnp.where(first, pos1, point + rot @ (pos1 - point))
            m1 = jnp.where(first, mat1, rot @ mat1)
            p2 = jnp.where(first, pos2, point + rot.T @ (pos2 - point))
            m2 = jnp.where(first, mat2, rot.T @ mat2)
            d, x, n = contact(p1, m1, size1, p2, m2, size2, verts1, verts2, codes)
            return dists.at[k].set(d), poss.at[k].set(x), normals.at[k].set(n)

        count = extra + 1
        zeros = jnp.zeros((count, 3), pos1.dtype)
        found_d, found_x, found_n = jax.lax.fori_loop(0, count, search, (zeros[:, 0], zeros, zeros))
        dist, tolerance = found_d[0], _DISTINCT * rbound
        dists, poss, kept = [dist], [found_x[0]], [jnp.array(True)]
        for k in range(1, count):
            x = found_x[k]
            apart = jnp.linalg.norm(jnp.stack(poss) - x, axis=-1) > tolerance
            found = (dist < margin) & (found_d[k] < margin) & jnp.all(apart | ~jnp.stack(kept))
            dists.append(jnp.where(found, dist, _FAR))
            poss.append(x)
            kept.append(found)
        return jnp.stack(dists), found_x, found_n, jnp.zeros((count, 3), pos1.dtype)

    return collide
