"""Tendons against MuJoCo C: lengths, Jacobians and velocities, their springs, dampers, armature
and actuators, the accelerations they cause, and 1 s trajectories.

The models are written here (not in tests/assets) so the per-asset oracle sweep does not grow; each
is compiled once (forward at random states and a trajectory in one jitted function).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import smooth, tendon
from fastrl.tools import scene_info
from tests.conftest import random_state

# (a) a fixed tendon coupling two hinge trees, one along a chain; springs with a dead band, dampers,
# actuators on both tendons (a position servo with kv), on a joint and on a site (a velocity
# servo); implicitfast.
FIXED = """
<mujoco>
  <option timestep="0.002" integrator="implicitfast"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="left" pos="-0.3 0 0">
      <joint name="l" type="hinge" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.04"/>
      <body name="left2" pos="0 0 -0.4">
        <joint name="l2" type="hinge" axis="1 0 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>
        <site name="foot" pos="0.05 0 -0.3"/>
      </body>
    </body>
    <body name="right" pos="0.3 0 0">
      <joint name="r" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.04"/>
    </body>
  </worldbody>
  <tendon>
    <fixed name="couple" stiffness="8" damping="0.6" springlength="-0.2 0.1">
      <joint joint="l" coef="1"/><joint joint="r" coef="-0.5"/>
    </fixed>
    <fixed name="chain" stiffness="3" damping="0.2">
      <joint joint="l" coef="0.3"/><joint joint="l2" coef="1"/>
    </fixed>
  </tendon>
  <actuator>
    <motor tendon="couple" gear="1.5" forcelimited="true" forcerange="-0.8 0.8"/>
    <position tendon="chain" kp="4" kv="0.5"/>
    <motor joint="r"/>
    <velocity site="foot" kv="0.4" gear="1 0.5 0 0 0.3 0"/>
  </actuator>
</mujoco>
"""

# (b) spatial tendons on a 3-link arm: around a cylinder (a helix: the sites sit at different
# heights along its axis), around a sphere with a side site outside it and with one inside it,
# and through a pulley; a motor and a position servo on tendons, motors on a joint and a site;
# Euler with joint damping.
ARM = """
<mujoco>
  <option timestep="0.002" integrator="Euler"/>
  <default><geom contype="0" conaffinity="0" density="500"/></default>
  <worldbody>
    <site name="base" pos="-0.1 0.02 0.1"/>
    <body name="l1">
      <joint name="h1" type="hinge" axis="0 1 0" damping="0.1"/>
      <geom name="cyl" type="cylinder" size="0.06 0.05" quat="0.7071068 0.7071068 0 0"/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.03"/>
      <site name="s1" pos="0.15 -0.02 -0.03"/>
      <body name="l2" pos="0.5 0 0">
        <joint name="h2" type="hinge" axis="0 1 0" damping="0.1"/>
        <geom name="ball" type="sphere" size="0.07"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.025"/>
        <site name="side" pos="0 0 0.15"/>
        <site name="inside" pos="0 0.01 0.02"/>
        <site name="s2" pos="0.2 0 0.04"/>
        <body name="l3" pos="0.4 0 0">
          <joint name="h3" type="hinge" axis="0 0 1"/>
          <joint name="sl" type="slide" axis="1 0 0" damping="1"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
          <site name="s3" pos="0.15 0.03 0"/>
          <site name="tip" pos="0.3 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <spatial name="over_cyl" stiffness="20" damping="0.5" springlength="0.5 0.6">
      <site site="base"/><geom geom="cyl"/><site site="s1"/><site site="s2"/>
    </spatial>
    <spatial name="over_ball" stiffness="10">
      <site site="s1"/><geom geom="ball" sidesite="side"/><site site="s3"/>
    </spatial>
    <spatial name="in_ball" damping="0.3">
      <site site="s1"/><geom geom="ball" sidesite="inside"/><site site="s3"/>
    </spatial>
    <spatial name="pulley" stiffness="5">
      <site site="s2"/><site site="s3"/><pulley divisor="2"/><site site="s2"/><site site="tip"/>
    </spatial>
  </tendon>
  <actuator>
    <motor tendon="over_cyl" gear="2"/>
    <position tendon="pulley" kp="10" kv="1"/>
    <motor joint="h3"/>
    <motor site="s3" gear="0.5 0 0.2 0 0 0.3"/>
  </actuator>
</mujoco>
"""

# (c) tendon armature: a fixed tendon along a chain, one coupling two trees (MuJoCo keeps only
# the inertia M has room for), and a spatial rope to a free body (its Jdot qvel bias); RK4.
ARMATURE = """
<mujoco>
  <option timestep="0.002" integrator="RK4"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="a">
      <joint name="a1" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="a2" pos="0.3 0 0">
        <joint name="a2" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <site name="sa2" pos="0.3 0 0"/>
      </body>
    </body>
    <body name="b" pos="0 0.5 0">
      <joint name="b1" type="hinge" axis="1 0 0"/>
      <geom type="box" size="0.1 0.05 0.05"/>
    </body>
    <body name="float" pos="0.5 0 0.4">
      <freejoint/>
      <geom type="box" size=".05 .05 .05"/>
      <site name="sf" pos="0.05 0.02 0"/>
    </body>
  </worldbody>
  <tendon>
    <fixed name="chain" armature="0.2">
      <joint joint="a1" coef="1"/><joint joint="a2" coef="0.5"/>
    </fixed>
    <fixed name="cross" armature="0.1" stiffness="5">
      <joint joint="a2" coef="1"/><joint joint="b1" coef="-1"/>
    </fixed>
    <spatial name="rope" armature="0.05" stiffness="10" damping="0.2">
      <site site="sa2"/><site site="sf"/>
    </spatial>
  </tendon>
  <actuator><motor tendon="chain"/></actuator>
</mujoco>
"""

MODELS = {"fixed": FIXED, "arm": ARM, "armature": ARMATURE}
NSTATES, NSTEPS, HOLD = 8, 500, 50  # random states; a 1 s trajectory, controls held 50 steps
# compared with mjData after mj_forward (besides ten_J and qM, which MuJoCo stores sparse)
FIELDS = (
    "ten_length", "ten_velocity", "qfrc_passive", "qfrc_bias", "actuator_length",
    "actuator_velocity", "actuator_force", "qfrc_actuator", "qacc",
)  # fmt: skip


def _mujoco(mj: mujoco.MjModel, md: mujoco.MjData) -> dict[str, np.ndarray]:
    ten_j = np.zeros((mj.ntendon, mj.nv))
    mujoco.mju_sparse2dense(ten_j, md.ten_J, mj.ten_J_rownnz, mj.ten_J_rowadr, mj.ten_J_colind)
    qm = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, md, qm)
    return {"ten_J": ten_j, "qM": qm} | {f: getattr(md, f).copy() for f in FIELDS}


def _check(name: str, ours: dict, ref: dict) -> None:
    for field, want in ref.items():
        got = np.asarray(ours[field])
        scale = max(1.0, float(np.abs(want).max(initial=0.0)))
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6 * scale, err_msg=f"{name}: {field}")


def _run(m: physics.Model):
    """One jitted function: ``forward`` at a batch of states, and a trajectory of ``step``s."""

    def run(qpos, qvel, ctrl, start, ctrls):
        def fwd(q, v, u):
            d = physics.forward(m, physics.make_data(m, qpos=q, qvel=v, ctrl=u))
            return {f: getattr(d, f) for f in ("ten_J", "qM", *FIELDS)}

        def step(d, u):
            d = physics.step(m, d, u)
            return d, d.qpos

        _, traj = jax.lax.scan(step, start, ctrls)
        return jax.vmap(fwd)(qpos, qvel, ctrl), traj

    return jax.jit(run)


def _wrapped(mj: mujoco.MjModel, md: mujoco.MjData) -> np.ndarray:
    """(ntendon,) bool: whether each tendon's path touches a geom now."""
    out = np.zeros(mj.ntendon, bool)
    for i in range(mj.ntendon):
        adr, num = md.ten_wrapadr[i], md.ten_wrapnum[i]
        objs = md.wrap_obj.ravel()[adr : adr + num]
        out[i] = np.any(objs >= 0)  # -1: a site, -2: a pulley, else the geom wrapped
    return out


@pytest.mark.parametrize("name", list(MODELS))
def test_tendons_match_mujoco_at_random_states_and_over_a_trajectory(name, x64):
    mj = mujoco.MjModel.from_xml_string(MODELS[name])
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    assert m.ntendon == mj.ntendon
    states = [random_state(mj, seed, qpos_scale=1.0) for seed in range(NSTATES)]
    qpos, qvel, ctrl = (np.stack(x) for x in zip(*states, strict=True))
    rng = np.random.default_rng(1)
    ctrls = np.repeat(rng.uniform(-1, 1, (NSTEPS // HOLD, mj.nu)), HOLD, axis=0)
    start = physics.make_data(m, qpos=qpos[0], qvel=0.5 * qvel[0])
    fwd, traj = _run(m)(qpos, qvel, ctrl, start, ctrls)

    wrapped = []
    for k in range(NSTATES):
        md.qpos[:], md.qvel[:], md.ctrl[:] = qpos[k], qvel[k], ctrl[k]
        mujoco.mj_forward(mj, md)
        _check(f"{name} state {k}", {f: v[k] for f, v in fwd.items()}, _mujoco(mj, md))
        wrapped.append(_wrapped(mj, md))
    if name == "arm":  # the states cover both sides of each wrap's switch
        wrapped = np.array(wrapped)[:, :3]
        assert wrapped.any(0).all() and (~wrapped).any(0).all(), wrapped

    mujoco.mj_resetData(mj, md)
    md.qpos[:], md.qvel[:] = qpos[0], 0.5 * qvel[0]
    worst = 0.0
    for t, u in enumerate(ctrls):
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        worst = max(worst, float(np.abs(np.asarray(traj[t]) - md.qpos).max()))
    assert worst < 1e-6, f"{name}: qpos parted from MuJoCo's by {worst:.2e} within 1 s"


def test_length_gradient_is_the_jacobian_where_the_path_is_shortest(x64):
    """The Jacobian MuJoCo builds from the tangent points (the arc's motion left out) is the
    gradient of the length wherever the wrapped path is the shortest one (envelope theorem):
    outside wraps around the cylinder (a helix) and the sphere, and the pulley. Hinge and slide
    joints only, so the gradient in qpos is the Jacobian in qvel. Also: no NaN in the gradient."""
    mj = mujoco.MjModel.from_xml_string(ARM)
    m = physics.model_from_mujoco(mj)
    shortest = np.array([0, 1, 3])  # in_ball wraps inside: not a shortest path

    def lengths(qpos):
        d = physics.make_data(m, qpos=qpos)
        d = smooth.com_pos(m, smooth.kinematics(m, d))
        return tendon.lengths_and_jacobians(m, d)

    jac_of = jax.jit(lambda q: (jax.jacfwd(lambda x: lengths(x)[0])(q), lengths(q)[1]))
    for seed in range(6):
        qpos, _, _ = random_state(mj, seed, qpos_scale=1.0)
        grad, jac = jac_of(jnp.asarray(qpos))
        assert np.isfinite(np.asarray(grad)).all()
        np.testing.assert_allclose(grad[shortest], jac[shortest], rtol=1e-7, atol=1e-9)


def test_model_without_tendons_or_with_inert_ones_keeps_none():
    """Tendons that only measure a length are dropped (their step stays a tendon-free one)."""
    xml = FIXED.replace('stiffness="8" damping="0.6"', "").replace('stiffness="3" damping="0.2"', "")
    xml = xml.replace('<motor tendon="couple" gear="1.5" forcelimited="true" forcerange="-0.8 0.8"/>', "")
    xml = xml.replace('<position tendon="chain" kp="4" kv="0.5"/>', "")
    m = physics.load_mjcf(xml)
    assert m.ntendon == 0 and m.tendon_stiffness.shape == (0,)
    d = physics.make_data(m)
    assert d.ten_length.shape == (0,) and d.ten_J.shape == (0, m.nv)
    full = physics.load_mjcf(FIXED)
    assert full.ntendon == 2 and physics.make_data(full).ten_J.shape == (2, 3)


def test_info_counts_tendons():
    lines = scene_info.summary_lines(physics.load_mjcf(ARM))
    assert "tendons         4 (0 fixed, 4 spatial; 2 actuated)" in lines
    lines = scene_info.summary_lines(physics.load_mjcf(FIXED))
    assert "tendons         2 (2 fixed, 0 spatial; 2 actuated)" in lines


@pytest.mark.parametrize(
    "attrs, word",
    [(' limited="true" range="0.3 0.305" margin="0.01"', "narrower than twice its margin")],
)
def test_unsimulated_tendon_features_raise_naming_the_tendon(attrs, word):
    xml = ARM.replace('<spatial name="over_cyl"', f'<spatial name="over_cyl"{attrs}')
    with pytest.raises(physics.UnsupportedFeatureError) as err:
        physics.load_mjcf(xml)
    assert "tendon 'over_cyl'" in str(err.value) and word in str(err.value)


def test_armature_on_a_wrapping_tendon_is_refused():
    """MuJoCo's compiler refuses it (no Jdot of a wrap); a model edited after compiling is too."""
    mj = mujoco.MjModel.from_xml_string(ARM)
    mj.tendon_armature[0] = 0.1
    with pytest.raises(physics.UnsupportedFeatureError, match="armature on a tendon wrapping a geom"):
        physics.model_from_mujoco(mj)


# Tendon constraint rows: a fixed tendon coupling two trees with limits and friction loss, a
# spatial cable through sites with limits and friction loss, and a tendon equality (a mimic joint
# driven by the coupling's length). The geoms do not collide: this model is about the rows.
ROWS = """
<mujoco><option timestep="0.002"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body pos="0 0 1">
      <joint name="a" type="hinge" axis="0 1 0" damping="0.02"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <site name="s1" pos="0.1 0 0.02"/>
      <body pos="0.3 0 0">
        <joint name="b" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
        <site name="s2" pos="0.2 0 0.02"/>
      </body>
    </body>
    <body pos="1 0 1">
      <joint name="c" type="hinge" axis="1 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0.3 0" size="0.02"/>
    </body>
    <site name="s0" pos="-0.1 0 1.05"/>
  </worldbody>
  <tendon>
    <fixed name="couple" limited="true" range="-0.3 0.4" frictionloss="0.2" margin="0.01">
      <joint joint="a" coef="1"/><joint joint="c" coef="-0.5"/></fixed>
    <spatial name="cable" limited="true" range="0.2 0.52" frictionloss="0.05" solreflimit="0.01 1">
      <site site="s0"/><site site="s1"/><site site="s2"/></spatial>
    <fixed name="mimic"><joint joint="b" coef="1"/></fixed>
  </tendon>
  <equality><tendon tendon1="mimic" tendon2="couple" polycoef="0.05 0.8 0.1 0 0"/></equality>
  <actuator><motor joint="a"/><motor tendon="cable" gear="3"/></actuator>
</mujoco>
"""


def test_tendon_limit_friction_and_equality_rows_match_mujoco(x64):
    mj = mujoco.MjModel.from_xml_string(ROWS)
    mj.opt.tolerance = 1e-14  # MuJoCo's solver converged: both find the same minimiser
    m = physics.model_from_mujoco(mj)
    md = mujoco.MjData(mj)
    forward = jax.jit(physics.forward)
    t = mujoco.mjtConstraint
    kinds = set()
    for seed in range(6):
        qpos, qvel, ctrl = random_state(mj, seed, qpos_scale=0.6)
        md.qpos[:], md.qvel[:], md.ctrl[:] = qpos, qvel, ctrl
        mujoco.mj_forward(mj, md)
        d = forward(m, physics.make_data(m, qpos=qpos, qvel=qvel, ctrl=ctrl))
        # MuJoCo's rows of each kind, in order, against ours with weight (inactive limits have none)
        ours_rows = np.flatnonzero(np.asarray(d.efc_D) > 0)[: md.nefc]
        mj_j = md.efc_J.reshape(md.nefc, mj.nv)
        for i, o in enumerate(ours_rows):
            kinds.add(int(md.efc_type[i]))
            np.testing.assert_allclose(d.efc_J[o], mj_j[i], atol=1e-12)
            np.testing.assert_allclose(d.efc_pos[o], md.efc_pos[i], atol=1e-12)
            np.testing.assert_allclose(d.efc_aref[o], md.efc_aref[i], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(d.efc_D[o], 1 / md.efc_R[i], rtol=1e-9)
            np.testing.assert_allclose(d.efc_force[o], md.efc_force[i], rtol=1e-6, atol=1e-6)
        scale = np.abs(md.qacc).max()
        np.testing.assert_allclose(d.qacc, md.qacc, atol=1e-6 * scale)
    assert {int(t.mjCNSTR_EQUALITY), int(t.mjCNSTR_FRICTION_TENDON), int(t.mjCNSTR_LIMIT_TENDON)} <= kinds
    # and over 1 s of random controls
    qpos, qvel, _ = random_state(mj, 5, qpos_scale=0.3)
    md.qpos[:], md.qvel[:] = qpos, qvel
    d = physics.make_data(m, qpos=qpos, qvel=qvel)
    step = jax.jit(physics.step)
    rng = np.random.default_rng(0)
    for _ in range(500):
        u = rng.uniform(-1, 1, mj.nu)
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        d = step(m, d, u)
    np.testing.assert_allclose(d.qpos, md.qpos, atol=1e-6)
