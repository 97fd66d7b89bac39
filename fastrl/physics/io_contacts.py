"""The contact-pair table of a ``Model``, built on the host from the compiled MuJoCo model: the geom
pairs MuJoCo's broadphase could let touch, each pair's contact parameters mixed from its geoms,
the mesh and height-field data of their geoms, and the number of contact slots.
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics.collision_driver import FACES, GJK_PAIRS, SUPPORTED
from fastrl.physics.constraint import default_nconmax
from fastrl.physics.types import GeomType

_DSBL = mujoco.mjtDisableBit


def _geom_pairs_off_world(m: mujoco.MjModel, chunk: int = 1 << 22) -> tuple[np.ndarray, np.ndarray]:
    """Every geom pair ``g1 < g2`` with at least one geom off the world body's weld, unordered.

    Two world-welded geoms never collide, so a scene of many static geoms costs O(moving x
    ngeom), not O(ngeom^2); the pairs are built in blocks of about ``chunk`` to bound the memory.
    """
    weld = m.body_weldid[m.geom_bodyid]
    moving = np.flatnonzero(weld != 0)
    static = np.flatnonzero(weld == 0)
    rows = max(1, chunk // max(1, m.ngeom))
    g1s, g2s = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for start in range(0, moving.size, rows):
        part = moving[start : start + rows]
        later = moving[start:]  # a moving partner pairs with the lower of the two only
        a = np.concatenate([np.repeat(part, static.size), np.repeat(part, later.size)])
        b = np.concatenate([np.tile(static, part.size), np.tile(later, part.size)])
        keep = (weld[b] == 0) | (b > a)
        g1s.append(np.minimum(a, b)[keep])
        g2s.append(np.maximum(a, b)[keep])
    return np.concatenate(g1s), np.concatenate(g2s)


def candidate_geom_pairs(m: mujoco.MjModel) -> list[tuple[int, int]]:
    """Geom pairs that MuJoCo's broadphase filter could let touch (contype/conaffinity, exclusions).

    Excludes pairs in one welded body, pairs of two world-welded geoms, parent-child pairs (unless
    filterparent is disabled) and ``<exclude>``d body pairs; adds explicit ``<pair>`` elements,
    which bypass those filters and replace the filtered pair of the same two geoms (MuJoCo keeps
    the other geom pairs of the same two bodies). The filtered pairs come in ascending
    ``(g1, g2)`` order, then the explicit ones. The filters are numpy masks over the pairs with a
    moving geom, so a scene of many static geoms loads in time linear in their number.
    """
    explicit = _explicit_pairs(m)
    g1, g2 = _geom_pairs_off_world(m)
    ctype, caff = m.geom_contype, m.geom_conaffinity
    ok = ((ctype[g1] & caff[g2]) != 0) | ((ctype[g2] & caff[g1]) != 0)
    b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
    weld, parent = m.body_weldid, m.body_parentid
    w1, w2 = weld[b1], weld[b2]
    ok &= w1 != w2
    if not m.opt.disableflags & _DSBL.mjDSBL_FILTERPARENT:
        ok &= ~((w1 != 0) & (w2 != 0) & ((weld[parent[w1]] == w2) | (weld[parent[w2]] == w1)))
    # An <exclude> signature is (lower body id << 16) | higher body id.
    low, high = np.minimum(b1, b2).astype(np.int64), np.maximum(b1, b2).astype(np.int64)
    signature = np.asarray(m.exclude_signature, np.int64)
    ok &= ~((high < 1 << 16) & np.isin(low << 16 | high, signature))
    key = g1 * m.ngeom + g2
    ok &= ~np.isin(key, np.array([min(p) * m.ngeom + max(p) for p in explicit], np.int64))
    order = np.argsort(key[ok], kind="stable")
    pairs = list(zip(g1[ok][order].tolist(), g2[ok][order].tolist(), strict=True))
    pairs.extend(tuple(sorted(p)) for p in explicit)
    # MuJoCo's collision table is indexed with the lower geom type first.
    return [(a, b) if m.geom_type[a] <= m.geom_type[b] else (b, a) for a, b in pairs]


def _explicit_pairs(m: mujoco.MjModel) -> dict[frozenset, int]:
    """``{frozenset((geom1, geom2)): pair id}`` of the model's explicit ``<contact><pair>``s."""
    return {
        frozenset((int(a), int(b))): i
        for i, (a, b) in enumerate(zip(m.pair_geom1, m.pair_geom2, strict=True))
    }


def _mix_pair_params(m: mujoco.MjModel, pairs: list[tuple[int, int]]) -> dict[str, np.ndarray]:
    """Contact parameters of each pair, mixed from its two geoms as MuJoCo mixes them.

    An explicit ``<pair>`` takes its own condim, friction, solref, solreffriction (the elliptic
    cone's friction rows; other pairs have none and use solref), solimp, margin and gap. Other
    pairs: condim and friction take the maximum (friction per component, expanded to MuJoCo's
    5-vector: tangential, tangential, torsional, rolling, rolling, each at least 1e-5); margins
    and gaps add up (MuJoCo >= 4.0); solref and solimp are a weighted mean with weights from
    ``solmix``; a geom with higher ``priority`` supplies condim, friction, solref and solimp.
    """
    n = len(pairs)
    out = {
        "condim": np.zeros(n, np.int32), "friction": np.zeros((n, 5)), "solref": np.zeros((n, 2)),
        "solimp": np.zeros((n, 5)), "margin": np.zeros(n), "gap": np.zeros(n),
        "solreffriction": np.zeros((n, 2)),
    }  # fmt: skip
    explicit = _explicit_pairs(m)
    for k, (g1, g2) in enumerate(pairs):
        pid = explicit.get(frozenset((int(g1), int(g2))))
        if pid is not None:  # an explicit <pair> states its own parameters
            out["condim"][k] = m.pair_dim[pid]
            out["friction"][k] = np.maximum(m.pair_friction[pid], mujoco.mjMINMU)
            out["solref"][k], out["solimp"][k] = m.pair_solref[pid], m.pair_solimp[pid]
            out["margin"][k], out["gap"][k] = m.pair_margin[pid], m.pair_gap[pid]
            out["solreffriction"][k] = m.pair_solreffriction[pid]
            continue
        p1, p2 = m.geom_priority[g1], m.geom_priority[g2]
        if p1 != p2:
            win = g1 if p1 > p2 else g2
            condim, fric = m.geom_condim[win], m.geom_friction[win]
            solref, solimp = m.geom_solref[win], m.geom_solimp[win]
        else:
            condim = max(m.geom_condim[g1], m.geom_condim[g2])
            fric = np.maximum(m.geom_friction[g1], m.geom_friction[g2])
            s1, s2 = m.geom_solmix[g1], m.geom_solmix[g2]
            small1, small2 = s1 < mujoco.mjMINVAL, s2 < mujoco.mjMINVAL
            mix = 0.5 if small1 and small2 else 0.0 if small1 else 1.0 if small2 else s1 / (s1 + s2)
            if m.geom_solref[g1][0] > 0 and m.geom_solref[g2][0] > 0:
                solref = mix * m.geom_solref[g1] + (1 - mix) * m.geom_solref[g2]
            else:  # direct (negative) solref: the stiffer of the two
                solref = np.minimum(m.geom_solref[g1], m.geom_solref[g2])
            solimp = mix * m.geom_solimp[g1] + (1 - mix) * m.geom_solimp[g2]
        out["condim"][k] = condim
        out["friction"][k] = np.maximum([fric[0], fric[0], fric[1], fric[2], fric[2]], mujoco.mjMINMU)
        out["solref"][k], out["solimp"][k] = solref, solimp
        out["margin"][k] = m.geom_margin[g1] + m.geom_margin[g2]
        out["gap"][k] = m.geom_gap[g1] + m.geom_gap[g2]
    return out


def _hull_vertices(m: mujoco.MjModel, mesh: int) -> np.ndarray:
    """Mesh-local ids, ascending, of the vertices of the convex hull MuJoCo's compiler built (its
    ``mesh_graph``: vertex count, face count, each vertex's edge address, then its mesh id), so
    that ``maxhullvert`` holds and no interior vertex is searched; every vertex without a hull."""
    adr = m.mesh_graphadr[mesh]
    if adr < 0:
        return np.arange(m.mesh_vertnum[mesh])
    num = int(m.mesh_graph[adr])
    return np.sort(m.mesh_graph[adr + 2 + num : adr + 2 + 2 * num]).astype(np.int64)


def _padded(rows: list) -> np.ndarray:
    """``rows`` of ints as one (len(rows), longest) int32 array, padded with -1."""
    out = np.full((len(rows), max((len(r) for r in rows), default=0)), -1, np.int32)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


def _mesh_fields(m: mujoco.MjModel, mesh_geoms: list[int]) -> dict:
    """``Model``'s mesh fields for the meshes of ``mesh_geoms``: the convex hull's vertices and
    polygons MuJoCo's compiler built (``mesh_poly*``): each vertex's polygons, each polygon's
    vertices (-1 padded) and normal."""
    meshes = sorted({int(m.geom_dataid[g]) for g in mesh_geoms})
    geom_meshid = np.full(m.ngeom, -1, np.int32)
    verts, maps, polys, normals, vadr, vnum, padr = [], [], [], [], [], [], []
    for k, mid in enumerate(meshes):
        v0, p0, npoly = m.mesh_vertadr[mid], m.mesh_polyadr[mid], m.mesh_polynum[mid]
        hull = _hull_vertices(m, mid)
        local = np.full(m.mesh_vertnum[mid], -1, np.int64)
        local[hull] = np.arange(hull.size)
        vadr.append(sum(vnum))
        vnum.append(hull.size)
        padr.append(len(polys))
        verts.append(m.mesh_vert[v0 + hull])
        for v in hull:  # the polygons each vertex lies on (mesh-local polygon ids)
            a, n = m.mesh_polymapadr[v0 + v], m.mesh_polymapnum[v0 + v]
            maps.append(m.mesh_polymap[a : a + n])
        for q in range(p0, p0 + npoly):  # each polygon's vertices (hull-local vertex ids)
            a, n = m.mesh_polyvertadr[q], m.mesh_polyvertnum[q]
            polys.append(local[m.mesh_polyvert[a : a + n]])
        normals.append(m.mesh_polynormal[p0 : p0 + npoly].reshape(-1, 3))
        geom_meshid[[g for g in mesh_geoms if m.geom_dataid[g] == mid]] = k
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return dict(
        geom_meshid=geom_meshid, mesh_vertadr=np.asarray(vadr, np.int32),
        mesh_vertnum=np.asarray(vnum, np.int32), mesh_polyadr=np.asarray(padr, np.int32),
        mesh_polymap=_padded(maps), mesh_polyvert=_padded(polys),
        mesh_polynormal=f(np.concatenate(normals) if normals else np.zeros((0, 3))),
        mesh_vert=f(np.concatenate(verts) if verts else np.zeros((0, 3))),
    )  # fmt: skip


def _hfield_windows(m: mujoco.MjModel, pairs: list[tuple[int, int]]) -> np.ndarray:
    """(npair, 2) the rows and columns of height-field cells examined around the other geom of
    each height-field pair (zero for other pairs)."""
    window = np.zeros((len(pairs), 2), np.int32)
    for k, (g1, g2) in enumerate(pairs):
        if m.geom_type[g1] == GeomType.HFIELD:
            hid = m.geom_dataid[g1]
            reach = 2 * (m.geom_rbound[g2] + m.geom_margin[g1] + m.geom_margin[g2])
            step = np.array(
                [
                    2 * m.hfield_size[hid, 1] / (m.hfield_nrow[hid] - 1),  # rows: y
                    2 * m.hfield_size[hid, 0] / (m.hfield_ncol[hid] - 1),
                ]
            )  # cols: x
            cells = np.floor(reach / step * (1 + 1e-9)).astype(np.int32) + 2
            window[k] = np.minimum(cells, [m.hfield_nrow[hid] - 1, m.hfield_ncol[hid] - 1])
    return window


def _hfield_fields(m: mujoco.MjModel, geoms: list[int], pairs: list[tuple[int, int]]) -> dict:
    """``Model``'s height-field fields for the height fields of ``geoms``: elevation data (0..1,
    scaled by ``hfield_size[2]``) and the cell window examined around each pair's other geom."""
    hfields = sorted({int(m.geom_dataid[g]) for g in geoms if m.geom_type[g] == GeomType.HFIELD})
    geom_hfieldid = np.full(m.ngeom, -1, np.int32)
    for k, hid in enumerate(hfields):
        geom_hfieldid[(m.geom_type == GeomType.HFIELD) & (m.geom_dataid == hid)] = k
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    hf_data = [
        m.hfield_data[m.hfield_adr[h] : m.hfield_adr[h] + m.hfield_nrow[h] * m.hfield_ncol[h]]
        for h in hfields
    ]
    hf_num = [m.hfield_nrow[h] * m.hfield_ncol[h] for h in hfields]
    return dict(
        geom_hfieldid=geom_hfieldid,
        hfield_nrow=np.asarray([m.hfield_nrow[h] for h in hfields], np.int32),
        hfield_ncol=np.asarray([m.hfield_ncol[h] for h in hfields], np.int32),
        hfield_adr=np.asarray(np.cumsum([0] + hf_num)[:-1], np.int32), pair_window=_hfield_windows(m, pairs),
        hfield_size=f(np.asarray([m.hfield_size[h] for h in hfields]).reshape(-1, 4)),
        hfield_data=f(np.concatenate(hf_data) if hf_data else np.zeros(0)),
    )  # fmt: skip


def _geometry_fields(m: mujoco.MjModel, pairs: list[tuple[int, int]]) -> dict:
    """``Model``'s mesh and height-field fields, for the geoms of the colliding pairs only
    (``_mesh_fields``, ``_hfield_fields``), and every geom's bounding radius."""
    geoms = sorted({g for pair in pairs for g in pair})
    mesh_geoms = [g for g in geoms if m.geom_type[g] == GeomType.MESH]
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return {**_mesh_fields(m, mesh_geoms), **_hfield_fields(m, geoms, pairs), "geom_rbound": f(m.geom_rbound)}


def _faceclip(m: mujoco.MjModel, g1: np.ndarray, g2: np.ndarray, margin: np.ndarray) -> dict:
    """``multiccd`` (False: ``<flag multiccd="disable"/>``, one contact per convex pair) and
    ``pair_faceclip``: the pairs MuJoCo gives its face-clipping multi-contact, a mesh against a
    mesh or a box with no margin (with a margin it searches by perturbation)."""
    flat = lambda g: np.isin(m.geom_type[g], [GeomType.BOX, GeomType.MESH])  # noqa: E731
    mesh = (m.geom_type[g1] == GeomType.MESH) | (m.geom_type[g2] == GeomType.MESH)
    multi = not m.opt.disableflags & _DSBL.mjDSBL_MULTICCD
    return {
        "multiccd": multi,
        "pair_faceclip": flat(g1) & flat(g2) & mesh & (np.asarray(margin) == 0) & multi,
    }


def _default_slots(m: mujoco.MjModel, pairs: list[tuple[int, int]], geometry: dict) -> int:
    """Contact slots when the scene does not set ``nconmax``: ``default_nconmax`` of the candidates
    (as ``collision_driver.contact_layout`` lays them out from ``geometry``'s pair window and
    face-clipping flags), plus one slot per height-field
    candidate. On rough terrain a foot often touches several prisms at once (MuJoCo C reports 9
    contacts for the Barkour's four feet on its terrain at rest), so those candidates all keep a
    slot rather than share a quarter of one."""
    window, faceclip = geometry["pair_window"], geometry["pair_faceclip"]
    groups: dict[tuple, list[int]] = {}
    for k, (a, b) in enumerate(pairs):
        key = (int(m.geom_type[a]), int(m.geom_type[b])) + ((FACES,) if faceclip[k] else ())
        groups.setdefault(key, []).append(k)
    other = terrain = 0
    single = m.opt.disableflags & _DSBL.mjDSBL_MULTICCD
    for key, ks in groups.items():
        count = 1 if single and key in GJK_PAIRS else SUPPORTED[key][1]
        if count is None:  # a height field: two prisms per cell of the group's window
            terrain += len(ks) * 2 * int(np.prod(window[ks].max(axis=0)))
        else:
            other += len(ks) * count
    return default_nconmax(other) + terrain


def contact_fields(
    m: mujoco.MjModel, pairs: list[tuple[int, int]], nconmax: int | None, caps: tuple[int, int]
) -> dict:
    """``Model``'s pair table for the candidate ``pairs`` (each pair's geoms, mixed parameters and
    shape data), its contact slots and MJX's pair cap; ``caps``: MJX's ``(max_geom_pairs,
    max_contact_points)``, -1 for each not honoured."""
    mixed = _mix_pair_params(m, pairs)
    g1 = np.array([p[0] for p in pairs], np.int32)
    g2 = np.array([p[1] for p in pairs], np.int32)
    geometry = _geometry_fields(m, pairs) | _faceclip(m, g1, g2, mixed["margin"])
    max_pairs, max_points = caps
    if nconmax is None:  # <size nconmax>, else MJX's max_contact_points, else the rule
        named = [n for n in (m.nconmax, max_points) if n > 0]
        nconmax = named[0] if named else _default_slots(m, pairs, geometry)
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return dict(
        **geometry, pair_geom1=g1, pair_geom2=g2, pair_condim=mixed["condim"],
        nconmax=int(nconmax), max_geom_pairs=int(max_pairs),
        pair_friction=f(mixed["friction"]), pair_solref=f(mixed["solref"]),
        pair_solimp=f(mixed["solimp"]), pair_solreffriction=f(mixed["solreffriction"]),
        pair_margin=f(mixed["margin"]), pair_gap=f(mixed["gap"]),
    )  # fmt: skip
