"""Mocap bodies: poses set between steps through ``Data.mocap_pos``/``mocap_quat``, against
MuJoCo C (the static case runs in test_oracle.py on the same asset)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl import physics
from tests.conftest import asset


def _paddle_pose(t: int) -> tuple[np.ndarray, np.ndarray]:
    pos = np.array([0.3 * np.sin(0.01 * t), 0.0, 0.6 + 0.1 * np.cos(0.02 * t)])
    quat = 2 * np.array([np.cos(0.005 * t), 0.0, np.sin(0.005 * t), 0.0])  # not normalised
    return pos, quat


def test_a_mocap_paddle_moved_every_step_pushes_bodies_as_in_mujoco(x64):
    mj = mujoco.MjModel.from_xml_path(asset("mocap"))
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    d = physics.make_data(m)
    np.testing.assert_array_equal(d.mocap_pos, md.mocap_pos)
    np.testing.assert_array_equal(d.mocap_quat, md.mocap_quat)
    step = jax.jit(physics.step)
    worst, touched = 0.0, 0
    for t in range(600):  # 3 s
        pos, quat = _paddle_pose(t)
        md.mocap_pos[0], md.mocap_quat[0] = pos, quat
        d = d.replace(mocap_pos=d.mocap_pos.at[0].set(pos), mocap_quat=d.mocap_quat.at[0].set(quat))
        mujoco.mj_step(mj, md)
        d = step(m, d, jnp.zeros(mj.nu))
        worst = max(worst, float(np.abs(np.asarray(d.qpos) - md.qpos).max()))
        paddle_geoms = {int(g) for g in np.flatnonzero(mj.geom_bodyid == 1)}
        touched += any({c.geom1, c.geom2} & paddle_geoms and 0 not in (c.geom1, c.geom2) for c in md.contact)
    assert touched > 20, "the paddle should push the ball and the pole"
    assert worst < 1e-6, f"qpos parted from MuJoCo's by {worst:.2e}"
    np.testing.assert_allclose(d.xpos[1], md.xpos[1], atol=1e-12)  # the mocap body is where it was set
    np.testing.assert_allclose(d.xquat[1], md.xquat[1], atol=1e-12)


def test_mocap_poses_batch_and_place_their_sites():
    m = physics.load_mjcf(asset("mocap"))
    targets = jnp.array([[0.0, 0.0, 1.0], [1.0, 2.0, 3.0]])

    def marker_site(target):
        d = physics.make_data(m)
        d = d.replace(mocap_pos=d.mocap_pos.at[1].set(target))
        return physics.forward(m, d).site_xpos[0]

    np.testing.assert_allclose(jax.jit(jax.vmap(marker_site))(targets), targets, atol=1e-6)
