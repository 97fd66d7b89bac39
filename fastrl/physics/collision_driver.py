"""Narrow phase over the static pair table: one vmapped primitive per geom-type pair.

Which geom pairs can touch is decided once on the host (``io.candidate_geom_pairs``); the traced
program only evaluates those pairs, each type pair by its own primitive, and always returns the
same number of candidate contacts. A scene with no pairs traces no collision code at all.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import collision_primitive as prim
from fastrl.physics.math import cross, dot
from fastrl.physics.types import Data, GeomType, Model

# (type1, type2) with type1 <= type2 -> (primitive, candidate contacts per pair)
PRIMITIVES = {
    (GeomType.PLANE, GeomType.SPHERE): (prim.plane_sphere, 1),
    (GeomType.PLANE, GeomType.CAPSULE): (prim.plane_capsule, 2),
    (GeomType.PLANE, GeomType.CYLINDER): (prim.plane_cylinder, 4),
    (GeomType.PLANE, GeomType.BOX): (prim.plane_box, 4),
    (GeomType.SPHERE, GeomType.SPHERE): (prim.sphere_sphere, 1),
    (GeomType.SPHERE, GeomType.CAPSULE): (prim.sphere_capsule, 1),
    (GeomType.SPHERE, GeomType.CYLINDER): (prim.sphere_cylinder, 1),
    (GeomType.SPHERE, GeomType.BOX): (prim.sphere_box, 1),
    (GeomType.CAPSULE, GeomType.CAPSULE): (prim.capsule_capsule, 1),
    (GeomType.CAPSULE, GeomType.CYLINDER): (prim.capsule_cylinder, 1),
    (GeomType.CAPSULE, GeomType.BOX): (prim.capsule_box, 3),
    (GeomType.BOX, GeomType.BOX): (prim.box_box, 16),
}


def pair_groups(m: Model) -> list[tuple[tuple[int, int], np.ndarray]]:
    """Pair indices grouped by geom-type pair, in a fixed order."""
    t1, t2 = m.geom_type[m.pair_geom1], m.geom_type[m.pair_geom2]
    groups = []
    for key in PRIMITIVES:
        idx = np.flatnonzero((t1 == key[0]) & (t2 == key[1]))
        if idx.size:
            groups.append((key, idx))
    return groups


def contact_layout(m: Model) -> np.ndarray:
    """(ncon,) the pair index of every candidate contact, in the order ``collision`` emits them."""
    parts = [np.repeat(idx, PRIMITIVES[key][1]) for key, idx in pair_groups(m)]
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


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


def collision(m: Model, d: Data) -> Data:
    """Candidate contacts of every pair: ``contact_dist``, ``contact_pos``, ``contact_frame``."""
    dists, poss, normals, tangents = [], [], [], []
    for key, idx in pair_groups(m):
        fn = PRIMITIVES[key][0]
        g1, g2 = m.pair_geom1[idx], m.pair_geom2[idx]
        dist, pos, normal, tangent = jax.vmap(fn)(
            d.geom_xpos[g1], d.geom_xmat[g1], m.geom_size[g1],
            d.geom_xpos[g2], d.geom_xmat[g2], m.geom_size[g2],
        )  # fmt: skip
        dists.append(dist.reshape(-1))
        poss.append(pos.reshape(-1, 3))
        normals.append(normal.reshape(-1, 3))
        tangents.append(tangent.reshape(-1, 3))
    if not dists:
        return d
    return d.replace(
        contact_dist=jnp.concatenate(dists),
        contact_pos=jnp.concatenate(poss),
        contact_frame=make_frame(jnp.concatenate(normals), jnp.concatenate(tangents)),
    )
