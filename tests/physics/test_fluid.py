"""The inertia-box fluid model against MuJoCo C (the oracle), and which tendons a model may have."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from tests.conftest import random_state

# A free body with an off-axis inertial frame (two geoms), a hinged tail (so the fluid wrench of
# one body reaches dofs of another) and a massless marker body, which MuJoCo's model skips.
KITE = """
<mujoco>
  <option density="{density}" viscosity="0.05" wind="3 -1 0.5" timestep="0.005"/>
  <worldbody>
    <body name="kite" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="0.3 0.1 0.02" euler="10 20 30" mass="0.4"/>
      <geom type="sphere" size="0.05" pos="0.2 0.1 0" mass="0.1"/>
      <body name="marker" pos="0 0 0.1"><site size="0.01"/></body>
      <body name="tail" pos="-0.3 0 0">
        <joint name="flap" type="hinge" axis="0 1 0" damping="0.01"/>
        <geom type="capsule" fromto="0 0 0 -0.4 0 0" size="0.02" mass="0.05"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _gym_asset(name: str) -> str:
    gym = pytest.importorskip("gymnasium")
    return os.path.join(os.path.dirname(gym.__file__), "envs", "mujoco", "assets", f"{name}.xml")


def _rel_err(ours, ref) -> float:
    ours, ref = np.asarray(ours), np.asarray(ref)
    return float(np.max(np.abs(ours - ref)) / (np.max(np.abs(ref)) + 1e-12))


def _passive_error(mj: mujoco.MjModel, m: physics.Model, seeds=range(5)) -> float:
    """Largest relative ``qfrc_passive`` error over random states (large velocities: drag is
    quadratic, so both regimes show)."""
    md = mujoco.MjData(mj)
    forward = jax.jit(physics.forward_forces)
    worst = 0.0
    for seed in seeds:
        qpos, qvel, _ = random_state(mj, seed, qpos_scale=1.0, qvel_scale=3.0)
        md.qpos[:], md.qvel[:] = qpos, qvel
        mujoco.mj_forward(mj, md)
        d = forward(m, physics.make_data(m, qpos=qpos, qvel=qvel))
        assert np.max(np.abs(md.qfrc_fluid)) > 1e-3  # the test is not vacuous
        worst = max(worst, _rel_err(d.qfrc_passive, md.qfrc_passive))
    return worst


def _trajectories(mj: mujoco.MjModel, m: physics.Model, steps: int, seed: int):
    """(steps, nq + nv) states of MuJoCo and fastrl from one random start under random controls."""
    qpos, qvel, _ = random_state(mj, seed, qpos_scale=0.5, qvel_scale=1.0)
    ctrls = np.random.default_rng(seed).uniform(-1, 1, (steps, mj.nu))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = qpos, qvel
    ref = []
    for u in ctrls:
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        ref.append(np.concatenate([md.qpos, md.qvel]))

    def body(d, u):
        d = physics.step(m, d, u)
        return d, jnp.concatenate([d.qpos, d.qvel])

    d0 = physics.make_data(m, qpos=qpos, qvel=qvel)
    _, ours = jax.jit(lambda d, c: jax.lax.scan(body, d, c))(d0, jnp.asarray(ctrls))
    return np.array(ref), np.asarray(ours)


def test_swimmer_passive_forces_match_mujoco(x64):
    mj = mujoco.MjModel.from_xml_path(_gym_asset("swimmer"))
    m = physics.model_from_mujoco(mj)
    assert list(m.body_fluid) == [0, 1, 1, 1]
    assert _passive_error(mj, m) < 1e-5
    # The medium is traced: a randomised one matches MuJoCo with the same options.
    mj.opt.density, mj.opt.viscosity, mj.opt.wind = 1000.0, 0.3, (0.5, -0.2, 0.1)
    m = m.replace(density=jnp.array(1000.0), viscosity=jnp.array(0.3), wind=jnp.array([0.5, -0.2, 0.1]))
    assert _passive_error(mj, m) < 1e-5


def test_swimmer_rk4_trajectory_matches_mujoco(x64):
    mj = mujoco.MjModel.from_xml_path(_gym_asset("swimmer"))
    assert mj.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    ref, ours = _trajectories(mj, physics.model_from_mujoco(mj), steps=100, seed=3)
    assert np.all(np.isfinite(ours))
    assert _rel_err(ours, ref) < 1e-6


@pytest.mark.parametrize("density", [0.0, 1.2])
def test_free_body_in_wind_matches_mujoco(density, x64):
    mj = mujoco.MjModel.from_xml_string(KITE.format(density=density))
    m = physics.model_from_mujoco(mj)
    assert list(m.body_fluid) == [0, 1, 0, 1]  # the marker has no mass
    assert _passive_error(mj, m) < 1e-5
    ref, ours = _trajectories(mj, m, steps=200, seed=5)
    assert _rel_err(ours, ref) < 1e-6


def test_fluid_gradient_matches_finite_differences(x64):
    """Fluid forces are differentiable in the medium and in the body mass (through the box).

    Differentiated at the force level: a gradient through whole trajectories costs a long
    compile and tests the integrator more than the fluid model.
    """
    mj = mujoco.MjModel.from_xml_string(KITE.format(density=1.2))
    m = physics.model_from_mujoco(mj)
    qpos, qvel, _ = random_state(mj, seed=2, qpos_scale=1.0, qvel_scale=3.0)
    weights = jnp.asarray(np.random.default_rng(2).standard_normal(mj.nv))
    names = ("density", "viscosity", "wind", "body_mass")

    def work(params):
        mm = m.replace(**params)
        d = physics.forward_forces(mm, physics.make_data(mm, qpos=qpos, qvel=qvel))
        return weights @ d.qfrc_passive

    params = {n: getattr(m, n) for n in names}
    value_and_grad = jax.jit(jax.value_and_grad(work))  # one compile for value and gradient
    grad = value_and_grad(params)[1]
    eps = 1e-6
    for name, index in [("density", ()), ("viscosity", ()), ("wind", (2,)), ("body_mass", (1,))]:
        up = {**params, name: params[name].at[index].add(eps)}
        down = {**params, name: params[name].at[index].add(-eps)}
        fd = (value_and_grad(up)[0] - value_and_grad(down)[0]) / (2 * eps)
        assert np.isfinite(grad[name]).all()
        np.testing.assert_allclose(grad[name][index], fd, rtol=1e-6, err_msg=name)


def test_no_medium_traces_no_fluid_code():
    mj = mujoco.MjModel.from_xml_string(KITE.format(density=0.0).replace('viscosity="0.05"', ""))
    m = physics.model_from_mujoco(mj)
    assert not m.body_fluid.any()
    # Springs and dampers both disabled switch MuJoCo's fluid forces off too.
    mj = mujoco.MjModel.from_xml_string(KITE.format(density=1.2))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SPRING | mujoco.mjtDisableBit.mjDSBL_DAMPER
    assert not physics.model_from_mujoco(mj).body_fluid.any()


def test_humanoid_loads_with_inert_tendons():
    mj = mujoco.MjModel.from_xml_path(_gym_asset("humanoid"))
    assert mj.ntendon == 2
    m = physics.model_from_mujoco(mj)
    assert (m.nq, m.nv, m.nu, m.ntendon) == (24, 23, 17, 0)  # inert: dropped


TENDON_MODEL = """
<mujoco>
  <worldbody>
    <site name="s0" pos="0 0 1"/>
    <body name="b">
      <joint name="j" type="hinge" axis="0 1 0"/>
      <geom size="0.1" contype="0" conaffinity="0"/>
      <site name="s1" pos="0.2 0 0"/>
    </body>
  </worldbody>
  <tendon>{tendon}</tendon>
  {actuator}
</mujoco>
"""
FIXED = '<fixed name="t"{attrs}><joint joint="j" coef="1"/></fixed>'
SPATIAL = '<spatial name="t"{attrs}><site site="s0"/><site site="s1"/></spatial>'


@pytest.mark.parametrize("shape", [FIXED, SPATIAL])
def test_inert_tendons_are_ignored(shape):
    m = physics.load_mjcf(TENDON_MODEL.format(tendon=shape.format(attrs=""), actuator=""))
    assert m.nv == 1


@pytest.mark.parametrize(
    "shape, attrs, actuator, word",
    [
        (FIXED, ' range="-1 -0.99" margin="0.1"', "", "narrower than twice its margin"),
        (SPATIAL, ' limited="true" range="0 0.01" margin="0.1"', "", "narrower than twice its margin"),
    ],
)
def test_active_tendons_raise_naming_the_tendon(shape, attrs, actuator, word):
    xml = TENDON_MODEL.format(tendon=shape.format(attrs=attrs), actuator=actuator)
    with pytest.raises(physics.UnsupportedFeatureError) as err:
        physics.load_mjcf(xml)
    assert "tendon 't'" in str(err.value) and word in str(err.value)
