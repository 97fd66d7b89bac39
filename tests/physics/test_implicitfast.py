"""The implicitfast integrator against MuJoCo C in float64: the velocity derivative, one step
from random states, and 1 s trajectories; both models are compiled once for the module."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import derivative

# A hinge chain: joint damping, a position servo (kp, kv) through a gear, velocity servos (one
# with ctrlrange, one saturating at its forcerange) on a joint with actuatorfrcrange, and an
# affine-gain actuator whose velocity gain multiplies the clamped control.
CHAIN = """
<mujoco><option integrator="implicitfast" timestep="0.01"/>
<worldbody>
  <body><joint name="a" damping="0.3"/><geom type="capsule" fromto="0 0 0 0 0 -.5" size=".05"/>
    <body pos="0 0 -.5"><joint name="b" axis="0 1 0" actuatorfrcrange="-2 2"/>
      <geom type="capsule" fromto="0 0 0 .5 0 0" size=".05"/>
      <body pos=".5 0 0"><joint name="c" axis="1 0 0" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0 .5 0" size=".05"/></body></body></body>
</worldbody>
<actuator>
  <position name="pos" joint="a" kp="10" kv="2" gear="2"/>
  <velocity name="vel" joint="b" kv="3" ctrlrange="-1 1"/>
  <velocity name="sat" joint="b" kv="5" forcerange="-0.5 0.5"/>
  <general name="aff" joint="c" gaintype="affine" gainprm="1 0.5 0.7" biastype="affine"
           biasprm="0 -1 -0.4" ctrlrange="-1 1" ctrllimited="true"/>
</actuator></mujoco>
"""

# Free bodies in a fluid over a plane (pyramidal cone): an asymmetric box landing and sliding,
# one spinning in the air with a welded child body, and one whose tree also has a hinge.
SCENE = """
<mujoco><option integrator="implicitfast" timestep="0.005" density="1.2" viscosity="0.01"/>
<worldbody><geom type="plane" size="5 5 .1"/>
  <body name="lander" pos="0 0 .3"><freejoint/><geom type="box" size=".3 .1 .05" pos=".05 .02 0"/></body>
  <body name="spinner" pos="0 2 6" quat="0.9 0.1 0.3 -0.2"><freejoint/>
    <geom type="box" size=".1 .2 .3" pos=".02 0 .01" contype="0" conaffinity="0"/>
    <body pos=".2 0 0"><geom size=".1" contype="0" conaffinity="0"/></body></body>
  <body name="hinged" pos="1 0 .5"><freejoint/><geom type="box" size=".1 .2 .05"/>
    <body pos=".1 0 0"><joint axis="0 1 0" damping=".2"/>
      <geom type="capsule" fromto="0 0 0 .2 0 0" size=".03"/></body></body>
</worldbody></mujoco>
"""

MODELS = {"chain": CHAIN, "scene": SCENE}
BATCH = 3


class _Case:
    """A model in MuJoCo and fastrl, with fastrl's batched step and derivative compiled once."""

    def __init__(self, xml: str):
        self.mj = mujoco.MjModel.from_xml_string(xml)
        # slots for every contact the scene makes (the default rule keeps the deepest 8 of up to 10)
        self.m = physics.model_from_mujoco(self.mj, nconmax=16)
        m = self.m
        self.step = jax.jit(jax.vmap(lambda d, u: physics.step(m, d, u)))
        self.deriv = jax.jit(jax.vmap(lambda d: derivative.smooth_vel(m, physics.forward(m, d))))

    def states(self, seed: int):
        """``BATCH`` random (qpos, qvel, ctrl); controls reach past the control ranges."""
        rng = np.random.default_rng(seed)
        qpos = np.tile(self.mj.qpos0, (BATCH, 1))
        for j in range(self.mj.njnt):  # free joints keep their height, hinges turn
            if self.mj.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                qpos[:, self.mj.jnt_qposadr[j]] += rng.normal(0, 0.5, BATCH)
        qvel = rng.normal(0, 3, (BATCH, self.mj.nv))
        return qpos, qvel, rng.uniform(-2, 2, (BATCH, self.mj.nu))

    def data(self, qpos, qvel, ctrl):
        return jax.vmap(lambda q, v, u: physics.make_data(self.m, qpos=q, qvel=v, ctrl=u))(qpos, qvel, ctrl)


@pytest.fixture(scope="module")
def cases():
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield {name: _Case(xml) for name, xml in MODELS.items()}
    jax.config.update("jax_enable_x64", previous)


def _mujoco_step(mj, qpos, qvel, ctrl) -> mujoco.MjData:
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:], md.ctrl[:] = qpos, qvel, ctrl
    mujoco.mj_step(mj, md)
    return md


def _rel(ours, ref) -> float:
    ours, ref = np.asarray(ours), np.asarray(ref)
    return float(np.max(np.abs(ours - ref)) / (1.0 + np.max(np.abs(ref))))


@pytest.mark.parametrize("name", MODELS)
def test_velocity_derivative_matches_mujoco_qderiv(cases, name):
    """``smooth_vel`` is MuJoCo's ``qDeriv`` (left by mj_step): damping, actuator gains with the
    forcerange / actuatorfrcrange saturations and the clamped control, and the fluid forces."""
    case = cases[name]
    mj = case.mj
    saturated = set()
    for seed in range(4):
        qpos, qvel, ctrl = case.states(seed)
        ours = case.deriv(case.data(qpos, qvel, ctrl))
        for k in range(BATCH):
            md = _mujoco_step(mj, qpos[k], qvel[k], ctrl[k])
            ref = np.zeros((mj.nv, mj.nv))
            mujoco.mju_sparse2dense(ref, md.qDeriv, mj.D_rownnz, mj.D_rowadr, mj.D_colind)
            assert _rel(ours[k], ref) < 1e-12, f"{name}: qDeriv differs from MuJoCo's"
            if name == "chain":
                saturated.add((abs(md.actuator_force[2]) == 0.5, abs(md.qfrc_actuator[1]) == 2.0))
    if name == "chain":  # each saturation was both hit and missed
        assert {s[0] for s in saturated} == {s[1] for s in saturated} == {True, False}


def test_the_option_or_the_argument_selects_implicitfast():
    assert physics.load_mjcf(CHAIN).integrator == physics.Integrator.IMPLICITFAST
    chain_euler = CHAIN.replace('integrator="implicitfast"', 'integrator="Euler"')
    assert physics.load_mjcf(chain_euler, integrator="implicitfast").integrator == 3  # mjINT_IMPLICITFAST


def test_free_trees_are_the_one_free_joint_trees():
    """MuJoCo 4.0 solves a free joint's block on its own when its tree has no other dof, welded
    child bodies included (the spinner), and not when a hinge hangs off it (hinged)."""
    m = physics.load_mjcf(SCENE)
    bodies = [m.body_names[b] for b in m.jnt_bodyid[derivative.free_trees(m)]]
    assert bodies == ["lander", "spinner"]


@pytest.mark.parametrize("name", MODELS)
def test_one_step_matches_mujoco(cases, name):
    case = cases[name]
    for seed in range(3):
        qpos, qvel, ctrl = case.states(seed)
        d = case.step(case.data(qpos, qvel, ctrl), ctrl)
        for k in range(BATCH):
            md = _mujoco_step(case.mj, qpos[k], qvel[k], ctrl[k])
            for field in ("qacc", "qvel", "qpos"):
                err = _rel(getattr(d, field)[k], getattr(md, field))
                assert err < 1e-9, f"{name}: {field} after one step differs by {err:.1e}"


@pytest.mark.parametrize("name", MODELS)
def test_trajectory_tracks_mujoco_for_one_second(cases, name):
    case = cases[name]
    mj = case.mj
    qpos, qvel, _ = case.states(100)
    rng = np.random.default_rng(1)
    refs = [mujoco.MjData(mj) for _ in range(BATCH)]
    for md, q, v in zip(refs, qpos, qvel, strict=True):
        md.qpos[:], md.qvel[:] = q, v
    d = case.data(qpos, qvel, np.zeros((BATCH, mj.nu)))
    worst = 0.0
    for _ in range(round(1.0 / mj.opt.timestep)):
        ctrl = rng.uniform(-2, 2, (BATCH, mj.nu))
        d = case.step(d, ctrl)
        for k, md in enumerate(refs):
            md.ctrl[:] = ctrl[k]
            mujoco.mj_step(mj, md)
            worst = max(worst, _rel(d.qpos[k], md.qpos), _rel(d.qvel[k], md.qvel))
    assert not np.any(np.asarray(d.diverged))
    if name == "scene":
        assert max(md.ncon for md in refs) > 0  # the lander and the hinged tree touch the plane
    assert worst < 1e-6, f"{name}: the state parted from MuJoCo's by {worst:.1e} within 1 s"
