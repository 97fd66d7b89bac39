"""Narrow phase over the static pair table: one vmapped primitive per geom-type pair.

Which geom pairs can touch is decided once on the host (``io_contacts.candidate_geom_pairs``); the
traced program only evaluates those pairs, each type pair by its own primitive, and always returns
the same number of candidate contacts. A scene with no pairs traces no collision code at all.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import collision_box as box
from fastrl.physics import collision_ccd as ccd
from fastrl.physics import collision_convex as convex
from fastrl.physics import collision_manifold as manifold
from fastrl.physics import collision_primitive as prim
from fastrl.physics.masked import masked_map as masked
from fastrl.physics.math import cross, dot
from fastrl.physics.types import Data, GeomType, Model

# (type1, type2) with type1 <= type2 -> (primitive, candidate contacts per pair)
PRIMITIVES = {
    (GeomType.PLANE, GeomType.SPHERE): (prim.plane_sphere, 1),
    (GeomType.PLANE, GeomType.CAPSULE): (prim.plane_capsule, 2),
    (GeomType.PLANE, GeomType.ELLIPSOID): (convex.plane_ellipsoid, 1),
    (GeomType.PLANE, GeomType.CYLINDER): (prim.plane_cylinder, 4),
    (GeomType.PLANE, GeomType.BOX): (prim.plane_box, 4),
    (GeomType.SPHERE, GeomType.SPHERE): (prim.sphere_sphere, 1),
    (GeomType.SPHERE, GeomType.CAPSULE): (prim.sphere_capsule, 1),
    (GeomType.SPHERE, GeomType.CYLINDER): (prim.sphere_cylinder, 1),
    (GeomType.SPHERE, GeomType.BOX): (prim.sphere_box, 1),
    (GeomType.CAPSULE, GeomType.CAPSULE): (prim.capsule_capsule, 1),
    (GeomType.CAPSULE, GeomType.CYLINDER): (prim.capsule_cylinder, 1),
    (GeomType.CAPSULE, GeomType.BOX): (prim.capsule_box, 3),
}

# Pairs with a mesh or height field, and box-box: their functions also take the shape's data and
# the pair's margin (``_shape_args``).
# A height-field pair's candidate count is two per cell of its window (None here).
SHAPED = {
    (GeomType.BOX, GeomType.BOX): (box.box_box, box.CONTACTS),
    (GeomType.PLANE, GeomType.MESH): (convex.plane_mesh, 4),
    (GeomType.HFIELD, GeomType.SPHERE): (convex.hfield_sphere, None),
    (GeomType.HFIELD, GeomType.BOX): (convex.hfield_box, None),
    **{
        (GeomType.HFIELD, t): (convex.hfield_convex(t), None)
        for t in (GeomType.CAPSULE, GeomType.ELLIPSOID, GeomType.CYLINDER, GeomType.MESH)
    },
}
# Every other pair of convex geoms (meshes' hulls, cylinders against cylinders and boxes,
# ellipsoids) goes through GJK/EPA: one contact per pair.
_CONVEX = (
    GeomType.SPHERE,
    GeomType.CAPSULE,
    GeomType.ELLIPSOID,
    GeomType.CYLINDER,
    GeomType.BOX,
    GeomType.MESH,
)
GJK_PAIRS = {
    (t1, t2)
    for t1 in _CONVEX
    for t2 in _CONVEX
    if t1 <= t2 and (t1, t2) not in PRIMITIVES and (t1, t2) not in SHAPED
}
SHAPED.update({key: (ccd.convex_pair(*key), ccd.contacts_per_pair(*key)) for key in sorted(GJK_PAIRS)})
# Meshes against meshes and boxes with no margin (``Model.pair_faceclip``): MuJoCo's face-clipping
# multi-contact instead of the perturbation search; keyed by the type pair and ``FACES``.
FACES = "faces"
FACE_CLIPPED = {(GeomType.BOX, GeomType.MESH, FACES), (GeomType.MESH, GeomType.MESH, FACES)}
SHAPED.update({key: (manifold.faces_pair(*key[:2]), manifold.CONTACTS) for key in sorted(FACE_CLIPPED)})
GJK_PAIRS |= FACE_CLIPPED
SUPPORTED = {**PRIMITIVES, **SHAPED}


@dataclasses.dataclass(frozen=True)
class Convex:
    """The key of a group of GJK/EPA pairs that may mix type pairs: the geom types on each side.
    Every type pair it holds has the same ``collision_ccd.program`` (EPA's iterations, candidate
    contacts), and each pair's own types are data (``codes``), so the group compiles GJK/EPA once
    however many type pairs it holds."""

    types1: tuple[int, ...]
    types2: tuple[int, ...]
    program: tuple[int, int]


MESH_GROUPS = 3  # at most this many hull-size groups per type pair (each compiles GJK/EPA anew)


def _plain_gjk(key) -> bool:
    """Whether a type pair (or group key) goes through ``collision_ccd.convex_pair``."""
    return isinstance(key, Convex) or (key in GJK_PAIRS and key not in FACE_CLIPPED)


def is_gjk(key) -> bool:
    """Whether a group's pairs go through GJK (``_cull``): plain or face-clipped."""
    return isinstance(key, Convex) or key in GJK_PAIRS


def key_types(key) -> tuple:
    """A group key's geom types on each side (tuples for a ``Convex`` group, else ints)."""
    return (key.types1, key.types2) if isinstance(key, Convex) else key[:2]


def _hull_buckets(m: Model, idx: np.ndarray) -> np.ndarray:
    """Each pair's hull-size group, named by its largest vertex count (0 with no mesh): from the
    largest size down, a group takes every size above half its own, so padding a hull to its
    group's size at most doubles its support's cost; then, while a type pair has more than
    ``MESH_GROUPS`` groups, the group whose padding up to the next size costs least (pairs x
    added vertices) joins that next group."""
    g = np.stack([m.pair_geom1[idx], m.pair_geom2[idx]])
    if not m.mesh_vertnum.size:  # no meshes in the model
        return np.zeros(idx.size, np.int64)
    num = np.where(m.geom_meshid[g] >= 0, m.mesh_vertnum[np.maximum(m.geom_meshid[g], 0)], 0).max(0)
    bucket, heads = np.zeros(idx.size, np.int64), []
    for size in np.unique(num)[::-1]:
        if not heads or 2 * size <= heads[-1]:
            heads.append(size)
        bucket[num == size] = heads[-1]
    sizes = list(np.unique(bucket))
    while len(sizes) > MESH_GROUPS:
        cost = [np.sum(bucket == a) * (b - a) for a, b in zip(sizes[:-1], sizes[1:], strict=False)]
        i = int(np.argmin(cost))
        bucket[bucket == sizes[i]] = sizes[i + 1]
        del sizes[i]
    return bucket


def _convex_groups(m: Model, key: tuple[int, int], seen: set) -> list[tuple[Convex, np.ndarray]]:
    """The GJK/EPA groups of ``key``'s program (``collision_ccd.program``): the pairs of every
    type pair with that program, split by hull size (``_hull_buckets``), each group keyed by the
    types it holds, so several type pairs compile one GJK/EPA. Empty when the program's groups
    were made already (``seen``). Under MJX's ``max_geom_pairs``, which caps each type pair and
    condim, type pairs are not mixed."""
    program = key if capped(m, key) else ccd.program(*key)
    if program in seen:
        return []
    seen.add(program)
    t1, t2 = m.geom_type[m.pair_geom1], m.geom_type[m.pair_geom2]
    plain = ~m.pair_faceclip.astype(bool)
    ours = [k for k in SUPPORTED if _plain_gjk(k) and (k if capped(m, k) else ccd.program(*k)) == program]
    idx = np.flatnonzero(plain & np.any([(t1 == k[0]) & (t2 == k[1]) for k in ours], axis=0))
    if not idx.size:
        return []
    by_condim = capped(m, key) and GeomType.MESH not in key
    bucket = m.pair_condim[idx] if by_condim else _hull_buckets(m, idx)
    groups = []
    for b in np.unique(bucket):
        sub = idx[bucket == b]
        types = tuple(tuple(int(t) for t in np.unique(side[sub])) for side in (t1, t2))
        groups.append((Convex(*types, ccd.program(int(t1[sub[0]]), int(t2[sub[0]]))), sub))
    return groups


def pair_groups(m: Model) -> list[tuple[tuple[int, int] | Convex, np.ndarray]]:
    """Pair indices grouped by geom-type pair (and, with meshes, by hull size; with MJX's
    ``max_geom_pairs``, by condim), in a fixed order. Plain GJK/EPA pairs of several type pairs
    share groups (``Convex``), placed where their first type pair stands."""
    t1, t2 = m.geom_type[m.pair_geom1], m.geom_type[m.pair_geom2]
    groups, seen = [], set()
    for key in SUPPORTED:
        if _plain_gjk(key):
            groups.extend(_convex_groups(m, key, seen))
            continue
        clipped = key in FACE_CLIPPED
        if key[:2] + (FACES,) in FACE_CLIPPED or clipped:  # split by Model.pair_faceclip
            idx = np.flatnonzero((t1 == key[0]) & (t2 == key[1]) & (m.pair_faceclip == clipped))
        else:
            idx = np.flatnonzero((t1 == key[0]) & (t2 == key[1]))
        if not idx.size:
            continue
        if GeomType.MESH in key:
            bucket = _hull_buckets(m, idx)
        elif capped(m, key):  # MJX caps each group of one type pair and one condim
            bucket = m.pair_condim[idx]
        else:
            bucket = np.zeros(idx.size, np.int64)
        groups.extend((key, idx[bucket == b]) for b in np.unique(bucket))
    return groups


def gjk_slots(n: int) -> tuple[int, int]:
    """How many of a group's ``n`` GJK/EPA pairs each stage of ``_cull`` keeps: GJK runs on the
    half of the group (at least 32) whose bounding spheres overlap most, EPA and the multi-contact
    search on the quarter of those (at least 16) that GJK finds closest. MuJoCo skips pairs whose
    bounding spheres, grown by the margin, do not overlap; in the Menagerie's full-collision
    scenes, posed at their keyframes with joint angles perturbed (sigma 0.4 rad), at most a quarter
    of a group's pairs overlap that way, and at most an eighth of those touch."""
    gjk = min(n, max(32, -(-n // 2)))
    return gjk, min(gjk, max(16, -(-gjk // 4)))


def _top(k: int, score: jax.Array) -> jax.Array:
    """(n,) bool: the ``k`` highest of ``score`` (ties: the lower index, as ``lax.top_k``)."""
    return jnp.zeros(score.shape, bool).at[jax.lax.top_k(score, k)[1]].set(True)


def _overlap(m: Model, d: Data, idx: np.ndarray) -> jax.Array:
    """(n,) how far each pair's bounding spheres, grown by its margin, overlap (< 0: apart)."""
    g1, g2 = m.pair_geom1[idx], m.pair_geom2[idx]
    reach = m.geom_rbound[g1] + m.geom_rbound[g2] + m.pair_margin[idx]
    return reach - jnp.linalg.norm(d.geom_xpos[g1] - d.geom_xpos[g2], axis=-1)


def capped(m: Model, key: tuple) -> bool:
    """Whether MJX's ``max_geom_pairs`` applies to a type pair (planes and height fields never)."""
    if isinstance(key, Convex):  # no planes or height fields go through GJK/EPA
        return m.max_geom_pairs > 0
    return m.max_geom_pairs > 0 and not {GeomType.PLANE, GeomType.HFIELD} & set(key[:2])


def compacted(m: Model, key: tuple, idx: np.ndarray) -> bool:
    """Whether a group emits contacts only for the pairs it collides: MJX's ``max_geom_pairs``
    on a primitive or box-box group with more pairs than that. Its candidates' pairs then change
    from step to step (``Data.contact_pair``); a GJK/EPA group keeps its whole layout (``_cull``)."""
    return capped(m, key) and not is_gjk(key) and idx.size > m.max_geom_pairs


def _broadphase(m: Model, d: Data, idx: np.ndarray, fn, args: tuple, axes: tuple):
    """A group's contacts with MJX's ``max_geom_pairs``: only the pairs whose bounding spheres
    overlap most are collided, and only their contacts are emitted, in the group's pair order
    (so ties in depth resolve as they would over the whole group). Returns the contacts and
    each collided pair's index, and how many pairs whose spheres overlap were left out."""
    overlap = _overlap(m, d, idx)
    kept, chosen = jax.lax.top_k(overlap, m.max_geom_pairs)
    chosen = jnp.sort(chosen)
    take = lambda a: jax.tree.map(lambda x: x[chosen], a)  # noqa: E731
    args = tuple(a if ax is None else take(a) for a, ax in zip(args, axes, strict=True))
    dropped = jnp.sum(overlap >= 0) - jnp.sum(kept >= 0)
    return jax.vmap(fn, axes)(*args), jnp.asarray(idx, jnp.int32)[chosen], dropped


def _gjk_budget(m: Model, key, idx: np.ndarray) -> tuple[int, int]:
    """How many of a GJK/EPA group's pairs ``_cull`` runs GJK on, and EPA (``gjk_slots``, or MJX's
    ``max_geom_pairs`` if fewer)."""
    k1, k2 = gjk_slots(idx.size)
    if capped(m, key):
        k1 = min(k1, m.max_geom_pairs)
        k2 = min(k2, k1)
    return k1, k2


def budgeted(m: Model) -> bool:
    """Whether some group's budget can drop pairs (``_cull``, ``_broadphase``): a GJK/EPA group
    with more pairs than its EPA slots, or a ``compacted`` group."""
    return any(
        (is_gjk(key) and _gjk_budget(m, key, idx)[1] < idx.size) or compacted(m, key, idx)
        for key, idx in pair_groups(m)
    )


def _cull(m: Model, d: Data, key: tuple, idx: np.ndarray, fn, args: tuple, axes: tuple):
    """A GJK/EPA group's contacts, in three stages, each pair's result as if solved alone:

    1. bounding spheres: the pairs whose spheres (grown by the margin) overlap most are kept
       (``gjk_slots``, or MJX's ``max_geom_pairs`` if fewer); the rest, and any whose spheres do
       not overlap, get no contact (``_FAR``);
    2. GJK's separation of each kept pair whose spheres overlap: the closest are kept, and of
       those, a pair at least its margin apart gets no contact;
    3. EPA and the multi-contact search for the kept pairs within their margin.
    Stages 2 and 3 run on those pairs only (``masked.masked_map``): a vmapped batch pays for the
    pairs that reach each stage in all its envs, not for every kept pair of every env.

    Also returns how many pairs whose spheres overlap it dropped: left untested (stage 1), or
    found within the margin but left unsolved (stage 2)."""
    overlap = _overlap(m, d, idx)
    reached = jnp.sum(overlap >= 0)  # pairs MuJoCo's bounding test passes
    k1, k2 = _gjk_budget(m, key, idx)
    tested = (overlap >= 0) & _top(k1, overlap) if k1 < idx.size else overlap >= 0
    margin = args[-2]  # the shaped GJK arguments end with the margin and the smaller rbound
    verts = [a[0] if isinstance(a, tuple) else a for a in args[6:8]]  # face-clipped: hull tuples
    codes = args[8:9] if isinstance(key, Convex) else ()  # each pair's own types
    gjk_args = (*args[:6], *verts, *codes)
    inf = jnp.asarray(jnp.inf, args[0].dtype)
    sep = masked(ccd.separation(*key_types(key)), tested, gjk_args, (0,) * len(gjk_args), inf)
    near = tested & (sep < margin)
    if k2 < k1:
        near = near & _top(k2, jnp.where(near, -sep, -jnp.inf))
    count = candidates_per_pair(m, key, idx)
    zeros = jnp.zeros((count, 3), sep.dtype)
    far = (jnp.full((count,), prim._FAR, sep.dtype), zeros, zeros.at[..., 2].set(1.0), zeros)
    out = masked(fn, near, args, axes, far)
    # the overlapping pairs dropped before EPA: those GJK found apart are not dropped contacts
    dropped = reached - jnp.sum(near) - jnp.sum(tested & (sep >= margin))
    return out, dropped


def _window(m: Model, idx: np.ndarray) -> tuple[int, int]:
    """The cell window (rows, columns) shared by a group of height-field pairs: the largest."""
    return tuple(int(w) for w in m.pair_window[idx].max(axis=0))


def candidates_per_pair(m: Model, key: tuple[int, int], idx: np.ndarray) -> int:
    """How many candidate contacts each pair of a type-pair group emits (static)."""
    if isinstance(key, Convex):
        count = key.program[1]
    else:
        count = SUPPORTED[key][1]
    if is_gjk(key) and not m.multiccd:  # <flag multiccd="disable"/>: the first contact only
        count = 1
    if count is None:  # a height field: two prisms per cell of the window
        rows, cols = _window(m, idx)
        count = 2 * rows * cols
    return count


def _emitted(m: Model, key: tuple[int, int], idx: np.ndarray) -> np.ndarray:
    """The pairs whose candidates a group emits, as laid out: all of them, or for a ``compacted``
    group its first ``max_geom_pairs`` (placeholders: the pairs collided change every step)."""
    return idx[: m.max_geom_pairs] if compacted(m, key, idx) else idx


def contact_layout(m: Model) -> np.ndarray:
    """(ncand,) the pair index of every candidate contact, in the order ``collision`` emits them.

    Static. Where ``dynamic_candidates`` is True the entry is a placeholder of the right group
    (same geom types and condim); the pair that candidate holds is ``Data.contact_pair``'s."""
    groups = pair_groups(m)
    parts = [np.repeat(_emitted(m, key, idx), candidates_per_pair(m, key, idx)) for key, idx in groups]
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


def dynamic_candidates(m: Model) -> np.ndarray:
    """(ncand,) bool: the candidates of ``compacted`` groups, whose pair changes step to step."""
    parts = [
        np.full(_emitted(m, key, idx).size * candidates_per_pair(m, key, idx), compacted(m, key, idx))
        for key, idx in pair_groups(m)
    ]
    return np.concatenate(parts) if parts else np.zeros(0, bool)


def candidate_pairs(m: Model, d: Data) -> jax.Array:
    """(ncand,) int32 the pair each candidate contact holds: ``Data.contact_pair`` when some
    group is ``compacted``, else the static ``contact_layout`` (a constant XLA folds)."""
    if dynamic_candidates(m).any():
        return d.contact_pair
    return jnp.asarray(contact_layout(m), jnp.int32)


def _mesh_verts(m: Model, g: np.ndarray) -> jax.Array:
    """Each geom's hull vertices (n, V, 3), padded to the group's largest with copies of vertex 0
    (which change no support point)."""
    mesh = m.geom_meshid[g]
    k = np.arange(m.mesh_vertnum[mesh].max())
    real = k[None, :] < m.mesh_vertnum[mesh][:, None]
    return m.mesh_vert[m.mesh_vertadr[mesh][:, None] + np.where(real, k[None, :], 0)]


def _side_verts(m: Model, g: np.ndarray) -> jax.Array:
    """One side of a GJK/EPA group: each geom's hull vertices where it is a mesh (``_mesh_verts``,
    zeros for the others), or a single zero vertex each when none is."""
    mesh = m.geom_type[g] == GeomType.MESH
    if not mesh.any():
        return jnp.zeros((g.size, 1, 3))
    verts = jnp.asarray(_mesh_verts(m, g[mesh]))
    if mesh.all():
        return verts
    return jnp.zeros((g.size,) + verts.shape[1:], verts.dtype).at[np.flatnonzero(mesh)].set(verts)


def _mesh_args(m: Model, g: np.ndarray) -> tuple[jax.Array, ...]:
    """Each geom's mesh, padded to the group's largest (with copies of vertex 0 and -1 ids):
    vertices (n, V, 3), each vertex's polygons (n, V, M), each polygon's vertices (n, P, K) and
    normals (n, P, 3)."""
    mesh = m.geom_meshid[g]

    def rows(adr, num):
        k = np.arange(num.max())
        real = k[None, :] < num[:, None]
        return adr[:, None] + np.where(real, k[None, :], 0), real

    vrows, vreal = rows(m.mesh_vertadr[mesh], m.mesh_vertnum[mesh])
    npoly = np.diff(np.r_[m.mesh_polyadr, m.mesh_polyvert.shape[0]])[mesh]
    prows, preal = rows(m.mesh_polyadr[mesh], npoly)
    polymap = np.where(vreal[..., None], m.mesh_polymap[vrows], -1)
    polyvert = np.where(preal[..., None], m.mesh_polyvert[prows], -1)
    normals = jnp.where(jnp.asarray(preal)[..., None], m.mesh_polynormal[prows], 0.0)
    return _mesh_verts(m, g), jnp.asarray(polymap), jnp.asarray(polyvert), normals


def _shape_args(m: Model, key: tuple[int, int], idx: np.ndarray) -> tuple[tuple, tuple, dict]:
    """Extra arguments of a ``SHAPED`` function, their vmap axes, and static keywords."""
    g1, g2 = m.pair_geom1[idx], m.pair_geom2[idx]
    margin = m.pair_margin[idx]
    if key == (GeomType.BOX, GeomType.BOX):
        return (margin,), (0,), {}
    if key == (GeomType.PLANE, GeomType.MESH):
        return (*_mesh_args(m, g2), margin), (0,) * 5, {}
    if key in FACE_CLIPPED:  # each side's hull and its rows in the shared polygon tables
        ints = lambda x: jnp.asarray(x, jnp.int32)  # noqa: E731
        hulls = []
        for g, t in ((g1, key[0]), (g2, key[1])):
            if t == GeomType.MESH:
                mesh = m.geom_meshid[g]
                hulls.append((_mesh_verts(m, g), ints(m.mesh_vertadr[mesh]), ints(m.mesh_polyadr[mesh])))
            else:
                hulls.append((jnp.zeros((g.size, 1, 3)), ints(np.zeros(g.size)), ints(np.zeros(g.size))))
        rbound = jnp.minimum(m.geom_rbound[g1], m.geom_rbound[g2])
        tables = (jnp.asarray(m.mesh_polymap), jnp.asarray(m.mesh_polyvert), m.mesh_polynormal)
        return (*hulls, margin, rbound), (0, 0, 0, 0), {"tables": tables}
    if isinstance(key, Convex):  # GJK/EPA: each side's mesh vertices (if a mesh), types
        verts = [_side_verts(m, g) for g in (g1, g2)]
        codes = jnp.asarray(np.stack([m.geom_type[g1], m.geom_type[g2]], axis=-1), jnp.int32)
        rbound = jnp.minimum(m.geom_rbound[g1], m.geom_rbound[g2])
        return (*verts, codes, margin, rbound), (0,) * 5, {}
    hf = m.geom_hfieldid[g1]
    if key[1] in (GeomType.SPHERE, GeomType.BOX):
        shape, shape_axes = (), ()
    else:  # GJK/EPA against each prism: the geom's mesh vertices (if a mesh)
        verts = _mesh_verts(m, g2) if key[1] == GeomType.MESH else jnp.zeros((g2.size, 1, 3))
        shape, shape_axes = (verts,), (0,)
    ints = lambda x: jnp.asarray(x, jnp.int32)  # noqa: E731
    args = (m.hfield_data, ints(m.hfield_adr[hf]), ints(m.hfield_nrow[hf]), ints(m.hfield_ncol[hf]),
            m.hfield_size[hf], m.geom_rbound[g2], margin)  # fmt: skip
    return (*shape, *args), (*shape_axes, None, 0, 0, 0, 0, 0, 0), {"window": _window(m, idx)}


def make_frame(normal: jax.Array, tangent: jax.Array) -> jax.Array:
    """Contact frame (..., 3, 3): rows are the normal and two tangents (mju_makeFrame).

    The first tangent is ``tangent`` made orthogonal to the normal; where that hint is absent
    (squared norm below 0.25, as MuJoCo tests it) or exactly along the normal, the world y axis is
    used instead (z if the normal is nearly along y). The second tangent is normal x first.
    """
    dtype = normal.dtype
    use_y = jnp.abs(normal[..., 1:2]) < 0.5
    default = jnp.where(use_y, jnp.array([0.0, 1.0, 0.0], dtype), jnp.array([0.0, 0.0, 1.0], dtype))
    hint = tangent - normal * dot(normal, tangent)[..., None]
    usable = (dot(tangent, tangent) >= 0.25)[..., None] & (dot(hint, hint) > 1e-12)[..., None]
    guess = jnp.where(usable, hint, default)
    t1 = guess - normal * dot(normal, guess)[..., None]
    t1 = t1 / jnp.linalg.norm(t1, axis=-1, keepdims=True)
    return jnp.stack([normal, t1, cross(normal, t1)], axis=-2)


def group_contacts(m: Model, d: Data, key, idx: np.ndarray) -> tuple[jax.Array, ...]:
    """One pair group's candidate contacts: ``(dist, pos, normal, tangent, pair, dropped)``, the
    first four per pair and candidate, ``pair`` the pair each candidate holds, ``dropped`` the
    pairs whose bounding spheres overlap that the group's budget left out."""
    convex = isinstance(key, Convex)
    fn = ccd.convex_pair(key.types1, key.types2, m.multiccd, key.program) if convex else SUPPORTED[key][0]
    g1, g2 = m.pair_geom1[idx], m.pair_geom2[idx]
    poses = (d.geom_xpos[g1], d.geom_xmat[g1], m.geom_size[g1],
             d.geom_xpos[g2], d.geom_xmat[g2], m.geom_size[g2])  # fmt: skip
    extra, axes, static = _shape_args(m, key, idx) if key in SHAPED or convex else ((), (), {})
    fn = functools.partial(fn, **static) if static else fn
    args, axes = (*poses, *extra), (0,) * 6 + axes
    count = candidates_per_pair(m, key, idx)
    pair = jnp.asarray(np.repeat(idx, count), jnp.int32)
    dropped = jnp.zeros((), jnp.int32)
    if is_gjk(key):  # bounding spheres and GJK first
        out, dropped = _cull(m, d, key, idx, fn, args, axes)
    elif compacted(m, key, idx):
        out, chosen, dropped = _broadphase(m, d, idx, fn, args, axes)
        pair = jnp.repeat(chosen, count)
    else:
        out = jax.vmap(fn, axes)(*args)
    dist, pos, normal, tangent = out
    return dist.reshape(-1), pos.reshape(-1, 3), normal.reshape(-1, 3), tangent.reshape(-1, 3), pair, dropped


def collision(m: Model, d: Data) -> Data:
    """Candidate contacts of every pair: ``contact_dist``, ``contact_pos``, ``contact_frame`` and
    ``contact_pair``; ``contact_overflow``: the pairs the budgets dropped (``Data``)."""
    groups = [group_contacts(m, d, key, idx) for key, idx in pair_groups(m)]
    if not groups:
        return d
    dist, pos, normal, tangent, pair = (jnp.concatenate([g[i] for g in groups]) for i in range(5))
    return d.replace(
        contact_dist=dist,
        contact_pos=pos,
        contact_frame=make_frame(normal, tangent),
        contact_pair=pair,
        contact_overflow=sum(g[5] for g in groups).astype(jnp.int32),
    )
