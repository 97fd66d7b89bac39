"""Capsule-box and box-box contacts against MuJoCo C: resting, tipping over an edge, geometry."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from tests.physics.test_contact import _run_both, _xml

TABLE = '<geom name="table" type="box" size="0.3 0.3 0.05"/>'
BOX = '<body pos="{}" euler="{}"><freejoint/><geom type="{}" size="{}"/></body>'
DROPS = {
    # one face flat on the table
    "cube_on_box": BOX.format("0 0.05 0.3", "0 0 20", "box", "0.05 0.05 0.05"),
    # lands on a corner, tips onto an edge, then a face
    "box_corner_first": BOX.format("0 0 0.3", "30 40 10", "box", "0.05 0.04 0.03"),
    # a capsule on its side: the two end contacts
    "capsule_on_box": BOX.format("0.05 0 0.3", "80 0 30", "capsule", "0.03 0.1"),
    # a capsule landing across the table's edge: an end and the edge carry it
    "capsule_over_edge": BOX.format("0.24 0 0.3", "0 85 0", "capsule", "0.03 0.1"),
}


@pytest.mark.parametrize("scene", sorted(DROPS))
def test_dropped_on_a_box_rest_like_mujoco(scene, x64):
    steps = 1500  # 3 s at 2 ms: fall, bounce, settle
    ref, ours = _run_both(_xml(TABLE + DROPS[scene], "euler"), steps)
    if scene.startswith(("cube", "box")):  # box-box is MuJoCo's algorithm: the same trajectory
        np.testing.assert_allclose(ours, ref, atol=1e-6)
    assert np.max(np.abs(ours[:, 2] - ref[:, 2])) < 7e-3  # the whole fall and bounce
    assert abs(ours[-1, 2] - ref[-1, 2]) < 1e-3  # rest height within 1 mm
    assert np.max(np.abs(ours[-1, 3:] - ref[-1, 3:])) < 5e-3  # rest orientation (quaternion)
    rest = ours[-steps // 4 :, 2]
    assert rest.max() - rest.min() < 1e-4  # no sinking


@pytest.mark.parametrize(
    "pose",
    [
        "0.3 0.02 0.07 0 60 10",  # a capsule leaning across the table's top edge
        "0.05 -0.1 0.078 88 0 0",  # lying on the top face, slightly tilted
        "-0.31 0.2 0.0 0 0 35",  # upright against a side face
    ],
)
def test_capsule_box_deepest_contact_matches_mujoco(pose, x64):
    *p, a, b, c = pose.split()
    xml = _xml(TABLE + f'<body pos="{" ".join(p)}" euler="{a} {b} {c}"><freejoint/>'
               '<geom type="capsule" size="0.03 0.1"/></body>', "euler")  # fmt: skip
    mj = mujoco.MjModel.from_xml_string(xml)
    md = mujoco.MjData(mj)
    mujoco.mj_forward(mj, md)
    assert md.ncon > 0
    m = physics.model_from_mujoco(mj)
    d = jax.jit(lambda d: physics.forward(m, d))(physics.make_data(m))
    ours = np.asarray(d.contact_dist)
    ref = md.contact.dist[: md.ncon]
    assert ours.min() == pytest.approx(ref.min(), abs=1e-6)
    deepest = np.argmin(ours)
    normal = np.asarray(d.contact_frame)[deepest, 0]
    np.testing.assert_allclose(normal, md.contact.frame[np.argmin(ref)][:3], atol=1e-5)


_TWO_BOXES = """<mujoco><worldbody>
<body><freejoint/><geom type="box" size="{}" margin="{}"/></body>
<body><freejoint/><geom type="box" size="{}"/></body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("margin", [0.0, 0.01])
def test_box_box_contacts_match_mujoco(margin, x64):
    """Random box pairs brought just into contact (faces nearly aligned every third pose, so
    that face manifolds of 2-8 points occur beside edge-edge and corner contacts): the same
    contacts as mjc_BoxBox, each distance, position and normal within 1e-9."""
    from fastrl.physics import collision_box

    rng = np.random.default_rng(1)
    collide = jax.jit(collision_box.box_box)
    counts = set()
    for trial in range(120):
        size1, size2 = rng.uniform(0.05, 0.5, 3), rng.uniform(0.05, 0.5, 3)
        fmt = lambda v: " ".join(map(str, v))  # noqa: E731
        mj = mujoco.MjModel.from_xml_string(_TWO_BOXES.format(fmt(size1), margin, fmt(size2)))
        md = mujoco.MjData(mj)
        quats = rng.normal(size=(2, 4))
        direction = rng.normal(size=3)
        if trial % 3 == 0:  # nearly aligned faces, box 2 above box 1
            quats = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]]) + [
                [0] * 4,
                rng.normal(0, 0.05, 4) * (trial % 2),
            ]
            direction = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), 1.0])
        quats /= np.linalg.norm(quats, axis=1, keepdims=True)
        direction /= np.linalg.norm(direction)
        md.qpos[:] = np.r_[0, 0, 0, quats[0], 2 * direction, quats[1]]
        for scale in np.linspace(2, 0, 400):  # slide box 2 in until they touch
            md.qpos[7:10] = direction * scale
            mujoco.mj_forward(mj, md)
            if md.ncon:
                break
        md.qpos[7:10] = direction * (scale - rng.uniform(0, 0.05))
        mujoco.mj_forward(mj, md)
        poses = [
            jnp.asarray(x)
            for g in (0, 1)
            for x in (md.geom_xpos[g], md.geom_xmat[g].reshape(3, 3), mj.geom_size[g])
        ]
        dist, pos, normal, _ = (np.asarray(x) for x in collide(*poses, jnp.asarray(margin)))
        active = np.flatnonzero(dist < margin)
        assert active.size == md.ncon, trial
        counts.add(md.ncon)
        order = lambda p: np.lexsort(np.round(p, 9).T[::-1])  # noqa: E731
        ours, ref = active[order(pos[active])], order(md.contact.pos[: md.ncon])
        np.testing.assert_allclose(dist[ours], md.contact.dist[ref], atol=1e-9)
        np.testing.assert_allclose(pos[ours], md.contact.pos[ref], atol=1e-9)
        np.testing.assert_allclose(normal[ours], md.contact.frame[ref, :3], atol=1e-9)
    assert {1, 2, 4} <= counts  # edge or corner contacts and face manifolds both met
