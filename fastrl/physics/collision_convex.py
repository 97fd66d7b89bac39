"""Collisions with convex meshes and height fields, as MuJoCo computes them.

Same contract as ``collision_primitive``: each function handles one geom-type pair, returns a
fixed number of candidate contacts ``(dist, pos, normal, tangent)`` and is vmapped by the driver;
a candidate MuJoCo would not report gets ``dist = _FAR`` (beyond any margin, so masked inactive).

- **Plane-mesh** (``mjc_PlaneConvex`` as MuJoCo 4.0 runs it): the vertex deepest below the
  plane, then the hull polygon through that vertex whose normal points most squarely into the
  plane. A polygon of more than four corners is pruned to a quadrilateral that keeps the deepest
  vertex: starting from it and the next three corners, the last, third and second corners
  advance while the area (half the cross product of the diagonals) grows. Of the four, those
  within the margin and not above the mesh's centre give contacts. The last public MuJoCo source
  we can read takes hull-graph neighbours instead; this rule gives MuJoCo 4.0's contacts in every
  one of 1500 random poses of each of Menagerie Spot's four collision meshes (11-gon faces).
- **Plane-ellipsoid**: the ellipsoid's deepest point, one contact (``mjc_PlaneConvex``).
- **Height field-sphere** follows ``mjc_ConvexHField``: the field is a grid of triangular prisms
  (two per cell, from the cell's top surface down to the base), and each prism the sphere
  comes within the margin of gives one contact. MuJoCo's GJK shrinks the sphere to its centre and
  inflates the result, so a contact is the centre's closest point on the prism (or, with the
  centre inside it, the nearest face), exactly what is computed here in closed form; the
  distance is the plain surface distance, and the cells examined are those under the sphere's
  box grown by the margin (as MuJoCo 4.0 reports them). Only a fixed window of
  cells around the sphere is examined (``Model.pair_window``), so the cost does not depend on the
  terrain's size. Candidates: two per cell of the window.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import collision_ccd as ccd
from fastrl.physics import collision_gjk as gjk
from fastrl.physics import collision_manifold as manifold
from fastrl.physics.collision_primitive import _FAR, _normalize
from fastrl.physics.math import cross, dot
from fastrl.physics.types import GeomType


def plane_mesh(p_pos, p_mat, p_size, m_pos, m_mat, m_size, verts, polymap, polyvert, polynormal, margin):
    """Four contacts: the deepest vertex, then the corners of the hull polygon it lies on that
    faces the plane most squarely, pruned to a large quadrilateral that keeps the deepest vertex
    (see module doc)."""
    del p_size, m_size
    normal = p_mat[:, 2]
    best = jnp.argmax(verts @ (m_mat.T @ -normal))
    polys = polymap[best]
    facing = jnp.where(polys >= 0, (polynormal[jnp.maximum(polys, 0)] @ m_mat.T) @ normal, jnp.inf)
    face = polyvert[polys[jnp.argmin(facing)]]
    if face.shape[0] < 4:  # triangles only: pad to the four candidates
        face = jnp.concatenate([face, jnp.full(4 - face.shape[0], -1, face.dtype)])
    n = jnp.sum(face >= 0)
    # From the deepest vertex's place in the face: the face itself when it has up to four
    # corners (in order from there), else the walk to a large quadrilateral that keeps it.
    pick = face[manifold.quad(verts[jnp.maximum(face, 0)], n, first=jnp.argmax(face == best))]
    points = m_pos + verts[jnp.maximum(pick, 0)] @ m_mat.T
    dist = (points - p_pos) @ normal
    below = (points - m_pos) @ normal <= 0  # not above the mesh's centre
    used = ((dist <= margin) & below & (jnp.arange(4) < n)).at[0].set(True)
    dist = jnp.where(used, dist, _FAR)
    pos = points - 0.5 * dist[:, None] * normal
    return dist, pos, jnp.tile(normal, (4, 1)), jnp.zeros((4, 3), normal.dtype)


def plane_ellipsoid(p_pos, p_mat, p_size, e_pos, e_mat, e_size):
    """One contact: the ellipsoid's point deepest below the plane (its support point along the
    plane's inward normal), as ``mjc_PlaneConvex`` gives it for an ellipsoid."""
    del p_size
    normal = p_mat[:, 2]
    scaled = e_size * (e_mat.T @ -normal)
    point = e_pos + e_mat @ (e_size * scaled / jnp.maximum(jnp.linalg.norm(scaled), 1e-30))
    dist = dot(normal, point - p_pos)
    return dist[None], (point - 0.5 * dist * normal)[None], normal[None], jnp.zeros((1, 3), normal.dtype)


# The prism's vertices: 0-2 the bottom triangle, 3-5 the top one, each above its bottom vertex;
# its side faces, by bottom vertex pairs (the order of ``_prism_faces``), and its edges.
_PRISM_SIDES = ((0, 1), (1, 2), (2, 0))
_PRISM_EDGES = ((0, 1), (1, 2), (2, 0), (3, 4), (4, 5), (5, 3), (0, 3), (1, 4), (2, 5))


def _prism_faces(prism):
    """Outward unit normals (5, 3) and a point of each face: top, bottom, three sides."""
    top = cross(prism[4] - prism[3], prism[5] - prism[3])
    top = top * jnp.sign(top[2])
    normals, points = [top, jnp.array([0.0, 0.0, -1.0], prism.dtype)], [prism[3], prism[0]]
    centre = jnp.mean(prism[:3], axis=0)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        side = cross(prism[j] - prism[i], jnp.array([0.0, 0.0, 1.0], prism.dtype))
        normals.append(side * jnp.sign(dot(side, prism[i] - centre)))
        points.append(prism[i])
    normals = jnp.stack(normals)
    return normals / jnp.linalg.norm(normals, axis=-1, keepdims=True), jnp.stack(points)


def _on_faces(prism, proj):
    """Whether each face plane's nearest point ``proj`` (5, 3) lies on that face. The top and
    bottom faces lie over the same triangle in x and y, and each side face is a vertical
    trapezoid from the base up to the top triangle's edge."""
    xy = prism[:3, :2]

    def over_triangle(p):
        e, w = jnp.roll(xy, -1, axis=0) - xy, p - xy  # each side's direction; p from its first vertex
        s = e[:, 0] * w[:, 1] - e[:, 1] * w[:, 0]  # which side of each p lies
        return jnp.all(s >= 0) | jnp.all(s <= 0)

    on = [over_triangle(proj[0, :2]), over_triangle(proj[1, :2])]
    for k, (i, j) in enumerate(_PRISM_SIDES):
        e = xy[j] - xy[i]
        t = dot(proj[2 + k, :2] - xy[i], e) / jnp.maximum(dot(e, e), 1e-30)
        top = prism[3 + i, 2] + t * (prism[3 + j, 2] - prism[3 + i, 2])
        z = proj[2 + k, 2]
        on.append((t >= 0) & (t <= 1) & (z >= prism[i, 2]) & (z <= top))
    return jnp.stack(on)


def _sphere_prism(centre, radius, prism):
    """Contact of a sphere with a convex prism, as MuJoCo's GJK/EPA on the sphere's centre gives it:
    ``(dist, pos, normal)`` with the normal from the prism to the sphere.

    Outside the prism the centre's closest point lies inside a face (the face plane's nearest
    point, where that lies on the face) or on one of the 9 edges, so it is the nearest of those 14
    candidates. Inside, the contact leaves through the nearest face."""
    normals, points = _prism_faces(prism)
    height = jnp.sum((centre - points) * normals, axis=-1)  # > 0 outside that face
    inside = jnp.all(height <= 0)
    proj = centre - height[:, None] * normals
    a = prism[np.array([e[0] for e in _PRISM_EDGES])]
    ab = prism[np.array([e[1] for e in _PRISM_EDGES])] - a
    t = jnp.clip(jnp.sum((centre - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-30), 0.0, 1.0)
    candidates = jnp.concatenate([proj, a + t[:, None] * ab])
    far = jnp.concatenate([~_on_faces(prism, proj), jnp.zeros(len(_PRISM_EDGES), bool)])
    q = candidates[jnp.argmin(jnp.where(far, jnp.inf, jnp.sum((candidates - centre) ** 2, axis=-1)))]
    # Outside: along the centre's closest point. Inside: out through the nearest face.
    n_out, gap = _normalize(centre - q)
    face = jnp.argmax(height)
    n = jnp.where(inside, normals[face], n_out)
    x1 = jnp.where(inside, centre - height[face] * n, q)  # on the prism
    dist = jnp.where(inside, height[face], gap) - radius
    x2 = centre - radius * n  # on the sphere
    return dist, 0.5 * (x1 + x2), n


def _window_prisms(h_size, heights, adr, nrow, ncol, lo, hi, window):
    """The window's prisms ``(2 * rows * cols, 6, 3)`` in the field's frame and which lie within
    MuJoCo's sub-grid ``[lo, hi]`` (rows, columns) of cells."""
    rows, cols = window
    dx = 2 * h_size[0] / (ncol - 1)
    dy = 2 * h_size[1] / (nrow - 1)
    r = lo[0] + jnp.arange(rows)[:, None]
    c = lo[1] + 1 + jnp.arange(cols)[None, :]
    active = (r < hi[0]) & (c <= hi[1])

    def corner(dr, dc):
        row, col = r + dr, c - 1 + dc
        z = heights[adr + jnp.clip(row, 0, nrow - 1) * ncol + jnp.clip(col, 0, ncol - 1)]
        top = jnp.stack(jnp.broadcast_arrays(dx * col - h_size[0], dy * row - h_size[1], z * h_size[2]), -1)
        return top

    # MuJoCo's two triangles of cell (r, c-1..c): its diagonal runs from (r, c-1) to (r+1, c).
    tris = [(corner(1, 0), corner(0, 0), corner(1, 1)), (corner(0, 0), corner(1, 1), corner(0, 1))]
    prisms = []
    for t in tris:
        top = jnp.stack(t, axis=-2)  # (rows, cols, 3, 3)
        bottom = top.at[..., 2].set(-h_size[3])
        prisms.append(jnp.concatenate([bottom, top], axis=-2))
    prisms = jnp.stack(prisms, axis=2).reshape(-1, 6, 3)  # cell by cell, triangle 0 then 1
    active = jnp.repeat(active.reshape(-1), 2)
    return prisms, active


def _hfield(
    h_pos, h_mat, local, lo_xyz, hi_xyz, collide, heights, adr, nrow, ncol, hsize, rbound, margin, window
):
    """Candidates of a geom against the window's prisms: ``collide(prism)`` gives one contact in
    the field's frame; ``local`` is the geom's centre there and ``lo_xyz``/``hi_xyz`` its box."""
    reach = rbound + margin
    inside = (
        jnp.all(jnp.abs(local[:2]) <= hsize[:2] + reach)
        & (local[2] - reach <= hsize[2])
        & (local[2] + reach >= -hsize[3])
    )
    lo_xy, hi_xy = lo_xyz[:2] - margin, hi_xyz[:2] + margin
    inside &= jnp.all(lo_xy <= hsize[:2]) & jnp.all(hi_xy >= -hsize[:2])
    inside &= (lo_xyz[2] - margin <= hsize[2]) & (hi_xyz[2] + margin >= -hsize[3])
    cells = jnp.stack([nrow, ncol]) - 1
    half = hsize[1::-1]  # (y, x): rows run along y, columns along x
    lo = jnp.maximum(jnp.floor((lo_xy[::-1] + half) / (2.0 * half) * cells).astype(jnp.int32), 0)
    hi = jnp.minimum(jnp.ceil((hi_xy[::-1] + half) / (2.0 * half) * cells).astype(jnp.int32), cells)
    prisms, active = _window_prisms(hsize, heights, adr, nrow, ncol, lo, hi, window)
    dist, pos, normal = jax.vmap(collide)(prisms)
    below = jnp.all(prisms[:, 3:, 2] + margin < lo_xyz[2], axis=-1)  # the prism height test
    keep = inside & active & ~below & (dist < margin)
    dist = jnp.where(keep, dist, _FAR)
    return dist, h_pos + pos @ h_mat.T, normal @ h_mat.T, jnp.zeros_like(pos)


def hfield_sphere(
    h_pos, h_mat, h_size, s_pos, s_mat, s_size, heights, adr, nrow, ncol, hsize, rbound, margin, *, window
):
    """One candidate per prism of the window (see module doc), the normal from field to sphere."""
    del h_size, s_mat
    local = h_mat.T @ (s_pos - h_pos)
    radius = s_size[0]
    collide = functools.partial(_sphere_prism, local, radius)
    field = (heights, adr, nrow, ncol, hsize, rbound, margin, window)
    return _hfield(h_pos, h_mat, local, local - radius, local + radius, collide, *field)


_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)


def _segments_closest(a0, a1, b0, b1):
    """Closest points of segments [a0, a1] and [b0, b1] (clamped line parameters)."""
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    uu, uv, vv, uw, vw = dot(u, u), dot(u, v), dot(v, v), dot(u, w), dot(v, w)
    den = jnp.maximum(uu * vv - uv * uv, 1e-30)
    s = jnp.clip((uv * vw - vv * uw) / den, 0.0, 1.0)
    t = jnp.clip((uv * s + vw) / jnp.maximum(vv, 1e-30), 0.0, 1.0)
    s = jnp.clip((uv * t - uw) / jnp.maximum(uu, 1e-30), 0.0, 1.0)
    return a0 + s * u, b0 + t * v


def _box_prism(centre, rot, half, prism):
    """Contact of a box with a convex prism by separating axes (both polytopes, so the minimum
    over face normals and edge-edge cross products is the exact penetration, as MuJoCo's EPA
    finds it): ``(dist, pos, normal)``, the normal from the prism to the box. The contact point
    is midway between the witnesses: the box's deepest corner (a prism face), the prism's deepest
    corner (a box face), or the two edges' closest points; tied corners are averaged."""
    signs = jnp.asarray(_SIGNS, half.dtype)
    corners = centre + (signs * half) @ rot.T
    faces, _ = _prism_faces(prism)
    pe = jnp.stack([prism[j] - prism[i] for i, j in _PRISM_EDGES])
    cross_axes = jnp.cross(rot.T[:, None, :], pe[None, :, :]).reshape(-1, 3)
    lengths = jnp.linalg.norm(cross_axes, axis=-1)
    usable = lengths > 1e-9 * jnp.max(lengths)
    axes = jnp.concatenate([faces, rot.T, cross_axes / jnp.where(usable, lengths, 1.0)[:, None]])
    valid = jnp.concatenate([jnp.ones(8, bool), usable])
    pb, pp = corners @ axes.T, prism @ axes.T  # (8, A), (6, A)
    up = pp.max(0) - pb.min(0)  # overlap with the box on the + side of the axis
    down = pb.max(0) - pp.min(0)
    overlap = jnp.where(valid, jnp.minimum(up, down), jnp.inf)
    k = jnp.argmin(overlap)
    depth = overlap[k]
    n = jnp.where(up[k] <= down[k], axes[k], -axes[k])
    tol = 1e-9 * (1.0 + jnp.max(jnp.abs(half)))
    box_d, prism_d = corners @ n, prism @ n
    deep_box = box_d <= box_d.min() + tol
    deep_prism = prism_d >= prism_d.max() - tol
    box_pt = jnp.sum(corners * deep_box[:, None], 0) / jnp.sum(deep_box)
    prism_pt = jnp.sum(prism * deep_prism[:, None], 0) / jnp.sum(deep_prism)
    # Edge-edge: the box edge along axis i nearest the prism, against prism edge j.
    i, j = jnp.maximum(k - 8, 0) // 9, jnp.maximum(k - 8, 0) % 9
    along = rot[:, i] * half[i]
    mids = corners - (signs[:, i][:, None] * along)  # each corner's edge midpoint along axis i
    mid = mids[jnp.argmin(mids @ n)]
    edges = jnp.asarray(_PRISM_EDGES)
    x1e, x2e = _segments_closest(prism[edges[j, 0]], prism[edges[j, 1]], mid - along, mid + along)
    face_of_prism, face_of_box = k < 5, (k >= 5) & (k < 8)
    x2 = jnp.where(face_of_prism, box_pt, jnp.where(face_of_box, prism_pt - depth * n, x2e))
    x1 = jnp.where(face_of_prism, box_pt + depth * n, jnp.where(face_of_box, prism_pt, x1e))
    return -depth, 0.5 * (x1 + x2), n


def hfield_box(
    h_pos, h_mat, h_size, b_pos, b_mat, b_size, heights, adr, nrow, ncol, hsize, rbound, margin, *, window
):
    """One candidate per prism of the window, by separating axes (``_box_prism``)."""
    del h_size
    local = h_mat.T @ (b_pos - h_pos)
    rot = h_mat.T @ b_mat
    extent = jnp.abs(rot) @ b_size
    collide = functools.partial(_box_prism, local, rot, b_size)
    field = (heights, adr, nrow, ncol, hsize, rbound, margin, window)
    return _hfield(h_pos, h_mat, local, local - extent, local + extent, collide, *field)


def hfield_convex(gtype: int):
    """Height field against a capsule, cylinder, ellipsoid or mesh: each prism of the window as a
    six-vertex hull against the geom by GJK/EPA (``collision_gjk``), one contact per prism, as
    MuJoCo's ``mjc_ConvexHField`` runs its GJK/EPA on each prism."""
    contact = ccd.single_contact(GeomType.MESH, gtype)

    def collide(
        h_pos,
        h_mat,
        h_size,
        g_pos,
        g_mat,
        g_size,
        verts,
        heights,
        adr,
        nrow,
        ncol,
        hsize,
        rbound,
        margin,
        *,
        window,
    ):
        del h_size
        local = h_mat.T @ (g_pos - h_pos)
        rot = h_mat.T @ g_mat
        support = lambda d: gjk.support(gtype, local, rot, g_size, verts, d)  # noqa: E731
        radius = gjk.core_radius(gtype, g_size)
        lo = jnp.stack([support(-e)[i] for i, e in enumerate(jnp.eye(3, dtype=local.dtype))]) - radius
        hi = jnp.stack([support(e)[i] for i, e in enumerate(jnp.eye(3, dtype=local.dtype))]) + radius
        eye, zero = jnp.eye(3, dtype=local.dtype), jnp.zeros(3, local.dtype)
        prism_contact = lambda prism: contact(zero, eye, zero, local, rot, g_size, prism, verts)  # noqa: E731
        field = (heights, adr, nrow, ncol, hsize, rbound, margin, window)
        return _hfield(h_pos, h_mat, local, lo, hi, prism_contact, *field)

    return collide
