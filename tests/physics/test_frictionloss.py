"""Dof friction loss against MuJoCo C: rows, forces in every zone, trajectories, stiction."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import envs, physics
from fastrl.physics import constraint
from tests.conftest import asset, random_state

STATE = mujoco.mjtConstraintState


def _model(scale: float, solver_iterations: int | None = None):
    mj = mujoco.MjModel.from_xml_path(asset("friction_loss"))
    mj.dof_frictionloss[:] *= scale
    return mj, physics.model_from_mujoco(mj, solver_iterations=solver_iterations)


@pytest.mark.parametrize("scale", [0.3, 1.0, 10.0])
def test_friction_rows_and_forces_match_mujoco_in_every_zone(scale, x64):
    mj, m = _model(scale)
    md = mujoco.MjData(mj)
    forward = jax.jit(physics.forward)
    assert list(constraint.friction_dofs(m)) == list(range(mj.nv))
    states = set()
    for seed in range(12):
        qpos, qvel, ctrl = random_state(mj, seed, qvel_scale=0.5 * (seed % 3 != 0))  # some at rest
        md.qpos[:], md.qvel[:], md.ctrl[:] = qpos, qvel, ctrl * (seed % 2)
        mujoco.mj_forward(mj, md)
        d = forward(m, physics.make_data(m, qpos=qpos, qvel=qvel, ctrl=md.ctrl.copy()))
        nf = md.nf
        assert nf == mj.nv
        np.testing.assert_allclose(d.efc_aref[:nf], md.efc_aref[:nf], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(d.efc_D[:nf], 1 / md.efc_R[:nf], rtol=1e-10)
        np.testing.assert_allclose(d.efc_force[:nf], md.efc_force[:nf], rtol=1e-7, atol=1e-7 * scale)
        np.testing.assert_allclose(d.qacc, md.qacc, rtol=1e-7, atol=1e-7 * (1 + np.abs(md.qacc).max()))
        states |= set(int(s) for s in md.efc_state[:nf])
    # MuJoCo's solution had rows in the quadratic zone (sticking) and in both linear zones
    assert {int(STATE.mjCNSTRSTATE_QUADRATIC), int(STATE.mjCNSTRSTATE_LINEARNEG),
            int(STATE.mjCNSTRSTATE_LINEARPOS)} <= states  # fmt: skip


def test_trajectory_with_friction_loss_tracks_mujoco(x64):
    mj, m = _model(1.0)
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(0)
    ctrls = rng.uniform(-1, 1, (400, mj.nu)) * (rng.random((400, 1)) < 0.5)  # pushes and rests
    step = jax.jit(physics.step)
    d = physics.make_data(m)
    worst = 0.0
    for u in ctrls:
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        d = step(m, d, u)
        worst = max(worst, float(np.abs(np.asarray(d.qpos) - md.qpos).max()))
    assert worst < 1e-6, f"qpos parted from MuJoCo's by {worst:.2e} over 400 steps"


SLIDER = """
<mujoco>
  <worldbody>
    <body>
      <joint name="x" type="slide" axis="1 0 0" frictionloss="20"/>
      <geom type="box" size=".1 .1 .1" mass="2"/>
    </body>
  </worldbody>
  <actuator><motor joint="x"/></actuator>
</mujoco>
"""


def test_friction_loss_holds_a_joint_against_a_smaller_force(x64):
    """Stiction: a 2 kg block on a horizontal slider with friction loss 20 N, pushed by 10 N,
    creeps only at the soft constraint's rate (under 1% of the 1 m/s it would reach freely in
    0.2 s); pushed by 30 N it slides, accelerating at (30 - 20) / 2 = 5 m/s^2. MuJoCo C agrees
    step by step."""
    mj = mujoco.MjModel.from_xml_string(SLIDER)
    m = physics.model_from_mujoco(mj)
    md = mujoco.MjData(mj)
    step = jax.jit(physics.step)
    for push, accel in ((10.0, 0.0), (30.0, 5.0)):
        d = physics.make_data(m)
        mujoco.mj_resetData(mj, md)
        md.ctrl[:] = push
        for _ in range(100):  # 0.2 s
            d = step(m, d, np.array([push]))
            mujoco.mj_step(mj, md)
        assert abs(float(d.qpos[0]) - md.qpos[0]) < 1e-9
        np.testing.assert_allclose(float(d.qvel[0]), accel * 100 * mj.opt.timestep, atol=0.01)


def test_models_without_friction_loss_have_no_friction_rows():
    for name in ("ant", "humanoid", "hopper"):
        m = envs.make(name).model
        assert constraint.friction_dofs(m).size == 0
    mj = mujoco.MjModel.from_xml_path(asset("friction_loss"))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS
    assert physics.model_from_mujoco(mj).friction_dofs.size == 0


def test_friction_loss_gradients_are_finite(x64):
    mj, m = _model(1.0)
    qpos, qvel, _ = random_state(mj, 3, qvel_scale=0.5)

    def final_height(u):
        d = physics.make_data(m, qpos=qpos, qvel=qvel)
        d, _ = jax.lax.scan(lambda d, _: (physics.step(m, d, u), None), d, None, length=3)
        return d.qpos.sum()

    g = jax.grad(final_height)(jax.numpy.full(mj.nu, 0.3))
    assert np.all(np.isfinite(np.asarray(g)))


def test_scene_summary_lists_the_row_kinds():
    from fastrl.tools import scene_info

    lines = "\n".join(scene_info.summary_lines(physics.load_mjcf(asset("friction_loss"))))
    assert "friction loss   9 dofs, 0 tendons" in lines
    assert "constraint rows 42 (9 friction loss + 1 limit + 32 contact" in lines
