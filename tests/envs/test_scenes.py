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
    step = jax.jit(env.step)
    nxt = step(s, jnp.zeros(env.action_size))
    assert float(nxt.metrics["success"]) == 1.0 and float(nxt.task["reached"]) == 1.0
    assert float(nxt.metrics["reward_reach"]) == pytest.approx(10.0)
    assert 2.0 - 0.5 <= float(jnp.linalg.norm(nxt.task["target"] - nxt.data.xpos[1, :2])) <= 4.0 + 0.5

    # Deterministic, and an unhealthy Ant (torso above the healthy range) auto-resets to a fresh
    # episode with a fresh target around its new start.
    np.testing.assert_array_equal(step(s, jnp.zeros(env.action_size)).data.qpos, nxt.data.qpos)
    flying = s.replace(data=s.data.replace(qpos=s.data.qpos.at[2].set(1.5)))
    new = step(flying, jnp.zeros(env.action_size))
    assert bool(new.terminated) and int(new.episode_length) == 1
    assert float(new.data.qpos[2]) < 1.0  # a fresh start pose, not the flying one
    assert not np.allclose(np.asarray(new.task["target"]), np.asarray(s.task["target"]))


# ------------------------------------------------------------------ arm_push


def _mujoco(env):
    mj = mujoco.MjModel.from_xml_path(str(ASSETS / env.asset))
    return mj, mujoco.MjData(mj)


def test_arm_push_block_and_goal_placement_and_auto_reset():
    env = envs.make("arm_push")
    assert (env.observation_size, env.action_size) == (38, 6)
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    s = reset(jax.random.split(jax.random.PRNGKey(0), 512))
    block = np.asarray(s.data.qpos[:, 6:9])
    radius, angle = np.hypot(block[:, 0], block[:, 1]), np.arctan2(block[:, 1], block[:, 0])
    assert radius.min() >= 0.35 and radius.max() <= 0.55 and np.abs(angle).max() <= np.pi / 4
    np.testing.assert_allclose(block[:, 2], 0.05)  # resting on the table
    goal = np.asarray(s.task["target"])
    assert np.hypot(*goal.T).min() >= 0.3 - 1e-6 and np.hypot(*goal.T).max() <= 0.7 + 1e-6
    offset = np.hypot(*(goal - block[:, :2]).T)
    assert offset.max() <= 0.25 + 1e-6 and np.median(offset) > 0.1
    assert s.metrics["success"].shape == (512,)

    keys = jax.random.split(jax.random.PRNGKey(1), 4)
    runs = []
    for _ in range(2):
        s = reset(keys)
        first = np.asarray(s.task["target"])
        for _ in range(env.episode_length):
            s = step(s, jnp.zeros((4, 6)))
        assert bool(s.truncated.all())
        assert not np.allclose(np.asarray(s.task["target"]), first)
        runs.append(np.asarray(s.data.qpos))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_arm_push_tool_sweeps_the_block_like_mujoco():
    """The tool swung into the block at table height: block and arm follow MuJoCo C."""
    env = envs.make("arm_push")
    mj, md = _mujoco(env)
    arm = np.array([0.0, 0.578, 2.271, 0.231, 0.0, 0.0])  # tool 4.4 cm above the table, 0.44 m out
    md.qpos[:6] = arm
    mujoco.mj_kinematics(mj, md)
    tool = md.site_xpos[1].copy()
    angle = np.arctan2(tool[1], tool[0]) - 0.10 / np.hypot(tool[0], tool[1])  # 2 cm clear of the tool
    md.qpos[6:9] = [0.44 * np.cos(angle), 0.44 * np.sin(angle), 0.05]
    state = jax.jit(env.reset_to)(jnp.asarray(md.qpos.copy()), jnp.zeros(mj.nv))
    step = jax.jit(env.step)
    action = arm.copy()
    action[0] = -0.8  # pan towards the block: the tool sweeps into it
    start = md.qpos[6:8].copy()
    for t in range(25):
        md.ctrl[:] = action
        mujoco.mj_step(mj, md, nstep=env.frame_skip)
        state = step(state, jnp.asarray(action, jnp.float32))
        err = f"step {t}"
        np.testing.assert_allclose(state.data.qpos[:6], md.qpos[:6], atol=2e-3, err_msg=err)
        np.testing.assert_allclose(state.data.qpos[6:9], md.qpos[6:9], atol=5e-3, err_msg=err)
    assert np.linalg.norm(md.qpos[6:8] - start) > 0.05  # MuJoCo's block was really pushed


# ------------------------------------------------------------------ hand_reorient


@pytest.fixture(scope="module")
def hand():
    env = envs.make("hand_reorient")
    return env, jax.jit(env.step)  # one compiled step shared by the hand's tests


def test_hand_reorient_targets_drop_and_success(hand):
    env, step = hand
    assert (env.observation_size, env.action_size) == (45, 12)
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 512))
    err = np.asarray(jax.vmap(env._error)(s.data, s.task))
    assert err.max() <= np.pi + 1e-5 and np.histogram(err, bins=4, range=(0, np.pi))[0].min() > 60
    target = np.asarray(s.task["target"])
    np.testing.assert_allclose(target[:, 1:3], 0.0, atol=1e-6)  # level faces: a turn about z

    one = jax.tree.map(lambda x: x[0], s)
    hold = one.data.qpos[:12]
    done = step(one.replace(task={"target": one.data.qpos[15:19]}), hold)
    assert float(done.metrics["success"]) == 1.0 and not bool(done.terminated)
    assert float(done.metrics["reward_bonus"]) == pytest.approx(0.5)
    # lifted off the palm's square: dropped, terminated, penalised
    qpos = one.data.qpos.at[12].set(0.09)
    before = env.reset_to(qpos, jnp.zeros(env.model.nv), key=jax.random.PRNGKey(5))
    dropped = step(before, hold)
    assert bool(dropped.terminated) and float(dropped.metrics["reward_drop"]) == -20.0
    # auto-reset: a fresh episode, the cube back on the palm with a new target
    assert float(dropped.data.qpos[14]) == pytest.approx(env.rest_height)
    assert not np.allclose(np.asarray(dropped.task["target"]), np.asarray(before.task["target"]))

    # deterministic: the same start and actions give the same states
    actions = jax.random.uniform(jax.random.PRNGKey(3), (10, 12), minval=-0.4, maxval=0.6)
    runs = []
    for _ in range(2):
        b = jax.tree.map(lambda x: x[1], s)
        for a in actions:
            b = step(b, a)
        runs.append(np.asarray(b.data.qpos))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_hand_cube_rests_and_follows_mujoco_under_random_finger_targets(hand):
    """The cube settles on the palm at MuJoCo's height; then the fingers strike and turn it.

    The contacts are MuJoCo's except one case: a finger lying along a cube face and past its
    edge gets a second contact at the clipped end in MuJoCo (``capsule_box``'s note), so
    trajectories part after such a touch; the cube stays within the contact issue's bound.
    """
    env, step = hand
    mj, md = _mujoco(env)
    low, high = env.action_bounds
    rng = np.random.default_rng(0)
    cube_err = []
    for seq in range(6):
        mujoco.mj_resetData(mj, md)
        md.qpos[:12] = rng.uniform(-0.05, 0.05, 12)
        md.qpos[15:19] = [np.cos(0.3 * seq), 0, 0, np.sin(0.3 * seq)]
        state = env.reset_to(jnp.asarray(md.qpos.copy()), jnp.zeros(mj.nv))
        hold = md.qpos[:12].astype(np.float32)
        for _ in range(30):  # the cube settles on the palm, fingers held
            md.ctrl[:] = hold
            mujoco.mj_step(mj, md, nstep=env.frame_skip)
            state = step(state, jnp.asarray(hold))
        assert abs(float(state.data.qpos[14]) - md.qpos[14]) < 1e-3  # rest height within 1 mm
        for _ in range(20):  # fingers driven to random targets: they strike and turn the cube
            action = rng.uniform(low, high).astype(np.float32)
            md.ctrl[:] = action
            mujoco.mj_step(mj, md, nstep=env.frame_skip)
            state = step(state, jnp.asarray(action))
            if bool(state.done):
                break
        cube = np.asarray(state.final_obs[24:27]) + [0, 0, env.rest_height]
        cube_err.append(np.linalg.norm(cube - md.qpos[12:15]))
    assert np.median(cube_err) < 0.02  # the contact issue's bound: 2 cm
    assert max(cube_err) < 0.03


def test_hand_reorient_faces_targets_put_every_face_up():
    from fastrl.envs.scenes import _CUBE_ROTATIONS

    assert len({tuple(np.round(q, 6)) for q in _CUBE_ROTATIONS}) == 24
    env = envs.make("hand_reorient", target="faces")
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 600))
    from fastrl.physics.math import quat_conj, quat_rotate

    # the cube-frame axis that points up in the target: each of the six faces, about equally often
    up = np.asarray(
        jax.vmap(lambda q: quat_rotate(quat_conj(q), jnp.array([0.0, 0.0, 1.0])))(s.task["target"])
    )
    faces = np.argmax(np.abs(up), axis=1) * 2 + (up[np.arange(600), np.argmax(np.abs(up), axis=1)] < 0)
    counts = np.bincount(faces, minlength=6)
    assert counts.min() > 600 / 6 * 0.6
