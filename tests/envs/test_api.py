"""Env API: registry, auto-reset, reset statistics, domain randomisation, Gymnasium adapters."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from fastrl import envs
from fastrl.envs import wrappers


@pytest.fixture(scope="module")
def pendulum():
    return envs.make("inverted_pendulum", episode_length=7)


def test_registry_lists_the_suite_and_rejects_unknown_names():
    expected = {
        "ant", "halfcheetah", "hopper", "walker2d", "humanoid", "humanoidstandup", "reacher",
        "swimmer", "pusher", "inverted_pendulum", "inverted_double_pendulum",
    }  # fmt: skip
    assert expected <= set(envs.names())
    with pytest.raises(ValueError, match="unknown environment 'antt'.*ant"):
        envs.make("antt")
    with pytest.raises(ValueError, match="unknown reward term 'speed'"):
        envs.make("halfcheetah", reward_weights={"speed": 1.0})


def test_auto_reset_starts_fresh_random_episodes(pendulum):
    env = pendulum
    n = 64
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
    step = jax.jit(jax.vmap(env.step))
    starts, lengths = [np.asarray(state.data.qpos)], []
    for _ in range(15):
        prev = state
        state = step(state, jnp.zeros((n, 1)))
        done = np.asarray(state.done)
        # Truncation at the time limit is separate from termination, and counters restart.
        length = np.asarray(prev.episode_length) * ~np.asarray(prev.done) + 1
        assert np.all(np.asarray(state.truncated) == (length >= 7))
        lengths += list(np.asarray(state.episode_length)[done])
        starts.append(np.asarray(state.data.qpos)[done])
        # The final observation of a finished episode is kept for bootstrapping.
        not_done = ~done
        np.testing.assert_array_equal(np.asarray(state.final_obs)[not_done], np.asarray(state.obs)[not_done])
        if done.any():
            assert not np.array_equal(np.asarray(state.final_obs)[done], np.asarray(state.obs)[done])
    starts = np.concatenate(starts)
    # Every reset is a new draw, not a replay of the first one.
    assert len(np.unique(starts.round(7), axis=0)) == len(starts)
    assert set(lengths) <= set(range(1, 8)) and 7 in lengths


@pytest.mark.parametrize("name", ["ant", "humanoid"])
def test_a_step_reads_its_data_only_through_what_an_auto_reset_carries(name):
    """An auto-reset takes only some Data fields from the new episode (``Env.carried_fields``);
    a step from a state whose other fields are NaN gives the same result to the bit."""
    env = envs.make(name, episode_length=2)
    carried = env.carried_fields
    assert {"qpos", "qvel", "xpos"} <= set(carried) and "qM" not in carried
    state = env.reset(jax.random.PRNGKey(3))
    stale = {f: jnp.full_like(getattr(state.data, f), jnp.nan) for f in state.data.__dataclass_fields__
             if f not in carried and jnp.issubdtype(getattr(state.data, f).dtype, jnp.floating)}  # fmt: skip
    assert "qM" in stale and "cvel" in stale
    action = jnp.full((env.action_size,), 0.3)
    step = jax.jit(env.step)
    for _ in range(2):  # the second step ends the episode: the reset state comes back
        a, b = step(state, action), step(state.replace(data=state.data.replace(**stale)), action)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(x, y)
        state = a
    assert bool(state.done)


def _fields_read(fn, data) -> set[str]:
    """The fields of ``data`` (abstract ``Data``) that ``fn(data)`` reads, from its traced program:
    a field counts as read if any operation or output takes it."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(data)
    jaxpr = jax.make_jaxpr(lambda *leaves: fn(jax.tree.unflatten(treedef, leaves)))(
        *(x for _, x in paths)
    ).jaxpr
    used = {id(v) for eqn in jaxpr.eqns for v in eqn.invars} | {id(v) for v in jaxpr.outvars}
    return {path[0].name for (path, _), var in zip(paths, jaxpr.invars, strict=True) if id(var) in used}


@pytest.mark.parametrize("name", envs.names())
def test_what_a_reward_reads_of_the_step_start_is_carried_at_reset(name):
    """Each task declares the ``Data`` fields its reward reads of the state a step starts from
    (``Env.carried_at_reset``, beyond the state and kinematics an auto-reset always carries); its
    traced reward reads no other. A field missed here would reach the next episode's first
    reward stale from the last one."""
    env = envs.make(name)
    model, key = env.model, jax.random.PRNGKey(0)

    def start():
        data = env._reset_data(key, model)
        return data, env._sample_task(key, model, data)

    data, task = jax.eval_shape(start)
    action = jnp.zeros(model.nu, data.qpos.dtype)

    def reward(before):  # what it reads of ``after``, the step computes itself
        after, zero_task = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), (data, task))
        return env._reward_task(model, before, after, action, zero_task, key)

    assert _fields_read(lambda d: jnp.sum(d.qM) + jnp.sum(d.cvel), data) == {"qM", "cvel"}  # it sees reads
    undeclared = _fields_read(reward, data) - set(env.carried_fields)
    assert not undeclared, f"{name}'s reward reads {sorted(undeclared)} of the step's start"


def test_reset_noise_has_the_configured_distribution():
    env = envs.make("halfcheetah")
    n = 10_000
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), n))
    dq = np.asarray(state.data.qpos - env.model.qpos0)
    dv = np.asarray(state.data.qvel)
    s = env.reset_noise_scale  # qpos ~ U(-s, s), qvel ~ s N(0, 1), as in HalfCheetah-v5
    np.testing.assert_allclose(dq.mean(0), 0.0, atol=4 * s / np.sqrt(3 * n))
    np.testing.assert_allclose(dq.std(0), s / np.sqrt(3), rtol=0.03)
    assert dq.min() >= -s and dq.max() <= s
    np.testing.assert_allclose(dv.mean(0), 0.0, atol=4 * s / np.sqrt(n))
    np.testing.assert_allclose(dv.std(0), s, rtol=0.03)
    assert len(np.unique(dq, axis=0)) == n  # 10k distinct initial states


def test_domain_randomisation_is_per_env_and_traced():
    env = envs.make("inverted_pendulum", randomization={"mass": 0.2, "damping": 0.5})
    reset = jax.jit(jax.vmap(env.reset))
    state = reset(jax.random.split(jax.random.PRNGKey(2), 256))
    scale = np.asarray(state.params["mass_scale"])
    assert scale.shape == (256, env.model.nbody)
    assert 0.8 <= scale.min() and scale.max() <= 1.2 and scale.std() > 0.05
    step = jax.jit(jax.vmap(env.step))
    out = step(state, jnp.ones((256, 1)))
    # Heavier carts accelerate less under the same force: the parameters reach the physics.
    v = np.asarray(out.data.qvel[:, 0] - state.data.qvel[:, 0])
    cart = scale[:, 1] if env.model.body_names[1] else scale[:, 1]
    assert np.corrcoef(cart, v)[0, 1] < -0.5
    # New parameters come without recompiling.
    state2 = reset(jax.random.split(jax.random.PRNGKey(3), 256))
    step(state2, jnp.ones((256, 1)))
    assert step._cache_size() == 1
    with pytest.raises(ValueError, match="half-width"):
        envs.make("inverted_pendulum", randomization={"mass": 1.5})


def test_gym_env_passes_gymnasium_checker():
    check_env(envs.make_gym("inverted_pendulum"), skip_render_check=True)


def test_vector_env_same_step_autoreset_and_async(pendulum):
    venv = envs.VectorEnv(pendulum, num_envs=6, seed=0)
    assert isinstance(venv, gymnasium.vector.VectorEnv)
    assert venv.single_observation_space.shape == (4,)
    assert venv.action_space.shape == (6, 1)
    obs, _ = venv.reset(seed=5)
    obs2, _ = envs.VectorEnv(pendulum, num_envs=6).reset(seed=5)
    np.testing.assert_array_equal(obs, obs2)  # seeded resets are reproducible
    assert obs.dtype == np.float64 and venv.observation_space.contains(obs)
    seen_final = False
    for _ in range(9):
        obs, rew, term, trunc, info = venv.step(venv.action_space.sample())
        assert obs.shape == (6, 4) and rew.shape == term.shape == trunc.shape == (6,)
        if (term | trunc).any():
            seen_final = True
            done = term | trunc
            assert np.all(info["_final_obs"] == done)
            assert all(info["final_obs"][i].shape == (4,) for i in np.flatnonzero(done))
            assert np.all(info["episode"]["l"][done] >= 1)
    assert seen_final
    # send/recv on a subset leaves the other envs untouched.
    before = np.asarray(venv._state.data.qpos).copy()
    venv.send(np.zeros((2, 1), np.float32), env_ids=[1, 4])
    obs, *_rest, info = venv.recv()
    after = np.asarray(venv._state.data.qpos)
    assert obs.shape == (2, 4) and list(info["env_id"]) == [1, 4]
    np.testing.assert_array_equal(after[[0, 2, 3, 5]], before[[0, 2, 3, 5]])
    with pytest.raises(ValueError, match="actions have shape"):
        venv.step(np.zeros((5, 1)))


def test_ant_can_leave_contact_forces_out_of_its_observation():
    """Gymnasium v5's ``include_cfrc_ext_in_observation`` keyword, also reachable from config."""
    from fastrl.training.config import EnvConfig

    full = envs.make("ant")
    short = EnvConfig(name="ant", options={"include_cfrc_ext_in_observation": False}).make()
    gym_short = gymnasium.make("Ant-v5", include_cfrc_ext_in_observation=False)
    assert (full.observation_size, short.observation_size) == (105, 27)
    assert gym_short.observation_space.shape == (short.observation_size,)
    state = full.reset(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(short._observe(full.model, state.data), state.obs[:27])
    assert envs.make("ant_goal", include_cfrc_ext_in_observation=False).observation_size == 31


def test_dropped_contacts_are_an_env_metric():
    """An env whose scene can drop contacts (here the Ant with one contact slot) reports how many
    it dropped as the ``contact_overflow`` metric; a scene with no contacts has no such metric."""
    assert "contact_overflow" not in envs.make("inverted_pendulum").metric_names()
    ant = envs.make("ant", nconmax=1)
    assert ant.metric_names()[-1] == "contact_overflow"

    def fall(state, _):  # the Ant dropped from its start height lands on several feet
        state = ant.step(state, jnp.zeros(ant.action_size))
        return state, state.metrics["contact_overflow"]

    _, dropped = jax.lax.scan(fall, ant.reset(jax.random.PRNGKey(0)), None, length=30)
    assert dropped[0] == 0 and dropped.max() >= 1


_SPLIT_SCRIPT = """
import json, numpy as np, jax
from fastrl import envs
v = envs.make_vec("inverted_pendulum", num_envs=4, seed=0)
v.reset(seed=3)
rng = np.random.default_rng(0)
out = []
for _ in range(30):
    obs, reward, term, trunc, info = v.step(rng.uniform(-3, 3, (4, 1)).astype(np.float32))
    out.append([obs.tolist(), reward.tolist(), term.tolist()])
print(json.dumps({"devices": jax.device_count(), "sharding": str(v._state.obs.sharding), "out": out}))
"""


def test_vector_env_splits_over_two_cpu_devices_with_the_same_results():
    """With 2 devices each steps half the envs; observations, rewards and resets are unchanged."""
    import json
    import os
    import pathlib
    import subprocess
    import sys

    root = pathlib.Path(__file__).resolve().parents[2]
    runs = {}
    for n in (1, 2):
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}")
        proc = subprocess.run([sys.executable, "-c", _SPLIT_SCRIPT], env=env, cwd=root, check=True,
                              capture_output=True, text=True, timeout=300)  # fmt: skip
        runs[n] = json.loads(proc.stdout.strip().splitlines()[-1])
    assert runs[2]["devices"] == 2 and "devices" in runs[2]["sharding"]
    assert any(step[2] != [False] * 4 for step in runs[1]["out"])  # episodes ended and reset
    for a, b in zip(runs[1]["out"], runs[2]["out"], strict=True):
        np.testing.assert_allclose(np.array(a[0]), np.array(b[0]), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(a[1], b[1], rtol=1e-6)
        assert a[2] == b[2]


def test_the_step_is_the_task_step_under_its_wrappers_and_they_compose():
    """``env.step`` equals ``task_step`` under the guard, the episode count and the auto-reset;
    a loop that leaves the count out has no time limit, and one without the guard lets a
    NaN reach the observation."""
    env = envs.make("inverted_pendulum", episode_length=3)
    state = env.reset(jax.random.PRNGKey(0))
    composed = wrappers.auto_reset(
        wrappers.count_episodes(wrappers.guard_divergence(env.task_step, True), 3),
        env.reset,
        env.carried_fields,
    )
    no_limit = jax.jit(wrappers.auto_reset(env.task_step, env.reset, env.carried_fields))
    a, b, c = state, state, state
    for _ in range(4):
        a, b, c = (
            env.step(a, jnp.ones(1) * 0.1),
            composed(b, jnp.ones(1) * 0.1),
            no_limit(c, jnp.ones(1) * 0.1),
        )
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(x, y)
        assert not bool(c.truncated)
    assert int(a.episode_length) == 1  # the third step truncated, the fourth began a new episode
    nan = jnp.full(1, jnp.nan)
    assert bool(jnp.isnan(no_limit(state, nan).final_obs).any())
    guarded = env.step(state, nan)
    assert bool(guarded.terminated) and not bool(jnp.isnan(guarded.final_obs).any())
    assert float(guarded.metrics["diverged"]) == 1.0
