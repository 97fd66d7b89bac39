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
and are inflated by their radius afterwards; they go through EPA only when the cores overlap. The
contacts of a pair are built from these in ``collision_ccd``.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

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


def _polytope(simplex, nv: int, nf: int):
    """EPA's starting polytope, GJK's enclosing tetrahedron ``simplex``, in buffers of ``nv``
    vertices and ``nf`` face slots: the vertices (nv, 3), their points on A and on B (nv, 3) and
    those points' vertex ids (nv,); the faces (nf, 3), each face's neighbours (nf, 3) and which
    slots hold a face (nf,)."""
    points, sa, sb, sia, sib = simplex
    dtype = points.dtype
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
    return v, va, vb, ia, ib, faces, adj, alive


def _fan(faces, adj, alive, seen, new, nv: int, nxt):
    """EPA's polytope with the ``seen`` faces (nf,) dropped and the hole closed by a fan of faces
    from vertex ``new`` over the horizon (the seen faces' edges whose neighbour is unseen), in the
    free slots: the faces (nf, 3), their neighbours (nf, 3) and the slots in use (nf,). ``nxt``
    maps each edge of a face to the next ([1, 2, 0])."""
    nf = faces.shape[0]
    horizon = seen[:, None] & ~seen[adj]  # (nf, 3): edge e of a seen face, its neighbour unseen
    free = ~alive | seen
    slots = jnp.argsort(~free, stable=True)  # free slots first
    flat = horizon.reshape(-1)
    slot = jnp.where(flat, slots[jnp.cumsum(flat) - 1], nf).reshape(nf, 3).astype(jnp.int32)
    start, end = faces, faces[:, nxt]  # each edge's two vertices
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
    return faces2, adj2, alive2


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
    dtype = simplex[0].dtype
    nv, nf = 4 + iterations, 4 + 3 * iterations
    polytope = _polytope(simplex, nv, nf)
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
        new = (k + 4).astype(jnp.int32)
        faces2, adj2, alive2 = _fan(faces, adj, alive, seen, new, nv, nxt)
        keep = lambda new, old: jnp.where(done, old, new)  # noqa: E731
        return (keep(v.at[new].set(w), v), keep(va.at[new].set(a), va), keep(vb.at[new].set(b), vb),
                keep(ia.at[new].set(i), ia), keep(ib.at[new].set(j), ib),
                keep(faces2, faces), keep(adj2, adj), keep(alive2, alive), done)  # fmt: skip

    state = (*polytope, jnp.asarray(skip))
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
