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
    # one face flat on the table (MuJoCo clips it to the same four corners)
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


def test_box_box_is_symmetric_in_its_geoms(x64):
    from fastrl.physics import collision_primitive as prim

    eye = jnp.eye(3)
    quat, mat = np.zeros(4), np.zeros(9)
    mujoco.mju_euler2Quat(quat, np.deg2rad([20.0, 30.0, 40.0]), "xyz")
    mujoco.mju_quat2Mat(mat, quat)
    tilt = jnp.asarray(mat.reshape(3, 3))
    args = (
        jnp.zeros(3),
        eye,
        jnp.array([0.3, 0.3, 0.05]),
        jnp.array([0.0, 0.0, 0.1]),
        tilt,
        jnp.array([0.05] * 3),
    )
    d12, p12, n12, _ = prim.box_box(*args)
    d21, p21, n21, _ = prim.box_box(*args[3:], *args[:3])
    np.testing.assert_allclose(np.sort(d12), np.sort(d21), atol=1e-12)
    deep = np.argmin(d12)
    assert d12[deep] < 0 and np.asarray(n12)[deep] @ np.array([0, 0, 1.0]) > 0.99  # table -> cube: up
    assert np.asarray(n21)[np.argmin(d21)] @ np.array([0, 0, 1.0]) < -0.99
