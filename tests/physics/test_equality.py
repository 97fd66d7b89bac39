"""Equality constraints (connect, weld, joint) against MuJoCo C in float64: the rows, forces and
acceleration at random states, 1 s trajectories, and switching constraints on and off; a gripper
driven through a tendon with a joint equality."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import equality
from fastrl.tools import scene_info
from tests.conftest import random_state

# A four-bar linkage: a crank, a coupler and a rocker on the ground, the loop closed by a connect.
FOUR_BAR = """
<mujoco><option timestep="0.002"/>
  <worldbody>
    <body name="crank" pos="0 0 1">
      <joint name="crank" type="hinge" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <body name="coupler" pos="0.3 0 0">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.6 0 0.3" size="0.02"/>
      </body>
    </body>
    <body name="rocker" pos="0.8 0 1">
      <joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0.3" size="0.02"/>
    </body>
  </worldbody>
  <equality><connect body1="coupler" body2="rocker" anchor="0.6 0 0.3" solref="0.01 1"/></equality>
  <actuator><motor joint="crank" gear="2"/></actuator>
</mujoco>
"""

# Welds: a free box welded to the world with a relative pose and torquescale, two free bodies
# welded to each other through sites, and a hinge pendulum held by a second weld that starts off.
WELDS = """
<mujoco><option timestep="0.002"/>
  <worldbody>
    <body name="box" pos="0 0 1" euler="10 20 30">
      <freejoint/>
      <geom type="box" size="0.1 0.05 0.03"/>
    </body>
    <body name="a" pos="1 0 1">
      <freejoint/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03"/>
      <site name="sa" pos="0.2 0 0" euler="0 0 30"/>
    </body>
    <body name="b" pos="1.25 0 1">
      <freejoint/>
      <geom type="sphere" size="0.05"/>
      <site name="sb" pos="0 0 0"/>
    </body>
    <body name="pend" pos="0 1 1">
      <joint name="swing" type="hinge" axis="1 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.02"/>
    </body>
  </worldbody>
  <equality>
    <weld body1="box" relpose="0.1 0 1.1 1 0.1 0 0" torquescale="0.5" solref="0.02 1"/>
    <weld site1="sa" site2="sb" solimp="0.9 0.95 0.001 0.5 2"/>
    <weld body1="pend" active="false"/>
  </equality>
</mujoco>
"""

# Joint couplings: a polynomial coupling of two hinges (a gripper's mimic joint), and a joint
# held at an offset from its reference; a slide finger pair mirrored by a linear coupling (the
# fingers do not collide: this model is about the coupling).
JOINTS = """
<mujoco><option timestep="0.002"/>
  <worldbody>
    <body pos="0 0 1">
      <joint name="j1" type="hinge" axis="0 1 0" range="-1 1" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <body pos="0.3 0 0">
        <joint name="j2" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      </body>
    </body>
    <body pos="1 0 1">
      <joint name="j3" type="hinge" axis="1 0 0" ref="0.2"/>
      <geom type="capsule" fromto="0 0 0 0 0.3 0" size="0.02"/>
    </body>
    <body name="palm" pos="0 1 1">
      <joint name="wrist" type="hinge" axis="0 0 1"/>
      <geom type="box" size="0.05 0.05 0.02"/>
      <body pos="0 0.04 -0.05"><joint name="left" type="slide" axis="0 1 0" range="0 0.04"/>
        <geom type="box" size="0.01 0.005 0.03" contype="0" conaffinity="0"/></body>
      <body pos="0 -0.04 -0.05"><joint name="right" type="slide" axis="0 -1 0" range="0 0.04"/>
        <geom type="box" size="0.01 0.005 0.03" contype="0" conaffinity="0"/></body>
    </body>
  </worldbody>
  <equality>
    <joint joint1="j2" joint2="j1" polycoef="0.1 0.5 0.3 -0.2 0.05"/>
    <joint joint1="j3" polycoef="0.3 0 0 0 0"/>
    <joint joint1="right" joint2="left" polycoef="0 1 0 0 0" solref="0.005 1"/>
  </equality>
  <actuator><motor joint="j1"/><position joint="left" kp="50"/><motor joint="wrist"/></actuator>
</mujoco>
"""

# A parallel gripper as Menagerie builds them: two finger slides, a fixed tendon summing them that
# one actuator pulls, a joint equality mirroring the fingers, and finger limits.
GRIPPER = """
<mujoco><option timestep="0.002"/>
  <worldbody>
    <body name="hand" pos="0 0 0.5">
      <joint name="lift" type="slide" axis="0 0 1" damping="5"/>
      <geom type="box" size="0.05 0.02 0.02" mass="0.5"/>
      <body pos="0 0.02 -0.04"><joint name="f1" type="slide" axis="0 1 0" range="0 0.04" damping="2"/>
        <geom type="box" size="0.01 0.005 0.03" contype="0" conaffinity="0"/></body>
      <body pos="0 -0.02 -0.04"><joint name="f2" type="slide" axis="0 -1 0" range="0 0.04" damping="2"/>
        <geom type="box" size="0.01 0.005 0.03" contype="0" conaffinity="0"/></body>
    </body>
  </worldbody>
  <tendon><fixed name="split"><joint joint="f1" coef="0.5"/><joint joint="f2" coef="0.5"/></fixed></tendon>
  <equality><joint joint1="f1" joint2="f2" solimp="0.95 0.99 0.001"/></equality>
  <actuator>
    <general tendon="split" ctrlrange="0 255" gainprm="0.01568 0 0" biasprm="0 -100 -10"/>
    <motor joint="lift" gear="10"/>
  </actuator>
</mujoco>
"""

MODELS = {"four_bar": FOUR_BAR, "welds": WELDS, "joints": JOINTS, "gripper": GRIPPER}


def _models(name):
    mj = mujoco.MjModel.from_xml_string(MODELS[name])
    mj.opt.tolerance = 1e-14  # MuJoCo's solver converged, so both find the same minimiser
    return mj, physics.model_from_mujoco(mj)


def _close(ours, ref, what, rtol=1e-6):
    ours, ref = np.asarray(ours), np.asarray(ref)
    scale = max(np.abs(ref).max(), 1e-9)
    assert np.abs(ours - ref).max() <= rtol * scale, (
        f"{what}: {np.abs(ours - ref).max():.2e} (scale {scale:.2e})"
    )


@pytest.mark.parametrize("name", sorted(MODELS))
def test_rows_forces_and_acceleration_match_mujoco(name, x64):
    mj, m = _models(name)
    md = mujoco.MjData(mj)
    forward = jax.jit(physics.forward)
    for seed in range(3):
        qpos, qvel, ctrl = random_state(mj, seed)
        md.qpos[:], md.qvel[:], md.ctrl[:] = qpos, qvel, ctrl
        mujoco.mj_forward(mj, md)
        d = forward(m, physics.make_data(m, qpos=qpos, qvel=qvel, ctrl=ctrl))
        ne = md.ne
        assert ne == int(np.asarray(md.eq_active).astype(bool) @ equality.row_counts(m))
        active = np.repeat(np.asarray(md.eq_active).astype(bool), equality.row_counts(m))
        mj_j = md.efc_J.reshape(md.nefc, mj.nv)
        _close(np.asarray(d.efc_J)[: active.size][active], mj_j[:ne], "efc_J")
        _close(np.asarray(d.efc_pos)[: active.size][active], md.efc_pos[:ne], "efc_pos")
        _close(np.asarray(d.efc_aref)[: active.size][active], md.efc_aref[:ne], "efc_aref")
        _close(np.asarray(d.efc_D)[: active.size][active], 1 / md.efc_R[:ne], "efc_D")
        assert not np.asarray(d.efc_D)[: active.size][~active].any()  # switched off: no weight
        _close(np.asarray(d.efc_force)[: active.size][active], md.efc_force[:ne], "efc_force")
        _close(d.qfrc_constraint, md.qfrc_constraint, "qfrc_constraint")
        _close(d.qacc, md.qacc, "qacc")


@pytest.mark.parametrize("name", sorted(MODELS))
def test_trajectory_matches_mujoco(name, x64):
    mj, m = _models(name)
    qpos, qvel, _ = random_state(mj, 5, qpos_scale=0.05, qvel_scale=0.5)
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = qpos, qvel
    d = physics.make_data(m, qpos=qpos, qvel=qvel)
    rng = np.random.default_rng(0)
    ctrls = rng.uniform(-1, 1, (500, mj.nu))
    step = jax.jit(physics.step)
    worst = 0.0
    for u in ctrls:  # 1 s
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        d = step(m, d, u)
        worst = max(worst, float(np.abs(np.asarray(d.qpos) - md.qpos).max()))
    assert worst < 1e-6, f"qpos parted from MuJoCo's by {worst:.2e}"


def test_constraints_switch_on_and_off_between_steps(x64):
    """``Data.eq_active`` as ``mjData.eq_active``: the pendulum swings free, is welded in place
    halfway, and the box's weld lets go; both engines agree throughout."""
    mj, m = _models("welds")
    md = mujoco.MjData(mj)
    md.qvel[-1] = 3.0
    d = physics.make_data(m, qvel=md.qvel.copy())
    step = jax.jit(physics.step)
    swing = []
    for t in range(400):
        if t == 200:
            md.eq_active[:] = [0, 1, 1]
            d = d.replace(eq_active=np.array([False, True, True]))
        mujoco.mj_step(mj, md)
        d = step(m, d)
        swing.append(float(d.qpos[-1]))
        np.testing.assert_allclose(d.qpos, md.qpos, atol=1e-6)
    assert np.ptp(swing[:200]) > 0.5 and np.ptp(swing[300:]) < 0.05  # free, then held
    assert md.qpos[2] < 0.8  # the released box fell (it was held near z = 1.1)


def test_scene_summary_lists_equalities():
    _, m = _models("welds")
    text = "\n".join(scene_info.summary_lines(m))
    assert "equalities      3 (3 weld; 1 off at reset), 18 rows" in text
