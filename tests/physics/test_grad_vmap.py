"""Differentiability (against finite differences) and batching over states and models."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import physics
from tests.conftest import asset


def _final_angle(m, ctrls):
    d = physics.make_data(m, qpos=jnp.array([0.3], ctrls.dtype))
    d = jax.lax.scan(lambda d, u: (physics.step(m, d, u), None), d, ctrls)[0]
    return d.qpos[0] + 0.1 * d.qvel[0]


# RK4's (about 50 s) runs with the slow tests; both integrators share every other stage.
@pytest.mark.parametrize("integrator", ["euler", pytest.param("rk4", marks=pytest.mark.slow)])
def test_gradient_matches_finite_differences(integrator, x64):
    m = physics.load_mjcf(asset("pendulum"), integrator=integrator)
    ctrls = 0.5 * jnp.sin(jnp.arange(100.0) / 7.0)[:, None]
    f_ctrl = jax.jit(lambda c: _final_angle(m, c))
    grad_ctrl = jax.grad(f_ctrl)(ctrls)
    assert np.all(np.isfinite(grad_ctrl))
    eps = 1e-6
    for t in (0, 37, 99):
        bump = jnp.zeros_like(ctrls).at[t, 0].set(eps)
        fd = (f_ctrl(ctrls + bump) - f_ctrl(ctrls - bump)) / (2 * eps)
        np.testing.assert_allclose(grad_ctrl[t, 0], fd, rtol=1e-5, atol=1e-9)

    # Model parameters: the pole's mass and the joint damping.
    def f_params(mass, damping):
        mm = m.replace(body_mass=m.body_mass.at[1].set(mass), dof_damping=damping)
        return _final_angle(mm, ctrls)

    mass, damping = m.body_mass[1], m.dof_damping
    g_mass, g_damp = jax.jit(jax.grad(f_params, argnums=(0, 1)))(mass, damping)
    f_params = jax.jit(f_params)
    fd_mass = (f_params(mass + eps, damping) - f_params(mass - eps, damping)) / (2 * eps)
    fd_damp = (f_params(mass, damping + eps) - f_params(mass, damping - eps)) / (2 * eps)
    np.testing.assert_allclose(g_mass, fd_mass, rtol=1e-5)
    np.testing.assert_allclose(g_damp[0], fd_damp, rtol=1e-5)


def test_gradient_finite_through_free_joint():
    """A scalar of the Ant's state after 100 steps has a finite gradient w.r.t. controls."""
    m = physics.load_mjcf(asset("ant_air"))
    ctrls = 0.3 * jnp.ones((100, m.nu))

    def loss(c):
        d = jax.lax.scan(lambda d, u: (physics.step(m, d, u), None), physics.make_data(m), c)[0]
        return jnp.sum(d.qpos**2) + jnp.sum(d.qvel**2)

    g = jax.jit(jax.grad(loss))(ctrls)
    assert np.all(np.isfinite(g)) and float(jnp.max(jnp.abs(g))) > 0


def test_vmap_over_states_matches_single_steps():
    m = physics.load_mjcf(asset("ant_air"))
    key = jax.random.PRNGKey(1)
    qvel = 0.5 * jax.random.normal(key, (16, m.nv))
    ctrl = jax.random.uniform(key, (16, m.nu), minval=-1, maxval=1)
    batch = jax.vmap(lambda v: physics.make_data(m, qvel=v))(qvel)
    stepped = jax.jit(jax.vmap(lambda d, u: physics.step(m, d, u)))(batch, ctrl)
    single = jax.jit(lambda d, u: physics.step(m, d, u))
    for i in (0, 5, 15):
        one = single(physics.make_data(m, qvel=qvel[i]), ctrl[i])
        np.testing.assert_allclose(stepped.qpos[i], one.qpos, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(stepped.qvel[i], one.qvel, rtol=1e-5, atol=1e-5)


def test_vmap_over_models_with_randomised_masses_compiles_once():
    m = physics.load_mjcf(asset("cartpole"))
    scales = jnp.linspace(0.5, 2.0, 8)
    models = jax.vmap(lambda s: m.replace(body_mass=m.body_mass * s))(scales)
    traces = []

    def run(models):
        traces.append(1)
        return jax.vmap(lambda mm: physics.step(mm, physics.make_data(mm), jnp.ones(1)))(models)

    run_jit = jax.jit(run)
    out = run_jit(models)
    run_jit(jax.vmap(lambda s: m.replace(body_mass=m.body_mass * s))(scales[::-1]))
    assert len(traces) == 1
    # Heavier carts accelerate less under the same force.
    accel = np.asarray(out.qvel[:, 0])
    assert np.all(np.diff(accel) < 0)
    for i in (0, 7):
        mm = m.replace(body_mass=m.body_mass * scales[i])
        one = physics.step(mm, physics.make_data(mm), jnp.ones(1))
        np.testing.assert_allclose(out.qvel[i], one.qvel, rtol=1e-5)
