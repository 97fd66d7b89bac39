"""The divergence guard flags the divergent cases ``experiments/stability_map.py`` found.

The map runs random-action episodes over timestep x solver iterations for each env. Past its
stability limit a simulation blows up; ``Data.diverged`` must flag every such episode (and keep
it flagged) so ``Env.step`` ends and resets it before NaNs reach a learner, while at the shipped
setting it stays silent. ``test_contact.py`` checks the guard on a stiff spring; here it is
checked on cases the map found in real envs, so a regression in the guard (or a change that moves
the envs' stability limits) shows.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import envs, physics

EPISODES = 8
STEPS = 150  # control steps


# (env, integrator, solver iterations, a timestep the map found the guard flags in every episode)
# at the shipped integrator and iterations (conf/experiment/ant_ppo.yaml; the pendulum's asset).
# The Ant at 0.1 s (twice its 0.05 s control step, one physics step per control step) blows up
# within 20-80 control steps from qpos0, the InvertedDoublePendulum at 0.2 s (four times it)
# within 15; both are stable at their shipped timestep (0.01 s x 5).
# The Humanoid (RK4, 8 iterations) blows up at 0.015 s, its own control step taken as one physics
# step, in every map episode (median guard flag at control step 22, some after 150); at 0.0075 s
# x 2 in none. Its compile (~30 s) and longer rollout put it in the slow set.
CASES = [
    ("ant", "euler", 5, 0.1, STEPS),
    ("inverted_double_pendulum", "rk4", 8, 0.2, STEPS),
    pytest.param("humanoid", "rk4", 8, 0.015, 400, marks=pytest.mark.slow),
]


def _rollout(env: envs.Env, steps: int = STEPS):
    """Jitted ``(timestep, substeps) -> (guard flag, state finite)``, each (steps, EPISODES),
    after each control step of random actions held over its substeps, from the model's qpos0."""
    m = env.model
    lo, hi = env.action_bounds
    ctrl = jax.random.uniform(jax.random.PRNGKey(0), (steps, EPISODES, m.nu), minval=lo, maxval=hi)
    d0 = jax.vmap(lambda _: physics.make_data(m))(jnp.arange(EPISODES))

    def run(timestep, substeps):
        mt = m.replace(timestep=timestep)

        def control_step(d, u):
            d = jax.lax.fori_loop(0, substeps, lambda _, d: physics.step(mt, d, u), d)
            finite = jnp.all(jnp.isfinite(d.qpos)) & jnp.all(jnp.isfinite(d.qvel))
            return d, (d.diverged, finite)

        return jax.lax.scan(lambda d, u: jax.vmap(control_step)(d, u), d0, ctrl)[1]

    return jax.jit(run)


@pytest.mark.parametrize("name, integrator, iterations, divergent_timestep, steps", CASES)
def test_guard_flags_map_found_divergence(name, integrator, iterations, divergent_timestep, steps):
    env = envs.make(name, terminate_when_unhealthy=False, integrator=integrator, solver_iterations=iterations)
    run = _rollout(env, steps)

    flags, finite = (np.asarray(x) for x in run(env.model.timestep, jnp.int32(env.frame_skip)))
    assert finite.all() and not flags.any(), f"{name} diverged at its shipped setting"

    flags, finite = (np.asarray(x) for x in run(jnp.float32(divergent_timestep), jnp.int32(1)))
    assert flags[-1].all(), f"the guard missed {np.sum(~flags[-1])} of {EPISODES} blown-up episodes"
    assert np.all(flags[1:] >= flags[:-1])  # once set, it stays set
    assert np.all(flags | finite)  # no non-finite state goes unflagged
    assert (~finite).any()  # and these are real blow-ups, not the bound alone
