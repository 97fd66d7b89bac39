"""The contacts of two convex geoms from GJK/EPA (``collision_gjk``), as MuJoCo's convex collision
(``mjc_ccd``) reports them: one contact (``single_contact``), GJK's separation alone, which lets
the driver skip EPA for pairs apart (``separation``), and the collision function with MuJoCo's
multi-contact search by perturbation (multiccd, ``convex_pair``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics.collision_gjk import (
    EPA_ITERATIONS,
    EPA_ITERATIONS_CURVED,
    GJK_ITERATIONS,
    core_radius,
    epa,
    gjk,
    nonzero_norm,
    stops_when_done,
    support_vertex,
)
from fastrl.physics.collision_primitive import _FAR
from fastrl.physics.types import GeomType

# Geoms with curved surfaces: their pairs' EPA takes EPA_ITERATIONS_CURVED steps.
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
