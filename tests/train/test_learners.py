"""SAC, FastTD3, ES and APG: unit oracles (replay buffer, ES gradient, APG gradient) and exact resume."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import agents, envs
from fastrl.agents import replay
from fastrl.agents.es import centered_ranks, es_gradient

from .test_front_door import _weights_of, compose_cfg, run


def test_replay_buffer_matches_a_python_ring_buffer():
    cap, rng = 10, np.random.default_rng(0)
    buf = replay.init(cap, {"x": jnp.zeros(2), "r": 0.0})
    ref = [None] * cap
    ptr = size = 0
    for n in (3, 4, 5, 7, 1):
        x = jnp.asarray(rng.normal(size=(n, 2)), jnp.float32)
        batch = {"x": x, "r": jnp.arange(n, dtype=jnp.float32)}
        buf = jax.jit(replay.insert)(buf, batch)
        for i in range(n):
            ref[ptr] = (np.asarray(batch["x"][i]), float(batch["r"][i]))
            ptr, size = (ptr + 1) % cap, min(size + 1, cap)
        assert int(buf.ptr) == ptr and int(buf.size) == size
        for i in range(size):
            np.testing.assert_array_equal(buf.data["x"][i], ref[i][0])
            assert float(buf.data["r"][i]) == ref[i][1]
    # Sampling only returns stored items, and covers them.
    small = replay.insert(replay.init(cap, {"v": 0.0}), {"v": jnp.arange(1.0, 5.0)})
    drawn = np.asarray(replay.sample(small, jax.random.PRNGKey(0), 2000)["v"])
    assert set(np.unique(drawn)) == {1.0, 2.0, 3.0, 4.0}


def test_es_gradient_estimate_matches_the_true_gradient_on_a_quadratic():
    dim, sigma, pairs = 5, 0.05, 20000
    a = jnp.linspace(0.5, 2.0, dim)
    theta = jnp.linspace(-1.0, 1.0, dim)
    f = lambda x: -jnp.sum(a * x**2, axis=-1)  # noqa: E731
    eps = jax.random.normal(jax.random.PRNGKey(0), (pairs, dim))
    fitness = f(theta + sigma * jnp.concatenate([eps, -eps]))
    est = es_gradient(fitness, eps, sigma)
    true = -2 * a * theta
    np.testing.assert_allclose(est, true, atol=0.05 * float(jnp.linalg.norm(true)))
    # Centred ranks keep the ascent direction.
    shaped = es_gradient(centered_ranks(fitness), eps, sigma)
    assert float(jnp.dot(shaped, true)) / float(jnp.linalg.norm(shaped) * jnp.linalg.norm(true)) > 0.9
    np.testing.assert_allclose(centered_ranks(jnp.array([3.0, 1.0, 2.0])), [0.5, -0.5, 0.0])


def test_apg_gradient_is_finite_and_matches_finite_differences():
    """APG's own window loss on a short pendulum horizon, through the physics: its gradient must
    match finite differences, which see every path from the weights to the return, including
    through the states earlier actions led to (a gradient that treats observations as constants
    cannot learn feedback and fails this)."""
    from jax.flatten_util import ravel_pytree

    from fastrl.agents import apg
    from fastrl.agents.base import observation_normalizer
    from fastrl.agents.networks import MLP, TanhGaussian

    with jax.enable_x64(True):
        env = envs.make("inverted_pendulum", reward_weights={"upright": 1.0, "centered": 0.1})
        config = agents.APGConfig(num_envs=2, horizon=12)
        low, high = (jnp.asarray(b) for b in env.action_bounds)
        net = MLP([6], 2 * env.action_size, "tanh", final_scale=1.0)
        window = apg.make_window(
            config, jax.vmap(env.step), net, TanhGaussian(low, high), observation_normalizer(False)
        )
        params = jax.tree.map(
            lambda x: x.astype(jnp.float64), net.init(jax.random.PRNGKey(1), jnp.zeros((1, 4)))
        )
        start = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
        flat, unravel = ravel_pytree(params)
        loss = jax.jit(lambda x: window(unravel(x), None, start, jax.random.PRNGKey(2))[0])
        grad = jax.grad(loss)(flat)
        assert np.all(np.isfinite(grad))
        rng, h = np.random.default_rng(0), 1e-6
        for _ in range(3):
            v = rng.normal(size=flat.shape)
            fd = (loss(flat + h * v) - loss(flat - h * v)) / (2 * h)
            np.testing.assert_allclose(float(grad @ v), float(fd), rtol=1e-5)


def test_apg_refuses_envs_with_useless_gradients():
    env = envs.make("hopper")
    with pytest.raises(agents.UnsuitableEnvError, match="hopper.*algo=ppo.*allow_unsuitable"):
        agents.make_apg(agents.APGConfig(), env, agents.NetworkConfig())


@pytest.mark.parametrize(
    "algo,env_name",
    [
        ("sac", "inverted_pendulum"),  # the replay buffer must come back exactly
        ("fasttd3", "inverted_pendulum"),  # its trajectory ring and exploration scales too
        # ES and APG resume through the same runner and checkpoint code; slow to keep CI short.
        pytest.param("es", "inverted_pendulum", marks=pytest.mark.slow),
        pytest.param("apg", "inverted_pendulum", marks=pytest.mark.slow),
    ],
)
def test_exact_resume(tmp_path, algo, env_name):
    base = [f"algo={algo}", f"env={env_name}", "debug=quick", "logger=quiet", "train.updates_per_chunk=1"]
    # 4 updates each: sac 16 envs x 1 step, es 8 members x 20 steps, apg 8 envs x 8 steps; fasttd3
    # 8 of 16 envs, learning from the 5th (after the resume).
    base.append(f"train.total_env_steps={ {'sac': 64, 'fasttd3': 128, 'es': 640, 'apg': 256}[algo] }")
    full = run(compose_cfg([*base, f"run_dir={tmp_path}/full"]))
    part = run(compose_cfg([*base, f"run_dir={tmp_path}/split", "train.stop_after_chunks=2"]))
    assert part["status"] == "stopped" and full["chunks"] > 2
    done = run(compose_cfg([*base, f"run_dir={tmp_path}/x", f"resume={tmp_path}/split"]))
    assert done["chunks"] == full["chunks"]
    a, b = _weights_of(tmp_path / "full"), _weights_of(tmp_path / "split")
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def _ppo_after_one_update(**overrides):
    env = envs.make("inverted_pendulum")
    cfg = agents.PPOConfig(num_envs=8, unroll_length=16, num_minibatches=2, **overrides)
    net = agents.NetworkConfig(policy_hidden=(8,), value_hidden=(8,), activation="tanh")
    learner = agents.make_learner("ppo", cfg, env, net, total_updates=1)
    state, _ = jax.jit(learner.update)(learner.init(jax.random.PRNGKey(0)))
    return jax.tree.leaves(state.params)


def test_ppo_recomputed_advantages_match_on_the_first_epoch_and_then_move():
    # The first epoch sees the collecting network either way; later epochs see the updated one.
    once = _ppo_after_one_update(update_epochs=1)
    again = _ppo_after_one_update(update_epochs=1, recompute_advantages=True)
    for a, b in zip(once, again, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    fixed = _ppo_after_one_update(update_epochs=3)
    fresh = _ppo_after_one_update(update_epochs=3, recompute_advantages=True)
    assert max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(fixed, fresh, strict=True)) > 1e-5


class _PrivilegedPendulum(envs.manipulation.InvertedPendulum):
    """The cart-pole with privileged state for a critic appended to its observation (qvel x 3)."""

    def _observe(self, model, data):
        return jnp.concatenate([super()._observe(model, data), 3.0 * data.qvel])

    @property
    def policy_observation_size(self) -> int:
        return self.observation_size - self.model.nv


def test_ppo_reads_privileged_state_in_its_critic_only():
    """An env whose observation appends privileged state (``policy_observation_size``): PPO's
    value network reads the whole observation, its policy only the leading part, so the
    trained policy's actions do not change with the privileged entries and it acts on the
    policy's part alone (as in MuJoCo C, where no privileged state is computed). Learners
    without a separate critic input refuse such an env."""
    env = _PrivilegedPendulum()
    k, n = env.policy_observation_size, env.observation_size
    assert (k, n) == (4, 6)
    config = agents.PPOConfig(num_envs=8, unroll_length=4, num_minibatches=2, update_epochs=1)
    learner = agents.make_learner("ppo", config, env, agents.NetworkConfig(), total_updates=2)
    state, _ = jax.jit(learner.update)(learner.init(jax.random.PRNGKey(0)))
    first = lambda net: jax.tree.leaves(net)[1].shape[0]  # noqa: E731 - Dense_0's kernel rows
    assert first(state.params["policy"]) == k and first(state.params["value"]) == n
    pp = learner.policy_params(state)
    obs = state.env_state.obs
    other = obs.at[:, k:].set(jax.random.normal(jax.random.PRNGKey(1), (obs.shape[0], n - k)))
    act = jax.jit(learner.act)
    np.testing.assert_array_equal(act(pp, obs), act(pp, other))
    np.testing.assert_array_equal(act(pp, obs), act(pp, obs[:, :k]))
    assert float(jnp.abs(state.obs_stats.mean[k:]).sum()) > 0  # the normaliser saw the critic's part
    for algo in ("sac", "es", "apg"):
        cfg = agents.config_class(algo)()
        with pytest.raises(agents.UnsuitableEnvError, match="privileged critic state"):
            agents.make_learner(algo, cfg, env, agents.NetworkConfig(), total_updates=1)
