"""Mesh and height-field collisions against MuJoCo C (float64).

Contacts are compared with ``mjData.contact`` after ``mj_forward`` over random poses: the same
set of contacts (distance, position, normal). Then whole trajectories: meshes dropped on a plane
and spheres rolling over rough terrain, against ``mj_step``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import collision_ccd as ccd
from fastrl.physics import collision_convex as convex
from fastrl.physics.collision_driver import Convex, contact_layout, gjk_slots, pair_groups
from fastrl.physics.collision_primitive import _FAR
from fastrl.physics.types import GeomType

_RNG = np.random.default_rng(3)
_RNG_GRAD = np.random.default_rng(11)
_ROCK = _RNG.standard_normal((40, 3)) * [0.08, 0.05, 0.04]
_CUBE = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])


def _vertex(points: np.ndarray) -> str:
    return " ".join(f"{v:.6f}" for v in points.ravel())


MESHES_XML = f"""
<mujoco>
  <option timestep="0.002"/>
  <asset>
    <mesh name="rock" vertex="{_vertex(_ROCK)}"/>
    <mesh name="cube" vertex="{_vertex(_CUBE)}"/>
  </asset>
  <worldbody>
    <geom type="plane" size="3 3 .1" margin="0.01"/>
    <body name="rock" pos="0 0 0.3"><freejoint/><geom type="mesh" mesh="rock"/></body>
    <body name="cube" pos="0.6 0 0.3"><freejoint/><geom type="mesh" mesh="cube" margin="0.005"/></body>
  </worldbody>
  <contact>
    <exclude body1="rock" body2="cube"/>
  </contact>
</mujoco>"""

HFIELD_XML = """
<mujoco>
  <option timestep="0.002"/>
  <asset><hfield name="terrain" nrow="21" ncol="25" size="1.2 1 0.15 0.1"/></asset>
  <worldbody>
    <geom type="hfield" hfield="terrain"/>
    <body pos="0.13 0.07 0.4"><freejoint/><geom type="sphere" size="0.06"/></body>
    <body pos="-0.3 0.2 0.4"><freejoint/><geom type="sphere" size="0.03" margin="0.004"/></body>
  </worldbody>
</mujoco>"""


def _compile(xml: str) -> mujoco.MjModel:
    mj = mujoco.MjModel.from_xml_string(xml)
    if mj.nhfield:  # smooth random terrain
        rows, cols = mj.hfield_nrow[0], mj.hfield_ncol[0]
        y, x = np.meshgrid(np.linspace(0, 3, rows), np.linspace(0, 4, cols), indexing="ij")
        mj.hfield_data[:] = (
            0.5 + 0.25 * np.sin(2.1 * x + 0.3) * np.cos(1.7 * y) + 0.2 * _RNG.uniform(size=x.shape)
        ).ravel()
    return mj


def _random_poses(mj: mujoco.MjModel, rng: np.random.Generator, n: int, height) -> np.ndarray:
    out = np.tile(mj.qpos0, (n, 1))
    for b in range(mj.njnt):
        quat = rng.standard_normal((n, 4))
        out[:, 7 * b : 7 * b + 3] = np.c_[rng.uniform(-1, 1, (n, 2)), rng.uniform(*height, n)]
        out[:, 7 * b + 3 : 7 * b + 7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out


def _contacts(mj: mujoco.MjModel, qposes: np.ndarray):
    """MuJoCo's and fastrl's contacts per pose: sorted (geom1, geom2, dist, pos, normal) rows."""
    m = physics.model_from_mujoco(mj)
    md = mujoco.MjData(mj)
    layout = contact_layout(m)
    fwd = jax.jit(jax.vmap(physics.forward, (None, 0)))
    d = jax.vmap(lambda q: physics.make_data(m).replace(qpos=q))(jnp.asarray(qposes))
    d = fwd(m, d)
    dist, pos, frame = (np.asarray(x) for x in (d.contact_dist, d.contact_pos, d.contact_frame))
    active = dist < np.asarray(m.pair_margin)[layout]
    g1, g2 = m.pair_geom1[layout], m.pair_geom2[layout]
    theirs, ours = [], []
    for k, qpos in enumerate(qposes):
        md.qpos[:] = qpos
        mujoco.mj_forward(mj, md)
        ref = [(c.geom1, c.geom2, c.dist, *c.pos, *c.frame[:3]) for c in md.contact[: md.ncon]]
        mine = [(g1[i], g2[i], dist[k, i], *pos[k, i], *frame[k, i, 0]) for i in np.flatnonzero(active[k])]
        theirs.append(np.array(sorted(ref)).reshape(-1, 9))
        ours.append(np.array(sorted(mine)).reshape(-1, 9))
    return theirs, ours


def test_plane_mesh_contacts_match_mujoco(x64):
    """Rock (triangular hull faces) and cube mesh (square faces, a margin): every contact of 600
    random poses near and through the plane, to rounding."""
    mj = _compile(MESHES_XML)
    rng = np.random.default_rng(0)
    qposes = _random_poses(mj, rng, 500, (-0.02, 0.12))
    flat = _random_poses(mj, rng, 100, (0.02, 0.06))  # nearly flat: a face down
    tilt = rng.uniform(-0.02, 0.02, (100, 3))
    for b in range(mj.njnt):
        flat[:, 7 * b + 3 : 7 * b + 7] = np.c_[np.ones(100), 0.5 * tilt]
        flat[:, 7 * b + 3 : 7 * b + 7] /= np.linalg.norm(
            flat[:, 7 * b + 3 : 7 * b + 7], axis=1, keepdims=True
        )
    theirs, ours = _contacts(mj, np.concatenate([qposes, flat]))
    counts = [len(t) for t in theirs]
    assert sum(counts) > 1000 and max(counts) >= 7
    for t, o in zip(theirs, ours, strict=True):
        assert t.shape == o.shape
        np.testing.assert_allclose(o, t, atol=1e-9)


def test_plane_mesh_on_large_faces_matches_mujoco(x64):
    """A prism over an irregular 11-gon (the kind of face Menagerie's foot meshes have): the deepest
    vertex's face is pruned to MuJoCo's quadrilateral. Every contact of 400 poses, to rounding,
    half of them with a cap nearly flat on the plane."""
    rng = np.random.default_rng(11)
    angle = np.sort(rng.uniform(0, 2 * np.pi, 11))
    ring = np.c_[0.05 * np.cos(angle), 0.04 * np.sin(angle)]
    prism = np.concatenate([np.c_[ring, np.full(11, -0.02)], np.c_[ring, np.full(11, 0.02)]])
    mj = mujoco.MjModel.from_xml_string(
        f'<mujoco><asset><mesh name="prism" vertex="{_vertex(prism)}"/></asset><worldbody>'
        '<geom type="plane" size="3 3 .1"/><body><freejoint/><geom type="mesh" mesh="prism"/>'
        "</body></worldbody></mujoco>"
    )
    qposes = _random_poses(mj, rng, 400, (0.0, 0.06))
    tilt = np.c_[np.ones(200), rng.uniform(-0.1, 0.1, (200, 2)), np.zeros(200)]
    qposes[:200, 2] = rng.uniform(0.0, 0.025, 200)
    qposes[:200, 3:7] = tilt / np.linalg.norm(tilt, axis=1, keepdims=True)
    theirs, ours = _contacts(mj, qposes)
    assert sum(len(t) >= 3 for t in theirs) > 50
    for t, o in zip(theirs, ours, strict=True):
        assert t.shape == o.shape
        np.testing.assert_allclose(o, t, atol=1e-9)


def test_hfield_sphere_contacts_match_mujoco(x64):
    """Two spheres (one with a margin) over rough terrain: the same prisms touched, and each
    contact to rounding while the centre stays outside the prism (MuJoCo's GJK then is exact);
    deeper, MuJoCo's EPA answers only to its tolerance."""
    mj = _compile(HFIELD_XML)
    rng = np.random.default_rng(1)
    qposes = _random_poses(mj, rng, 400, (0.0, 0.25))
    qposes[:, [0, 7]] *= 1.25  # some beyond the field's edge
    theirs, ours = _contacts(mj, qposes)
    assert sum(len(t) for t in theirs) > 600
    for t, o in zip(theirs, ours, strict=True):
        assert t.shape == o.shape
        shallow = t[:, 2] > -0.025
        np.testing.assert_allclose(o[shallow], t[shallow], atol=1e-9)
        np.testing.assert_allclose(o[~shallow], t[~shallow], atol=1e-3)


def _trajectory(mj: mujoco.MjModel, steps: int):
    m = physics.model_from_mujoco(mj)
    md = mujoco.MjData(mj)
    step = jax.jit(lambda d: jax.lax.fori_loop(0, 10, lambda _, x: physics.step(m, x), d))
    d = physics.make_data(m)
    ours, theirs = [], []
    for _ in range(steps // 10):
        d = step(d)
        for _ in range(10):
            mujoco.mj_step(mj, md)
        ours.append(np.asarray(d.qpos))
        theirs.append(md.qpos.copy())
    return np.array(ours), np.array(theirs)


@pytest.mark.parametrize("xml", [MESHES_XML, HFIELD_XML], ids=["meshes-on-plane", "spheres-on-terrain"])
def test_dropped_bodies_track_mujoco(xml, x64):
    """Dropped from 0.3 m (meshes tumble onto the plane; spheres land and roll over the
    terrain): qpos within 1e-6 of MuJoCo C over 1 s, and the bodies come to rest at MuJoCo's
    heights (no sinking)."""
    mj = _compile(xml)
    ours, theirs = _trajectory(mj, 500)
    assert np.max(np.abs(ours - theirs)) < 1e-6
    assert np.ptp(theirs[:, 2]) > 0.1  # they did fall


def test_box_prism_penetration_is_the_minimum_translation(x64):
    """Box against one terrain prism, by separating axes: the depth is the smallest overlap of
    the two shapes' supports over all directions (checked against sampled directions, 100k over
    the sphere then 100k near the best, whose minimum can only lie above the exact one), and
    along the normal the two overlap by exactly the depth."""
    rng = np.random.default_rng(4)
    dirs = rng.standard_normal((100_000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    collide = jax.jit(convex._box_prism)
    for _ in range(40):
        top = np.c_[rng.uniform(0, 0.1, (3, 2)), rng.uniform(0.0, 0.05, 3)]
        prism = np.r_[np.c_[top[:, :2], np.full(3, -0.1)], top]
        centre = top.mean(0) + [0, 0, rng.uniform(-0.01, 0.02)]
        quat = rng.standard_normal(4)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat / np.linalg.norm(quat))
        rot, half = rot.reshape(3, 3), rng.uniform(0.005, 0.04, 3)
        corners = centre + (convex._SIGNS * half) @ rot.T

        def overlap(d, prism=prism, corners=corners):
            pp, pb = prism @ d.T, corners @ d.T
            return np.minimum(pp.max(0) - pb.min(0), pb.max(0) - pp.min(0))

        coarse = dirs[np.argmin(overlap(dirs))]  # then finer around the best sampled direction
        fine = coarse + 0.02 * rng.standard_normal((100_000, 3))
        fine /= np.linalg.norm(fine, axis=1, keepdims=True)
        sampled = min(overlap(dirs).min(), overlap(fine).min())
        dist, _, normal = collide(
            jnp.asarray(centre), jnp.asarray(rot), jnp.asarray(half), jnp.asarray(prism)
        )
        depth = -float(dist)
        assert depth <= sampled + 1e-12 and sampled - depth < 1e-4
        n = np.asarray(normal)  # along it (prism to box) the two overlap by exactly the depth
        np.testing.assert_allclose((prism @ n).max() - (corners @ n).min(), depth, atol=1e-12)


def test_box_rests_on_terrain_at_mujocos_height(x64):
    """A tilted box dropped on a height field settles at MuJoCo C's height (within 0.1 mm) and
    stays there. Contact by contact the two differ: MuJoCo 4.0's native EPA reports box-prism
    penetrations shallower than the minimum translation this computes (its libccd path,
    ``<flag nativeccd="disable"/>``, agrees with fastrl's depths on most prisms)."""
    xml = """<mujoco><option timestep="0.002"/><asset><hfield name="t" nrow="11" ncol="11" size="1 1 .1 .1"/>
    </asset><worldbody><geom type="hfield" hfield="t"/><body pos="0.013 0.021 0.08" euler="3 2 0">
    <freejoint/><geom type="box" size="0.06 0.04 0.01"/></body></worldbody></mujoco>"""
    mj = mujoco.MjModel.from_xml_string(xml)
    mj.hfield_data[:] = 0.5
    ours, theirs = _trajectory(mj, 1000)
    assert np.abs(ours[-1, 2] - theirs[-1, 2]) < 1e-4
    assert np.ptp(ours[50:, 2]) < 1e-5  # at rest: no sinking


# Free bodies of every convex kind that GJK/EPA handles; explicit pairs select the pairs tested
# (some with a margin). MuJoCo's GJK/EPA runs to convergence, and its multi-contact is off (fastrl
# gives one contact per pair; see the next test for how often MuJoCo's default adds more).
_SHAPES = {
    "rock": 'type="mesh" mesh="rock"',
    "cube": 'type="mesh" mesh="cube"',
    "box": 'type="box" size="0.05 0.03 0.02"',
    "cyl": 'type="cylinder" size="0.04 0.05"',
    "cyl2": 'type="cylinder" size="0.02 0.06"',
    "ell": 'type="ellipsoid" size="0.05 0.03 0.04"',
    "ball": 'type="sphere" size="0.03"',
    "caps": 'type="capsule" size="0.02 0.05"',
}
_GJK_PAIRS = [("rock", "cube", 0), ("box", "rock", 0.01), ("ball", "rock", 0), ("caps", "cube", 0.005),
              ("cyl", "rock", 0), ("ell", "cube", 0), ("cyl", "cyl2", 0.01), ("cyl", "box", 0),
              ("ell", "box", 0), ("ell", "cyl2", 0)]  # fmt: skip


def _gjk_xml(multiccd: bool) -> str:
    bodies = "".join(
        f'<body name="{k}"><freejoint/><geom name="{k}" {v} contype="0" conaffinity="0"/></body>'
        for k, v in _SHAPES.items()
    )
    pairs = "".join(f'<pair geom1="{a}" geom2="{b}" margin="{mg}"/>' for a, b, mg in _GJK_PAIRS)
    flag = "" if multiccd else '<flag multiccd="disable"/>'
    return (
        f'<mujoco><option ccd_tolerance="1e-13" ccd_iterations="1000">{flag}</option><asset>'
        f'<mesh name="rock" vertex="{_vertex(_ROCK)}"/><mesh name="cube" vertex="{_vertex(_CUBE)}"/>'
        f"</asset><worldbody>{bodies}</worldbody><contact>{pairs}</contact></mujoco>"
    )


def _clustered_poses(mj: mujoco.MjModel, n: int) -> np.ndarray:
    """Random poses with every body within 12 cm of the origin, so most pairs touch or nearly."""
    rng = np.random.default_rng(5)
    qpos = _random_poses(mj, rng, n, (-0.06, 0.06))
    for b in range(mj.njnt):
        qpos[:, 7 * b : 7 * b + 2] = rng.uniform(-0.06, 0.06, (n, 2))
    return qpos


def _hull(m, g: int) -> jax.Array:
    """Geom ``g``'s hull vertices (a single zero vertex for a primitive)."""
    if m.geom_type[g] != GeomType.MESH:
        return jnp.zeros((1, 3))
    adr, num = m.mesh_vertadr[m.geom_meshid[g]], m.mesh_vertnum[m.geom_meshid[g]]
    return m.mesh_vert[adr : adr + num]


def test_type_pairs_of_one_gjk_program_share_a_group(x64):
    """Plain GJK/EPA pairs of different type pairs that share EPA's iteration count, their
    candidate count and a hull size form one group (one compiled GJK/EPA, each pair's types as
    data): here the cylinder's pairs with a cylinder and a box, the ellipsoid's with a box and a
    cylinder, and a box's and a capsule's with two meshes. Every contact of such a group is what
    its own type pair's function gives alone (float64): the depth to 1e-10, the position to 1e-5
    and the normal to 1e-4. They differ as compiled programs do, where EPA on a curved surface
    stops as rounding says it has converged; MuJoCo's own contacts are 3e-2 from either there
    (``test_gjk_epa_contacts_match_mujoco``)."""
    mj = _compile(_gjk_xml(multiccd=True))
    m = physics.model_from_mujoco(mj)
    mixed = [idx for k, idx in pair_groups(m) if isinstance(k, Convex) and len(k.types1) * len(k.types2) > 1]
    names = [
        {(mj.geom(int(m.pair_geom1[i])).name, mj.geom(int(m.pair_geom2[i])).name) for i in idx}
        for idx in mixed
    ]
    assert sorted(map(sorted, names)) == [
        [("box", "rock"), ("caps", "cube")],
        [("cyl", "box"), ("cyl", "cyl2")],
        [("ell", "box"), ("ell", "cyl2")],
    ]
    qpos = _clustered_poses(mj, 12)
    d = jax.jit(jax.vmap(lambda q: physics.forward(m, physics.make_data(m).replace(qpos=q))))(
        jnp.asarray(qpos)
    )
    assert _compared_to_alone(m, d, np.concatenate(mixed)) >= 20


def _compared_to_alone(m, d, pairs) -> int:
    """Asserts each of ``pairs``' contacts in ``d`` (a batch) is what its own type pair's GJK/EPA
    gives for that pair alone: the depth to 1e-10, the position to 1e-5, the normal to 1e-4 (float64);
    returns how many contacts were compared."""
    layout = contact_layout(m)
    compared = 0
    for p in pairs:
        g1, g2 = int(m.pair_geom1[p]), int(m.pair_geom2[p])
        alone = ccd.convex_pair(int(m.geom_type[g1]), int(m.geom_type[g2]))
        alone = jax.jit(jax.vmap(alone, (0, 0, None, 0, 0, None, None, None, None, None, None)))
        rbound = min(m.geom_rbound[g1], m.geom_rbound[g2])
        pose1 = (d.geom_xpos[:, g1], d.geom_xmat[:, g1], m.geom_size[g1])
        pose2 = (d.geom_xpos[:, g2], d.geom_xmat[:, g2], m.geom_size[g2])
        dist, pos, normal, _ = alone(
            *pose1, *pose2, _hull(m, g1), _hull(m, g2), None, m.pair_margin[p], rbound
        )
        ours = np.asarray(d.contact_dist[:, layout == p])
        found = ours < _FAR  # the group's cull keeps the pairs GJK finds within the margin
        assert found[np.asarray(dist[:, 0]) < m.pair_margin[p] - 1e-9, 0].all()
        close = functools.partial(np.testing.assert_allclose, rtol=0)
        close(ours[found], np.asarray(dist)[found], atol=1e-10)
        close(np.asarray(d.contact_pos[:, layout == p])[found], np.asarray(pos)[found], atol=1e-5)
        close(np.asarray(d.contact_frame[:, layout == p, 0])[found], np.asarray(normal)[found], atol=1e-4)
        compared += found.sum()
    return compared


def _sphere_points(n: int, radius: float) -> np.ndarray:
    """``n`` points spread over a sphere (a Fibonacci lattice): every one is a hull vertex."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    return radius * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def test_gjk_groups_take_hulls_over_half_their_size(x64):
    """GJK/EPA pairs are split by hull size from the largest down, each group taking every hull
    over half its size: a box against hulls of 50, 30 and 20 vertices makes the groups {50, 30}
    and {20} (padding at most doubles a support point's cost; power-of-two buckets would split
    50 from 30). A hull padded to its group's size gives the contacts it gives alone."""
    sizes = {"h50": 50, "h30": 30, "h20": 20}
    assets = "".join(
        f'<mesh name="{k}" vertex="{_vertex(_sphere_points(n, 0.05))}"/>' for k, n in sizes.items()
    )
    shapes = {"box": 'type="box" size="0.04 0.03 0.05"', **{k: f'type="mesh" mesh="{k}"' for k in sizes}}
    bodies = "".join(
        f'<body name="{k}"><freejoint/><geom name="{k}" {v} contype="0" conaffinity="0"/></body>'
        for k, v in shapes.items()
    )
    pairs = "".join(f'<pair geom1="box" geom2="{k}" margin="0.01"/>' for k in sizes)
    mj = _compile(
        f"<mujoco><asset>{assets}</asset><worldbody>{bodies}</worldbody><contact>{pairs}</contact></mujoco>"
    )
    m = physics.model_from_mujoco(mj)
    assert sorted(m.mesh_vertnum) == [20, 30, 50]
    groups = [idx for k, idx in pair_groups(m) if isinstance(k, Convex)]
    names = sorted(sorted(mj.geom(int(m.pair_geom2[i])).name for i in idx) for idx in groups)
    assert names == [["h20"], ["h30", "h50"]]
    qpos = _clustered_poses(mj, 12)
    d = jax.jit(jax.vmap(lambda q: physics.forward(m, physics.make_data(m).replace(qpos=q))))(
        jnp.asarray(qpos)
    )
    assert _compared_to_alone(m, d, next(idx for idx in groups if idx.size == 2)) >= 6


def test_gjk_epa_contacts_match_mujoco(x64):
    """Ten convex pairs (mesh-mesh, box/sphere/capsule/cylinder/ellipsoid against meshes,
    cylinder-cylinder, cylinder-box, ellipsoid-box/cylinder), margins included, with
    ``<flag multiccd="disable"/>`` (one contact a pair, on both sides): every contact over 100
    clustered random poses, apart and overlapping, against MuJoCo's GJK/EPA run to
    convergence: to rounding between polytopes (and sphere/capsule cores), and on cylinders and
    ellipsoids the depth within 1e-5 and the position and normal within 3e-2 (99% within 3e-4)."""
    mj = _compile(_gjk_xml(multiccd=False))
    theirs, ours = _contacts(mj, _clustered_poses(mj, 100))
    assert sum(len(t) for t in theirs) > 300
    curved = np.flatnonzero(
        np.isin(mj.geom_type, [mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_ELLIPSOID])
    )
    for t, o in zip(theirs, ours, strict=True):
        assert t.shape == o.shape
        bent = np.isin(t[:, 0], curved) | np.isin(t[:, 1], curved)
        np.testing.assert_allclose(o[~bent], t[~bent], atol=1e-6)  # polytopes, sphere/capsule cores
        # On a curved surface EPA's normal converges slowly (see collision_gjk.EPA_ITERATIONS).
        np.testing.assert_allclose(o[bent, :3], t[bent, :3], atol=1e-5)
        np.testing.assert_allclose(o[bent, 3:], t[bent, 3:], atol=3e-2)


def _touching(mj: mujoco.MjModel, rng: np.random.Generator, aligned: bool) -> np.ndarray:
    """A pose of the scene's two free bodies (the first at the origin) with the second slid in
    from a random direction until MuJoCo reports contact, then up to 1 cm deeper; ``aligned``:
    from above, turned a little, so that faces meet nearly flat."""
    md = mujoco.MjData(mj)
    quat = np.array([1.0, 0, 0, 0]) + rng.normal(0, 0.03, 4) if aligned else rng.normal(size=4)
    way = np.array([*rng.normal(0, 0.2, 2), 1.0]) if aligned else rng.normal(size=3)
    way /= np.linalg.norm(way)
    md.qpos[:] = np.r_[0, 0, 0, 1, 0, 0, 0, 2 * way, quat / np.linalg.norm(quat)]
    for scale in np.linspace(2, 0, 800):
        md.qpos[7:10] = way * scale
        mujoco.mj_forward(mj, md)
        if md.ncon:
            break
    md.qpos[7:10] = way * (scale - rng.uniform(0, 0.01))
    return md.qpos.copy()


FACE_PAIRS_XML = """<mujoco><option ccd_tolerance="1e-13" ccd_iterations="1000"/><asset>
<mesh name="cube" vertex="{cube}"/><mesh name="rock" vertex="{rock}"/></asset><worldbody>
<body><freejoint/><geom {first}/></body><body><freejoint/><geom type="mesh" mesh="{second}"/></body>
</worldbody></mujoco>"""


def test_face_clipped_contacts_match_mujoco(x64):
    """Boxes and meshes against meshes with no margin: MuJoCo's face-clipping multi-contact
    (MuJoCo's GJK/EPA converged). Faces meeting nearly flat give 2-4 contacts, edges on faces 2,
    other touches 1; over 90 poses at least 90% give MuJoCo's contacts to 1e-6 (measured: 88 of 90;
    the rest are edges on faces where fastrl's EPA ends on another face of the Minkowski
    difference and keeps its single contact where MuJoCo clips the edge to two)."""
    rng = np.random.default_rng(0)
    box = 'type="box" size="0.1 0.08 0.03"'
    same, counts, total = 0, set(), 0
    for first, second in ((box, "cube"), ('type="mesh" mesh="cube"', "cube"), (box, "rock")):
        xml = FACE_PAIRS_XML.format(
            cube=_vertex(_CUBE), rock=_vertex(_ROCK * 0.7), first=first, second=second
        )
        mj = mujoco.MjModel.from_xml_string(xml)
        poses = np.stack([_touching(mj, rng, aligned=k % 2 == 1) for k in range(30)])
        for theirs, ours in zip(*_contacts(mj, poses), strict=True):
            total += 1
            if theirs.shape == ours.shape and np.allclose(theirs, ours, atol=1e-6):
                same += 1
                counts.add(len(theirs))
    assert same >= 0.9 * total, (same, total)
    assert {1, 2, 4} <= counts


def test_meshes_rest_on_a_box_at_mujocos_height(x64):
    """The cube and the rock meshes dropped on a box come to rest within 1 mm of MuJoCo C's
    heights (4 s) and stay there (the last 2 s): one contact per pair could not hold a face up; the extra
    contacts of the multi-contact search do (their points differ from MuJoCo 4.0's clipped faces,
    so the two part while they tumble; the rest heights agree)."""
    xml = f"""<mujoco><option timestep="0.002"/><asset><mesh name="cube" vertex="{_vertex(_CUBE)}"/>
    <mesh name="rock" vertex="{_vertex(_ROCK)}"/></asset><worldbody><geom type="box" size="0.5 0.5 0.05"/>
    <body pos="0 0 0.2" euler="0.1 0.05 0"><freejoint/><geom type="mesh" mesh="cube"/></body>
    <body pos="0.3 0 0.15"><freejoint/><geom type="mesh" mesh="rock"/></body></worldbody></mujoco>"""
    mj = mujoco.MjModel.from_xml_string(xml)
    ours, theirs = _trajectory(mj, 2000)
    z = [2, 9]
    assert np.all(np.abs(ours[-1, z] - theirs[-1, z]) < 1e-3)
    assert np.all(np.ptp(ours[100:, z], axis=0) < 1e-4)  # the last 2 s: no sinking


def test_mesh_slides_to_mujocos_stop(x64):
    """The cube mesh pushed along the plane at 1 m/s slides to MuJoCo C's stop (within 2%; in
    fact to rounding) and rests there."""
    mj = _compile(MESHES_XML)
    mj.body_pos[1:, 2] = [0.15, 0.0499]  # the rock out of the way, the cube resting on the plane
    md = mujoco.MjData(mj)
    md.qvel[6] = 1.0
    m = physics.model_from_mujoco(mj)
    d = physics.make_data(m).replace(qvel=jnp.asarray(md.qvel))
    run = jax.jit(lambda d: jax.lax.fori_loop(0, 500, lambda _, x: physics.step(m, x), d))
    d = run(d)
    for _ in range(500):
        mujoco.mj_step(mj, md)
    travelled = md.qpos[7] - mj.body_pos[2, 0]
    assert travelled > 0.05
    assert abs(float(d.qpos[7]) - md.qpos[7]) < 0.02 * travelled
    assert abs(float(d.qvel[6])) < 1e-3


def test_ellipsoid_on_a_plane_and_cylinder_on_a_cylinder_track_mujoco(x64):
    """A tilted ellipsoid dropped on a plane, and a cylinder dropped across a fixed cylinder lying
    on its side: 1 s of qpos within 1e-6 of MuJoCo C (its GJK/EPA converged), both at rest."""
    xml = """<mujoco><option timestep="0.002" ccd_tolerance="1e-13" ccd_iterations="1000"/><worldbody>
    <geom type="plane" size="2 2 .1"/><geom type="cylinder" size="0.05 0.3" pos="1 0 0.05" euler="0 90 0"/>
    <body pos="0 0 0.2" euler="20 10 0"><freejoint/><geom type="ellipsoid" size="0.08 0.05 0.03"/></body>
    <body pos="1 0 0.2" euler="90 0 0"><freejoint/><geom type="cylinder" size="0.04 0.1"/></body>
    </worldbody></mujoco>"""
    mj = mujoco.MjModel.from_xml_string(xml)
    ours, theirs = _trajectory(mj, 500)
    assert np.max(np.abs(ours - theirs)) < 1e-6
    assert abs(theirs[-1, 9] - 0.14) < 2e-3  # the cylinder lies across the other (0.05 + 0.05 + 0.04)


def test_hfield_gjk_contacts_match_mujoco(x64):
    """A capsule, a cylinder and an ellipsoid over rough terrain: the same prisms touched and each
    contact as MuJoCo's converged GJK/EPA gives it (to rounding against the capsule's core;
    within 1e-5 in depth and 3e-2 in position and normal on curved surfaces, as between geoms).
    In 3 of these 100 poses a cylinder's rim lies on an edge two prisms share and MuJoCo reports it
    twice, fastrl once. A mesh's contacts with the prisms, like a box's, are the exact minimum
    translation, which MuJoCo 4.0's EPA does not report there (normals up to 2 apart here)."""
    shapes = (
        '<geom type="capsule" size="0.03 0.05"/>',
        '<geom type="cylinder" size="0.05 0.04"/>',
        '<geom type="ellipsoid" size="0.06 0.04 0.05"/>',
    )
    bodies = "".join(f"<body><freejoint/>{g}</body>" for g in shapes)
    xml = f"""<mujoco><option ccd_tolerance="1e-13" ccd_iterations="1000"/>
    <asset><hfield name="terrain" nrow="21" ncol="25" size="1.2 1 0.15 0.1"/></asset>
    <worldbody><geom type="hfield" hfield="terrain"/>{bodies}</worldbody></mujoco>"""
    mj = _compile(xml)
    qposes = _random_poses(mj, np.random.default_rng(6), 100, (0.0, 0.2))
    theirs, ours = _contacts(mj, qposes)
    assert sum(len(t) for t in theirs) > 200
    curved = np.flatnonzero(
        np.isin(mj.geom_type, [mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_ELLIPSOID])
    )
    differ = 0
    for t, o in zip(theirs, ours, strict=True):
        if t.shape != o.shape:  # a curved rim exactly on an edge two prisms share (see docstring)
            differ += 1
            continue
        bent = np.isin(t[:, 1], curved)
        np.testing.assert_allclose(o[~bent], t[~bent], atol=1e-6)
        np.testing.assert_allclose(o[bent, :3], t[bent, :3], atol=1e-5)
        np.testing.assert_allclose(o[bent, 3:], t[bent, 3:], atol=3e-2)
    assert differ <= 0.05 * len(qposes)


def test_culled_mesh_group_keeps_every_touching_pair(x64):
    """Twelve mesh cubes in a 3 x 4 grid (66 mesh-mesh pairs, one contact each): GJK runs on the
    33 pairs whose bounding spheres overlap most and EPA on the 16 closest of those. With 29
    spheres overlapping and up to 9 pairs touching, every pose gives MuJoCo's contacts."""
    assert gjk_slots(66) == (33, 16)
    bodies = "".join(
        f'<body pos="{0.1 * i} {0.12 * j} 0"><freejoint/><geom type="mesh" mesh="cube"/></body>'
        for i in range(4)
        for j in range(3)
    )
    mj = mujoco.MjModel.from_xml_string(
        f'<mujoco><option ccd_tolerance="1e-13" ccd_iterations="1000"><flag multiccd="disable"/>'
        f'</option><asset><mesh name="cube" vertex="{_vertex(_CUBE)}"/></asset>'
        f"<worldbody>{bodies}</worldbody></mujoco>"
    )
    rng = np.random.default_rng(8)
    qposes = np.tile(mj.qpos0, (40, 1)).reshape(40, 12, 7)
    qposes[..., :3] += rng.normal(0, 0.004, (40, 12, 3))
    quat = np.c_[np.ones(40 * 12), rng.normal(0, 0.05, (40 * 12, 3))].reshape(40, 12, 4)
    qposes[..., 3:] = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    theirs, ours = _contacts(mj, qposes.reshape(40, -1))
    assert max(len(t) for t in theirs) >= 6
    for t, o in zip(theirs, ours, strict=True):
        np.testing.assert_allclose(o, t, atol=1e-6)


# the mesh pair in the default suite; the other pairs run the same GJK/EPA code (~40 s each)
@pytest.mark.parametrize(
    "types",
    [("mesh", "mesh"), pytest.param(("box", "mesh"), marks=pytest.mark.slow),
     pytest.param(("cylinder", "cylinder"), marks=pytest.mark.slow)],
)  # fmt: skip
def test_gjk_epa_contacts_are_differentiable(types, x64):
    """GJK and EPA stop when converged (a ``while_loop``, which reverse mode cannot run), yet
    ``jax.grad`` goes through them (``collision_gjk.stops_when_done``): the contact distance's
    gradient with respect to the second geom's position equals central differences, overlapping
    (EPA) and apart (GJK), and is finite."""
    t1, t2 = (getattr(GeomType, t.upper()) for t in types)
    contact = ccd.single_contact(t1, t2)
    cube, size, eye = jnp.asarray(_CUBE), jnp.array([0.05, 0.05, 0.05]), jnp.eye(3)
    rot = jnp.asarray(_RNG_GRAD.standard_normal((3, 3)))
    mat = jnp.linalg.qr(rot)[0] * jnp.sign(jnp.linalg.det(jnp.linalg.qr(rot)[0]))
    dist = lambda p: contact(jnp.zeros(3), eye, size, p, mat, size, cube, cube)[0]  # noqa: E731
    for p in ([0.07, 0.02, 0.01], [0.09, -0.01, 0.03], [0.16, 0.02, 0.01]):
        p = jnp.asarray(p)
        grad = np.asarray(jax.grad(dist)(p))
        assert np.isfinite(grad).all()
        eps = 1e-7
        fd = [(float(dist(p.at[i].add(eps))) - float(dist(p.at[i].add(-eps)))) / (2 * eps) for i in range(3)]
        np.testing.assert_allclose(grad, fd, atol=1e-5)
