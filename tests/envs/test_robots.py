"""The real-robot tasks (fastrl/envs/robots.py): API, auto-reset, determinism, MuJoCo C agreement.

One env per module, each program compiled once (module-scoped fixtures): the Go1 scene's step
takes ~30 s to compile on one core.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import envs

NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0}


@pytest.fixture(scope="module")
def go1():
    env = envs.make("go1_joystick", episode_length=30)
    reset = jax.jit(jax.vmap(env.reset))
    step = jax.jit(jax.vmap(env.step))
    return env, reset, step


def _run(reset, step, seed, n, actions):
    state = reset(jax.random.split(jax.random.PRNGKey(seed), n))
    out = []
    for a in actions:
        state = step(state, a)
        out.append(state)
    return out


def test_go1_joystick_api_and_rewards(go1):
    env, reset, step = go1
    assert (env.observation_size, env.action_size, env.dt) == (48, 12, pytest.approx(0.02))
    rng = np.random.default_rng(0)
    actions = jnp.asarray(rng.uniform(-1, 1, (40, 8, 12)), jnp.float32)
    states = _run(reset, step, 0, 8, actions)
    last = states[-1]
    assert last.obs.shape == (8, 48) and np.isfinite(np.asarray(last.obs)).all()
    terms = [k for k in last.metrics if k.startswith("reward_")]
    assert {"reward_tracking_lin_vel", "reward_feet_air_time", "reward_floor"} <= set(terms)
    for s in states:  # the named terms sum to the reward, which Playground's clip keeps >= 0
        total = sum(np.asarray(s.metrics[k]) for k in terms)
        np.testing.assert_allclose(total, np.asarray(s.reward), atol=1e-6)
        assert (np.asarray(s.reward) >= 0).all()
    # commands lie within the limits; randomised parameters differ between envs
    cmd = np.asarray(last.task["command"])
    assert (np.abs(cmd) <= np.asarray(env.command_limits) + 1e-6).all()
    assert np.ptp(np.asarray(last.params["gain_scale"]), axis=0).min() > 0
    # the viewer's marker: half a second along the command, above the trunk
    mark = np.asarray(jax.vmap(env.markers)(last.task))
    assert mark.shape == (8, 1, 3) and (mark[:, 0, 2] > np.asarray(last.data.qpos)[:, 2]).all()


def test_go1_joystick_actions_are_offsets_from_standing_in_unit_bounds(go1):
    """A learner squashes its actions into ``action_bounds``: they must be [-1, 1] (offsets of
    ``action_scale`` from the standing pose), so that its untrained, zero-mean policy targets the
    standing pose, not the middle of each joint's range (the ctrlrange)."""
    from fastrl.agents.networks import TanhGaussian

    env = go1[0]
    low, high = env.action_bounds
    np.testing.assert_array_equal(low, -1.0)
    np.testing.assert_array_equal(high, 1.0)
    dist = TanhGaussian(jnp.asarray(low), jnp.asarray(high))
    neutral = dist.postprocess(dist.mode_raw(jnp.zeros(2 * env.action_size)))
    np.testing.assert_allclose(env._control(neutral, None), env._stand, atol=1e-6)
    extreme = env._control(jnp.ones(env.action_size), None) - env._stand
    np.testing.assert_allclose(extreme, env.action_scale, rtol=1e-6)


def test_go1_joystick_auto_resets_to_fresh_commands_and_is_deterministic(go1):
    env, reset, step = go1
    zeros = jnp.zeros((30, 4, 12))
    a, b = _run(reset, step, 3, 4, zeros), _run(reset, step, 3, 4, zeros)
    for s, t in zip(a, b, strict=True):  # same keys, same episode, bit for bit
        jax.tree.map(np.testing.assert_array_equal, s, t)
    before, end = a[-2], a[-1]  # the 30-step episode ends at the 30th step
    assert not np.asarray(before.done).any() and np.asarray(end.truncated).all()
    assert not np.allclose(np.asarray(end.task["command"]), np.asarray(before.task["command"]))
    np.testing.assert_array_equal(np.asarray(end.task["last_action"]), 0.0)
    assert (np.asarray(end.episode_length) == 30).all()
    start = reset(jax.random.split(jax.random.PRNGKey(3), 4))
    assert not np.allclose(np.asarray(end.data.qpos), np.asarray(start.data.qpos))  # a new draw


def test_go1_joystick_steps_as_mujoco_c_and_observes_its_sensors(x64):
    """20 control steps of random actions from a reset state: fastrl's qpos and observation
    (noise off, nominal parameters) against MuJoCo C stepping the same scene with the same
    servo targets, the observation read from MuJoCo's own IMU sensors."""
    env = envs.make("go1_joystick", randomization=NOMINAL, observation_noise=0.0)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(5))
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    rng = np.random.default_rng(1)
    for _ in range(20):
        action = rng.uniform(-1, 1, 12)
        state = step(state, jnp.asarray(action))
        md.ctrl[:] = np.asarray(env._control(jnp.asarray(action), state.task))
        for _ in range(env.frame_skip):
            mujoco.mj_step(mj, md)
        np.testing.assert_allclose(np.asarray(state.data.qpos), md.qpos, atol=1e-9)
        np.testing.assert_allclose(
            np.asarray(state.obs), env.observation_from_mujoco(md, state.task), atol=1e-9
        )
    assert not bool(state.done)
