"""Checks against closed-form physics: free fall, pendulum period, energy, momentum."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import math
from tests.conftest import asset

FALLING_BALL = """
<mujoco><option timestep="{dt}" integrator="{integrator}"/>
  <worldbody><body pos="0 0 10">
    <freejoint/><geom type="sphere" size="0.1" contype="0" conaffinity="0"/>
  </body></worldbody>
</mujoco>"""

# A rod pendulum with a heavy tip (no damping, no armature): period from I / (m g d).
PENDULUM = """
<mujoco><option timestep="{dt}" integrator="{integrator}"/>
  <worldbody><body pos="0 0 2">
    <joint name="hinge" type="hinge" axis="0 1 0"/>
    <geom type="sphere" pos="0 0 -1" size="0.05" mass="1" contype="0" conaffinity="0"/>
  </body></worldbody>
</mujoco>"""


def _rollout(m, d, n, ctrl_fn=None):
    """States after each of n steps, as a Data pytree with a leading time axis."""

    def body(d, i):
        ctrl = None if ctrl_fn is None else ctrl_fn(i)
        d = physics.step(m, d, ctrl)
        return d, d

    return jax.jit(lambda d: jax.lax.scan(body, d, jnp.arange(n))[1])(d)


@pytest.mark.parametrize("integrator", ["Euler", "RK4"])
def test_free_fall(integrator, x64):
    dt, n = 0.01, 100
    m = physics.load_mjcf(FALLING_BALL.format(dt=dt, integrator=integrator))
    traj = _rollout(m, physics.make_data(m), n)
    g = 9.81
    t = dt * np.arange(1, n + 1)
    if integrator == "Euler":  # semi-implicit: z_n = z0 - g dt^2 n (n + 1) / 2
        k = np.arange(1, n + 1)
        expected = 10 - g * dt**2 * k * (k + 1) / 2
    else:  # RK4 integrates constant acceleration exactly
        expected = 10 - 0.5 * g * t**2
    np.testing.assert_allclose(np.asarray(traj.qpos[:, 2]), expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(traj.qvel[:, 2]), -g * t, rtol=0, atol=1e-9)


def test_pendulum_small_angle_period(x64):
    dt = 0.001
    m = physics.load_mjcf(PENDULUM.format(dt=dt, integrator="RK4"))
    inertia = float(m.body_inertia[1, 1]) + 1.0 * 1.0**2  # about the pivot: I_com + m d^2
    expected = 2 * np.pi * np.sqrt(inertia / (1.0 * 9.81 * 1.0))
    traj = _rollout(m, physics.make_data(m, qpos=np.array([0.01])), int(3 * expected / dt))
    angle = np.asarray(traj.qpos[:, 0])
    # Upward zero crossings, linearly interpolated, give the period.
    idx = np.flatnonzero((angle[:-1] < 0) & (angle[1:] >= 0))
    crossings = (idx + angle[idx] / (angle[idx] - angle[idx + 1]) + 1) * dt
    period = np.mean(np.diff(crossings))
    assert abs(period - expected) / expected < 1e-3


def _pendulum_energy_drift(integrator: str) -> float:
    dt = 0.01
    m = physics.load_mjcf(PENDULUM.format(dt=dt, integrator=integrator))
    traj = _rollout(m, physics.make_data(m, qpos=np.array([1.0])), 2000)
    inertia = float(m.body_inertia[1, 1]) + 1.0
    theta, omega = np.asarray(traj.qpos[:, 0]), np.asarray(traj.qvel[:, 0])
    energy = 0.5 * inertia * omega**2 - 9.81 * np.cos(theta)  # tip 1 m below the pivot
    e0 = -9.81 * np.cos(1.0)
    return float(np.max(np.abs(energy - e0)))


def test_rk4_energy_drift_smaller_than_euler(x64):
    euler, rk4 = _pendulum_energy_drift("Euler"), _pendulum_energy_drift("RK4")
    assert rk4 < euler / 100, (euler, rk4)
    assert rk4 < 1e-4


def _momentum_drift(integrator: str, dt: float, seconds: float = 0.5):
    """Max relative change of the Ant's spatial momentum (zero gravity, random joint torques)."""
    mj = mujoco.MjModel.from_xml_path(asset("ant_air"))
    mj.opt.timestep = dt
    m = physics.model_from_mujoco(mj, integrator=integrator)
    d = physics.make_data(m, qvel=np.concatenate([[0.3, -0.2, 0.1, 0.5, -0.4, 0.2], np.zeros(8)]))
    n = int(round(seconds / dt))
    ctrls = jax.random.uniform(jax.random.PRNGKey(0), (n, m.nu), minval=-1, maxval=1)

    def momentum(d):  # spatial momentum about the tree's com (angular, linear), world axes
        d = physics.forward(m, d)
        return jnp.sum(math.mul_inert_vec(d.cinert, d.cvel), axis=0)

    def body(d, u):
        d = physics.step(m, d, u)
        return d, (momentum(d), jnp.max(jnp.abs(d.qpos[7:])))

    _, (p, joint_travel) = jax.jit(lambda d: jax.lax.scan(body, d, ctrls))(d)
    p0 = momentum(d)
    assert float(jnp.max(joint_travel)) > 0.1  # the legs really moved
    return float(jnp.max(jnp.abs(p - p0)) / jnp.max(jnp.abs(p0)))


def test_momentum_conserved_to_float32_precision_with_rk4():
    """Internal torques cannot change momentum; RK4 at a fine step keeps it to rounding."""
    assert _momentum_drift("rk4", dt=0.001) < 2e-5


@pytest.mark.slow  # in the default suite, tests/test_experiments.py::test_conservation_quick checks this
def test_euler_momentum_drift_is_discretisation_error(x64):
    """Semi-implicit Euler conserves momentum only to O(h): the drift must shrink with dt."""
    coarse, fine = _momentum_drift("euler", 0.01), _momentum_drift("euler", 0.001)
    assert fine < coarse / 10, (coarse, fine)
    assert _momentum_drift("rk4", 0.001) < 1e-6
