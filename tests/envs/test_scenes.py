"""fastrl's own scenes: API, goals in State.task, auto-reset, determinism, MuJoCo agreement."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import envs
from fastrl.envs.base import ASSETS


@pytest.fixture(scope="module")
def arm():
    env = envs.make("arm_reach")
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def test_arm_reach_targets_lie_all_around_the_arm(arm):
    env, reset, _ = arm
    assert (env.observation_size, env.action_size) == (27, 6)
    target = np.asarray(reset(jax.random.split(jax.random.PRNGKey(0), 512)).task["target"])
    radius = np.hypot(target[:, 0], target[:, 1])
    assert radius.min() >= 0.25 and radius.max() <= 0.6
    assert target[:, 2].min() >= 0.1 and target[:, 2].max() <= 0.6
    quadrants = np.histogram(np.arctan2(target[:, 1], target[:, 0]), bins=4, range=(-np.pi, np.pi))[0]
    assert quadrants.min() > 512 / 4 * 0.7  # full 360 degrees, roughly uniform


def test_arm_reach_auto_resets_to_a_new_target_and_is_deterministic(arm):
    env, reset, step = arm
    keys = jax.random.split(jax.random.PRNGKey(1), 4)
    runs = []
    for _ in range(2):
        s = reset(keys)
        first = np.asarray(s.task["target"])
        action = jnp.tile(jnp.array([0.5, -0.4, 0.9, 0.2, 0.0, 0.0]), (4, 1))
        for _ in range(env.episode_length):
            s = step(s, action)
        assert bool(s.truncated.all())
        assert not np.allclose(np.asarray(s.task["target"]), first)  # a fresh goal, not a replay
        runs.append(np.asarray(s.data.qpos))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_arm_reach_success_and_reward_terms(arm):
    env, reset, _ = arm
    s = jax.tree.map(lambda x: x[0], reset(jax.random.split(jax.random.PRNGKey(2), 1)))
    hold = s.data.qpos  # servo targets at the current pose: the flange barely moves
    on_target = s.replace(task={"target": s.data.site_xpos[0]})
    nxt = jax.jit(env.step)(on_target, hold)
    assert float(nxt.metrics["success"]) == 1.0
    assert float(nxt.metrics["reward_bonus"]) == pytest.approx(0.5)
    far = jax.jit(env.step)(s.replace(task={"target": jnp.array([0.6, 0.0, 0.1])}), hold)
    assert float(far.metrics["success"]) == 0.0
    assert float(far.metrics["reward_dist"]) == pytest.approx(-float(far.metrics["distance"]))


def test_arm_reach_tracks_mujoco_under_random_servo_targets(arm):
    env, _, _ = arm
    mj = mujoco.MjModel.from_xml_path(str(ASSETS / env.asset))
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(0)
    md.qpos[:] = rng.uniform(-0.1, 0.1, mj.nq)
    state = jax.jit(env.reset_to)(jnp.array(md.qpos.copy()), jnp.array(md.qvel.copy()))
    step = jax.jit(env.step)
    low, high = env.action_bounds
    for t in range(20):
        action = rng.uniform(low, high).astype(np.float32)
        md.ctrl[:] = action
        mujoco.mj_step(mj, md, nstep=env.frame_skip)
        state = step(state, jnp.asarray(action))
        err = f"step {t}"
        np.testing.assert_allclose(state.data.qpos, md.qpos, rtol=1e-4, atol=2e-4, err_msg=err)
        np.testing.assert_allclose(state.data.qvel, md.qvel, rtol=1e-3, atol=2e-3, err_msg=err)
        # the flange the reward reads is MuJoCo's site, after mj_step
        np.testing.assert_allclose(state.data.site_xpos[0], md.site_xpos[0], atol=2e-4, err_msg=err)


def test_ant_goal_targets_body_frame_and_new_target_on_reach():
    env = envs.make("ant_goal", integrator="euler", solver_iterations=5)
    ant = envs.make("ant", integrator="euler", solver_iterations=5)
    assert env.observation_size == ant.observation_size + 4
    starts = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 256))
    offset = np.asarray(starts.task["target"] - starts.data.xpos[:, 1, :2])
    assert np.hypot(*offset.T).min() >= 2.0 and np.hypot(*offset.T).max() <= 4.0
    assert np.histogram(np.arctan2(offset[:, 1], offset[:, 0]), bins=4, range=(-np.pi, np.pi))[0].min() > 40

    # The target in the torso's frame: yawing the Ant by 90 degrees rotates it by -90 degrees.
    qpos = np.asarray(ant.model.qpos0).copy()
    qpos[3:7] = [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]
    s = jax.jit(env.reset_to)(jnp.asarray(qpos), jnp.zeros(env.model.nv))
    s = s.replace(task={"target": s.data.xpos[1, :2] + jnp.array([3.0, 0.0]), "reached": jnp.zeros(())})
    obs = jax.jit(lambda s: env._observe_task(env.model, s.data, s.task))(s)
    np.testing.assert_allclose(obs[-4:], [0.0, -3.0, 0.0, 3.0], atol=1e-5)
    np.testing.assert_allclose(
        obs[:-4], ant.reset_to(jnp.asarray(qpos), jnp.zeros(env.model.nv)).obs, atol=1e-6
    )

    # A target within reach is collected, counted and replaced by one 2-4 m from the torso.
    s = s.replace(task={"target": s.data.xpos[1, :2] + jnp.array([0.1, 0.0]), "reached": jnp.zeros(())})
    nxt = jax.jit(env.step)(s, jnp.zeros(env.action_size))
    assert float(nxt.metrics["success"]) == 1.0 and float(nxt.task["reached"]) == 1.0
    assert float(nxt.metrics["reward_reach"]) == pytest.approx(10.0)
    assert 2.0 - 0.5 <= float(jnp.linalg.norm(nxt.task["target"] - nxt.data.xpos[1, :2])) <= 4.0 + 0.5
