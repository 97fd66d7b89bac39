"""Activation dynamics (filter, filterexact, integrator) and the noslip solver against MuJoCo C."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import constraint, noslip
from fastrl.tools import scene_info

# Three kinds of actuator state: a position servo with a filtered setpoint (filterexact), a
# filtered motor (filter), an integrated-velocity servo clamped to its actrange (integrator), an
# integrator whose gain depends on the joint's velocity (implicitfast differentiates it), and a
# plain motor. Two of them read the next step's activation (actearly).
ACTIVATION = """
<mujoco>
  <option timestep="0.01"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body>
      <joint name="a" type="hinge" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 .3 0 0" size=".03"/>
      <body pos=".3 0 0">
        <joint name="b" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 .3 0 0" size=".03"/>
      </body>
    </body>
    <body pos="0 .5 0">
      <joint name="c" type="slide" axis="1 0 0"/>
      <geom type="box" size=".05 .05 .05"/>
    </body>
    <body pos="0 -.5 0">
      <joint name="d" type="slide" axis="0 0 1" damping="0.5"/>
      <geom type="box" size=".05 .05 .05"/>
    </body>
  </worldbody>
  <actuator>
    <position name="servo" joint="a" kp="20" kv="1" timeconst="0.05"/>
    <general name="filtered" joint="b" dyntype="filter" dynprm="0.03" gainprm="3" actearly="true"/>
    <intvelocity name="intvel" joint="c" kp="30" actrange="-0.2 0.3"/>
    <general name="damped" joint="d" dyntype="integrator" gaintype="affine" gainprm="4 0 -2"
             actlimited="true" actrange="-1 1" actearly="true"/>
    <motor name="plain" joint="b" gear="0.5"/>
  </actuator>
</mujoco>
"""

# Friction on a 12-degree slope (a box on four contacts, a ball with rolling friction), a two-finger
# grasp holding a box against gravity (fingers driven by filtered position servos), and a hinge
# with friction loss: four islands, contacts of condim 3, 4 and 6, and friction-loss rows.
NOSLIP = """
<mujoco>
  <option timestep="0.005" cone="{cone}" noslip_iterations="10"/>
  <default><geom contype="1" conaffinity="1"/></default>
  <worldbody>
    <geom type="plane" size="2 2 .1" euler="0 12 0" friction="0.5"/>
    <body pos="0 0 .12" euler="0 12 0">
      <freejoint/>
      <geom type="box" size=".1 .08 .06"/>
    </body>
    <body pos=".5 .5 .2">
      <freejoint/>
      <geom size=".06" condim="6" friction="0.5 0.02 0.01"/>
    </body>
    <body name="left" pos="-.09 -1 1">
      <joint name="left" type="slide" axis="1 0 0"/>
      <geom size=".03" condim="4" contype="2" conaffinity="2" friction="0.6 0.01"/>
    </body>
    <body name="right" pos=".09 -1 1">
      <joint name="right" type="slide" axis="1 0 0"/>
      <geom size=".03" condim="4" contype="2" conaffinity="2" friction="0.6 0.01"/>
    </body>
    <body name="held" pos="0 -1 1">
      <freejoint/>
      <geom type="box" size=".05 .05 .05" mass=".2" contype="2" conaffinity="2"/>
    </body>
    <body pos="1 -1 1">
      <joint type="hinge" axis="0 1 0" frictionloss="0.05"/>
      <geom type="capsule" fromto="0 0 0 .2 0 0" size=".02" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <position joint="left" kp="1000" timeconst="0.02"/>
    <position joint="right" kp="1000" timeconst="0.02"/>
  </actuator>
</mujoco>
"""
SQUEEZE = np.array([0.02, -0.02])  # each finger's setpoint, 1 cm into the held box


def _trajectory(xml: str, ctrls: np.ndarray, integrator: str | None = None):
    """Steps MuJoCo C and fastrl side by side; returns both final Data, the largest gaps in
    qpos, qvel and act over the run, and MuJoCo's activations after each step."""
    mj = mujoco.MjModel.from_xml_string(xml)
    if integrator is not None:
        mj.opt.integrator = {"euler": 0, "rk4": 1, "implicitfast": 3}[integrator]
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    d = physics.make_data(m)
    step = jax.jit(physics.step)
    gap, acts = np.zeros(3), []
    for u in ctrls:
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        d = step(m, d, u)
        for i, (ours, theirs) in enumerate(((d.qpos, md.qpos), (d.qvel, md.qvel), (d.act, md.act))):
            gap[i] = max(gap[i], np.abs(np.asarray(ours) - theirs).max(initial=0.0))
        acts.append(md.act.copy())
    return md, d, gap, np.array(acts)


@pytest.mark.parametrize("integrator", ["euler", "rk4", "implicitfast"])
def test_activation_dynamics_track_mujoco(integrator, x64):
    """Every activation, position and velocity stays on MuJoCo's over 100 steps of random
    controls, under each integrator (RK4 integrates the activations in its stages too)."""
    ctrls = np.random.default_rng(0).uniform(-2, 2, (100, 5))
    ctrls[:, 3] += 1.5  # drives the clamped integrator to its bound
    _, _, gap, acts = _trajectory(ACTIVATION, ctrls, integrator)
    assert np.all(gap < 1e-9), f"qpos, qvel, act parted from MuJoCo's by {gap}"
    assert np.any(acts[:, 2] == 0.3) and np.any(np.abs(acts[:, 3]) == 1.0)  # both clamps held
    assert np.all(np.ptp(acts, axis=0) > 0.1)  # every activation moved


@pytest.mark.parametrize("cone", ["pyramidal", "elliptic"])
def test_noslip_tracks_mujoco_and_stops_the_creep(cone, x64):
    """qpos and qvel stay on MuJoCo's over 100 steps with the noslip pass on. The box on the slope
    then creeps 100x slower than MuJoCo's own without noslip, and the grasp holds its box."""
    xml = NOSLIP.format(cone=cone)
    _, d, gap, _ = _trajectory(xml, np.tile(SQUEEZE, (100, 1)))
    assert np.all(gap < 1e-6), f"qpos, qvel, act parted from MuJoCo's by {gap}"
    mj = mujoco.MjModel.from_xml_string(xml)
    mj.opt.noslip_iterations = 0
    soft = mujoco.MjData(mj)
    for _ in range(100):
        soft.ctrl[:] = SQUEEZE
        mujoco.mj_step(mj, soft)
    qvel = np.asarray(d.qvel)
    creep = np.linalg.norm(qvel[:3])
    assert creep < 1e-2 * np.linalg.norm(soft.qvel[:3]), (creep, soft.qvel[:3])
    sink = 16  # the held box's vertical velocity: after the box's, the ball's and the fingers' dofs
    assert abs(qvel[sink]) < 1e-5 < 1e-3 < abs(soft.qvel[sink]), (qvel[sink], soft.qvel[sink])


def test_noslip_rows_and_the_summary():
    """The sweeps' static blocks, and ``scene_info`` naming what a model simulates."""
    m = physics.load_mjcf(NOSLIP.format(cone="pyramidal"))
    assert m.noslip_iterations == 10 and noslip.friction_rows(m).size == 1
    pairs = noslip.pyramid_pairs(m)  # every slot's edges, two by two: condim - 1 pairs a slot
    assert pairs.size == sum(n * (dim - 1) for dim, _, n in constraint.contact_groups(m) if dim > 1)
    assert pairs[0] == constraint.first_contact_row(m) and np.all(np.diff(pairs) == 2)
    lines = "\n".join(scene_info.summary_lines(m))
    assert "up to 10 Gauss-Seidel sweeps" in lines and "2 filterexact" in lines
    plain = physics.load_mjcf(NOSLIP.format(cone="elliptic").replace(' noslip_iterations="10"', ""))
    assert plain.noslip_iterations == 0 and "noslip          off" in "\n".join(
        scene_info.summary_lines(plain)
    )
    a = physics.load_mjcf(ACTIVATION)
    assert a.na == 4 and "4 activations (1 filter, 1 filterexact, 2 integrator; 2 actearly, 2 clamped" in (
        "\n".join(scene_info.summary_lines(a))
    )
    with pytest.raises(ValueError, match="act has shape"):
        physics.make_data(a, act=np.zeros(3))
