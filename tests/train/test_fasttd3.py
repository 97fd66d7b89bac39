"""FastTD3: its distributional projection and n-step replay against plain-Python references,
and the privileged critic (its exact resume: tests/train/test_learners.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import agents
from fastrl.agents import replay
from fastrl.agents.fasttd3 import project

from .test_learners import _PrivilegedPendulum


def _project_reference(probs, reward, discount, atoms):
    """C51's projection as Bellemare et al. write it: each shifted atom's mass to the floor and
    ceiling of its position, all of it to the floor where the two coincide."""
    v_min, v_max, n = atoms[0], atoms[-1], len(atoms)
    dz = (v_max - v_min) / (n - 1)
    out = np.zeros_like(probs)
    for b in range(probs.shape[0]):
        for j in range(n):
            tz = min(max(reward[b] + discount[b] * atoms[j], v_min), v_max)
            pos = (tz - v_min) / dz
            lo, hi = int(np.floor(pos)), int(np.ceil(pos))
            if lo == hi:
                out[b, lo] += probs[b, j]
            else:
                out[b, lo] += probs[b, j] * (hi - pos)
                out[b, hi] += probs[b, j] * (pos - lo)
    return out


def test_projection_matches_the_c51_reference_and_keeps_mass():
    rng = np.random.default_rng(0)
    atoms = np.linspace(-10.0, 10.0, 11)
    probs = rng.dirichlet(np.ones(11), size=6)
    # Shifts inside the support, beyond both ends, exactly onto atoms, and a terminal (discount 0).
    reward = np.array([0.3, 25.0, -40.0, 2.0, -1.7, 4.2])
    discount = np.array([0.97, 0.99, 0.5, 1.0, 0.0, 0.9])
    got = np.asarray(
        project(jnp.asarray(probs), jnp.asarray(reward), jnp.asarray(discount), jnp.asarray(atoms))
    )
    np.testing.assert_allclose(got, _project_reference(probs, reward, discount, atoms), atol=1e-6)
    np.testing.assert_allclose(got.sum(-1), 1.0, atol=1e-6)
    assert got[1, -1] == pytest.approx(1.0) and got[2, 0] == pytest.approx(1.0)


def _n_step_reference(steps, first, env, n, gamma):
    """The n-step transition starting at step ``first`` of env ``env``, summed by hand."""
    ret, k = 0.0, 0
    while True:
        ret += gamma**k * steps["reward"][first + k, env]
        if steps["done"][first + k, env] or k == n - 1:
            break
        k += 1
    last = first + k
    discount = gamma ** (k + 1) * (0.0 if steps["terminated"][last, env] else 1.0)
    return ret, steps["next_obs"][last, env], discount


def test_n_step_samples_match_a_hand_sum_and_stop_at_episode_ends():
    rng = np.random.default_rng(1)
    length, num_envs, n, gamma, written = 12, 3, 3, 0.9, 17
    steps = {
        # Each step's observation is (its step, its env), so a sample says where it started.
        "obs": np.stack(np.meshgrid(np.arange(written), np.arange(num_envs), indexing="ij"), -1).astype(
            np.float32
        ),
        "action": rng.normal(size=(written, num_envs, 1)).astype(np.float32),
        "reward": rng.normal(size=(written, num_envs)).astype(np.float32),
        "terminated": rng.random((written, num_envs)) < 0.15,
        "next_obs": rng.normal(size=(written, num_envs, 2)).astype(np.float32),
    }
    steps["done"] = steps["terminated"] | (rng.random((written, num_envs)) < 0.15)
    example = {k: jnp.zeros(v.shape[2:], v.dtype) for k, v in steps.items()}
    buf = replay.init_trajectories(length, num_envs, example)
    for lo, hi in ((0, 5), (5, 6), (6, 17)):  # wraps around: the oldest 5 steps are overwritten
        buf = replay.append(buf, {k: jnp.asarray(v[lo:hi]) for k, v in steps.items()})
    assert int(buf.size) == length and int(buf.ptr) == written % length
    batch = jax.jit(replay.sample_n_step, static_argnums=(2, 3, 4))(
        buf, jax.random.PRNGKey(0), 4000, n, gamma
    )
    starts = set()
    obs_index = {
        (tuple(np.round(steps["obs"][t, e], 6)), e): t for t in range(written) for e in range(num_envs)
    }
    for i in range(4000):
        obs = np.asarray(batch["obs"][i])
        ((t, e),) = [(t, e) for (o, e), t in obs_index.items() if o == tuple(np.round(obs, 6))]
        starts.add((t, e))
        ret, next_obs, discount = _n_step_reference(steps, t, e, n, gamma)
        np.testing.assert_allclose(float(batch["reward"][i]), ret, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(np.asarray(batch["next_obs"][i]), next_obs)
        np.testing.assert_allclose(float(batch["discount"][i]), discount, rtol=1e-6)
        np.testing.assert_array_equal(np.asarray(batch["action"][i]), steps["action"][t, e])
    # Every start whose n steps are stored is drawn, and no other.
    assert starts == {(t, e) for t in range(written - length, written - n + 1) for e in range(num_envs)}


def test_fasttd3_reads_privileged_state_in_its_critics_only():
    env = _PrivilegedPendulum()
    k, n = env.policy_observation_size, env.observation_size
    config = agents.FastTD3Config(num_envs=8, batch_size=16, buffer_size=256, learning_starts=16)
    net = agents.NetworkConfig(policy_hidden=(8,), value_hidden=(8,))
    learner = agents.make_learner("fasttd3", config, env, net, total_updates=1)
    update = jax.jit(learner.update)
    state = learner.init(jax.random.PRNGKey(0))
    before = state.params["policy"]
    for _ in range(4):
        state, metrics = update(state)
    assert all(np.isfinite(float(v)) for v in metrics.values())
    # It learned (the actor moved), its actor reads k entries and its critics all n (+ action).
    moved = jax.tree.map(lambda a, b: float(jnp.max(jnp.abs(a - b))), before, state.params["policy"])
    assert max(jax.tree.leaves(moved)) > 0
    rows = lambda net: jax.tree.leaves(net)[1].shape[-2]  # noqa: E731 - Dense_0's kernel rows
    assert rows(state.params["policy"]) == k and rows(state.params["q"]) == n + env.action_size
    pp = learner.policy_params(state)
    obs = state.env_state.obs
    other = obs.at[:, k:].set(jax.random.normal(jax.random.PRNGKey(1), (obs.shape[0], n - k)))
    act = jax.jit(learner.act)
    np.testing.assert_array_equal(act(pp, obs), act(pp, other))
    np.testing.assert_array_equal(act(pp, obs), act(pp, obs[:, :k]))


def test_fasttd3_config_names_what_is_wrong():
    with pytest.raises(ValueError, match="buffer_size=64 holds 4 steps"):
        agents.FastTD3Config(num_envs=16, buffer_size=64, n_step=5)
    with pytest.raises(ValueError, match="v_min < v_max"):
        agents.FastTD3Config(v_min=1.0, v_max=-1.0)
