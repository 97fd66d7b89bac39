"""The real-robot tasks (fastrl/envs/robots/): API, auto-reset, determinism, MuJoCo C agreement.

Each env's batched reset and step compile once for the module (module-scoped fixtures): a robot
scene's step takes ~20-30 s to compile on one core.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import agents, envs

NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0}


def _batched(name, **overrides):
    """The env and its jitted batched reset and step."""
    env = envs.make(name, **overrides)
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


@pytest.fixture(scope="module", params=["go1_joystick", "go1_joystick_rough"])
def go1(request):
    return _batched(request.param, episode_length=30)


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


def test_go1_joystick_privileged_critic_state_follows_the_policys_observation(go1):
    """``privileged_critic=True`` appends Playground's privileged state after the policy's 48
    entries, which stay as they were: the noise-free sensors, the actuator forces, the trunk's
    angular velocity and each foot's contact, velocity and air time."""
    env, reset, step = go1
    priv = envs.make(env.name, privileged_critic=True)
    assert (priv.policy_observation_size, priv.observation_size) == (48, 48 + 33 + 12 + 3 + 4 + 12 + 4)
    state = _run(reset, step, 2, 4, jnp.zeros((6, 4, 12)))[-1]
    obs = np.asarray(
        jax.jit(jax.vmap(priv._observe_task, in_axes=(None, 0, 0)))(priv.model, state.data, state.task)
    )
    np.testing.assert_array_equal(obs[:, :48], np.asarray(state.obs))
    np.testing.assert_allclose(obs[:, 48:81], np.asarray(state.obs[:, :33] - state.task["noise"]), atol=1e-5)
    np.testing.assert_array_equal(obs[:, 81:93], np.asarray(state.data.actuator_force))
    np.testing.assert_array_equal(obs[:, 96:100], np.asarray(state.task["last_contact"], np.float32))
    np.testing.assert_array_equal(obs[:, -4:], np.asarray(state.task["air_time"]))
    assert np.asarray(state.task["last_contact"]).any()  # standing: some feet touch


def test_a_held_command_survives_resets_and_due_redraws():
    """``command=`` holds one command at every reset and through the task's redraws (which go
    on without it); the motion metrics report what the tracking terms score."""
    held, free = (envs.make("go1_joystick", command=c) for c in ((0.5, 0.0, -0.25), None))
    keys = jax.random.split(jax.random.PRNGKey(1), 3)

    @jax.jit
    def redraw_due(keys):  # a reset, then the task's update on a step where a redraw is due
        def one(env):
            def per(key):
                state = env.reset(key)
                task = dict(state.task, resample_in=jnp.ones((), jnp.int32))
                action = jnp.zeros(env.action_size)
                d = state.data
                _, _, extra, nxt = env._reward_task(env.model, d, d, action, task, jax.random.fold_in(key, 5))
                return state.task["command"], nxt["command"], extra

            return jax.vmap(per)(keys)

        return one(held), one(free)

    (h0, h1, extra), (f0, f1, _) = redraw_due(keys)
    np.testing.assert_allclose(np.asarray(h0), [[0.5, 0.0, -0.25]] * 3, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(h1), np.asarray(h0))
    assert np.ptp(np.asarray(f0), axis=0).min() > 0  # without it: drawn per reset
    assert not np.allclose(np.asarray(f1), np.asarray(f0))  # and redrawn when due
    assert {"forward_velocity", "sideways_velocity", "yaw_rate"} <= set(extra)
    with pytest.raises(ValueError, match="three finite numbers"):
        envs.make("go1_joystick", command=(1.0, 0.0))


@pytest.mark.parametrize("name", ["go1_joystick", "go1_joystick_rough"])
def test_go1_joystick_steps_as_mujoco_c_and_observes_its_sensors(x64, name):
    """20 control steps of random actions from a reset state: fastrl's qpos and observation
    (noise off, nominal parameters) against MuJoCo C stepping the same scene with the same
    servo targets, the observation read from MuJoCo's own IMU sensors, and each foot's contact
    from the scene's own foot-floor contact sensors (Playground's), on the plane and on the
    height field."""
    env = envs.make(name, randomization=NOMINAL, observation_noise=0.0)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(5))
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    atol = obs_atol = 1e-9
    if name == "go1_joystick_rough":
        # MuJoCo C meets the height field's prisms by GJK/EPA, which stops within its
        # ccd_tolerance (1e-6) of the contact fastrl computes exactly: the runs part by 1e-5 at
        # the first such contact and 3e-2 by the 20th step. Converged, they agree to ~1e-7 in
        # qpos (and velocities to ~1e-5).
        mj.opt.ccd_tolerance, mj.opt.ccd_iterations = 1e-13, 1000
        atol, obs_atol = 1e-6, 1e-4
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    rng = np.random.default_rng(1)
    touched = []
    for _ in range(20):
        action = rng.uniform(-1, 1, 12)
        state = step(state, jnp.asarray(action))
        md.ctrl[:] = np.asarray(env._control(jnp.asarray(action), state.task))
        for _ in range(env.frame_skip):
            mujoco.mj_step(mj, md)
        np.testing.assert_allclose(np.asarray(state.data.qpos), md.qpos, atol=atol)
        np.testing.assert_allclose(
            np.asarray(state.obs), env.observation_from_mujoco(md, state.task), atol=obs_atol
        )
        found = [md.sensor(f"{f}_floor_found").data[0] > 0 for f in env.feet]
        touching = np.asarray(env._feet(state.data)[2])
        np.testing.assert_array_equal(touching, found)
        touched.append(touching)
    assert not bool(state.done)
    assert np.any(touched) and not np.all(touched)  # the feet both touched and lifted


@pytest.fixture(scope="module")
def panda():
    return _batched("panda_pick_cube", episode_length=12)


def test_panda_pick_cube_api_rewards_and_auto_reset(panda):
    env, reset, step = panda
    assert (env.observation_size, env.action_size, env.dt) == (66, 8, pytest.approx(0.02))
    assert env.eval_metrics == ("success",)
    np.testing.assert_array_equal(env.action_bounds[0], -1.0)
    rng = np.random.default_rng(0)
    actions = jnp.asarray(rng.uniform(-1, 1, (12, 6, 8)), jnp.float32)
    states = _run(reset, step, 0, 6, actions)
    terms = [k for k in states[-1].metrics if k.startswith("reward_")]
    assert set(terms) == {f"reward_{k}" for k in env.default_weights}
    for s in states:  # the named terms sum to the reward; every term lies in [0, its scale]
        total = sum(np.asarray(s.metrics[k]) for k in terms)
        np.testing.assert_allclose(total, np.asarray(s.reward), rtol=1e-6)
        for k in terms:
            assert (np.asarray(s.metrics[k]) >= 0).all()
            assert (np.asarray(s.metrics[k]) <= env.default_weights[k[7:]] + 1e-6).all()
    # each step moves a servo target by at most action_scale, within the ctrlrange
    first, second = states[0].task["ctrl"], states[1].task["ctrl"]
    assert np.abs(np.asarray(second - first)).max() <= env.action_scale + 1e-6
    # targets lie 0.2-0.4 m above the cube's start; the viewer marks them
    start = reset(jax.random.split(jax.random.PRNGKey(0), 6))
    target = np.asarray(start.task["target"])
    assert ((target[:, 2] > 0.2) & (target[:, 2] < 0.5)).all()
    np.testing.assert_array_equal(np.asarray(jax.vmap(env.markers)(start.task))[:, 0], target)
    # the 12-step episodes end together; the next episode has fresh targets and servo targets
    before, end = states[-2], states[-1]
    assert not np.asarray(before.done).any() and np.asarray(end.truncated).all()
    assert not np.allclose(np.asarray(end.task["target"]), np.asarray(before.task["target"]))
    np.testing.assert_allclose(np.asarray(end.task["ctrl"]), np.asarray(start.task["ctrl"]))
    np.testing.assert_array_equal(np.asarray(end.task["reached_box"]), 0.0)
    # the same keys and actions give the same run, bit for bit
    again = _run(reset, step, 0, 6, actions)
    jax.tree.map(np.testing.assert_array_equal, states[-1], again[-1])


def test_panda_pick_cube_steps_as_mujoco_c_and_flags_the_floor_as_its_sensors(x64):
    """From a reset state (nominal parameters): 20 control steps of random actions, then the
    hand swung aside and driven into the floor. fastrl's qpos and observation track MuJoCo C
    stepping the scene with the same servo targets, and ``no_floor_collision`` drops exactly
    when one of the scene's own floor contact sensors (Playground's) fires."""
    env = envs.make("panda_pick_cube", randomization={"friction": 0.0, "mass": 0.0, "gain": 0.0})
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(5))
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    floor_sensors = [
        mj.sensor(f"{g}_floor_found").adr[0] for g in ("left_finger_pad", "right_finger_pad", "hand_capsule")
    ]
    rng = np.random.default_rng(1)
    aside, down = np.eye(8)[0], np.array([0, 1, 0, 1, 0, -1, 0, 0.0])
    actions = [rng.uniform(-1, 1, 8) for _ in range(20)] + [aside] * 15 + [down] * 25
    touched = []
    for action in actions:
        ctrl = np.asarray(env._control(jnp.asarray(action), state.task))
        state = step(state, jnp.asarray(action))
        md.ctrl[:] = ctrl
        for _ in range(env.frame_skip):
            mujoco.mj_step(mj, md)
        np.testing.assert_allclose(np.asarray(state.data.qpos), md.qpos, atol=1e-9)
        # the resting cube's velocities are ~1e-9: rounding of its contact forces
        np.testing.assert_allclose(
            np.asarray(state.obs), env.observation_from_mujoco(md, state.task), atol=1e-8
        )
        on_floor = bool(md.sensordata[floor_sensors].any())
        assert float(state.metrics["reward_no_floor_collision"]) == (0.0 if on_floor else 0.25)
        touched.append(on_floor)
    assert not any(touched[:20]) and any(touched[20:])  # the scripted part reaches the floor
    assert not bool(state.done)


@pytest.fixture(scope="module")
def humanoid():
    env, reset, step = _batched("humanoid_joystick", episode_length=12)
    env.push_seconds = (0.1, 0.1)  # a kick every 5 control steps, to see them in a short run
    return env, reset, step


def test_humanoid_joystick_api_pushes_auto_reset_and_determinism(humanoid):
    env, reset, step = humanoid
    assert (env.observation_size, env.action_size, env.dt) == (52, 12, pytest.approx(0.02))
    np.testing.assert_array_equal(env.action_bounds[1], 1.0)
    rng = np.random.default_rng(0)
    actions = jnp.asarray(rng.uniform(-1, 1, (12, 8, 12)), jnp.float32)
    states = _run(reset, step, 0, 8, actions)
    terms = [k for k in states[-1].metrics if k.startswith("reward_")]
    assert set(terms) == {f"reward_{k}" for k in env.default_weights} | {"reward_floor"}
    for s in states:  # the named terms sum to the reward, which Playground's clip keeps >= 0
        total = sum(np.asarray(s.metrics[k]) for k in terms)
        np.testing.assert_allclose(total, np.asarray(s.reward), atol=1e-6)
        assert (np.asarray(s.reward) >= 0).all()
    start = reset(jax.random.split(jax.random.PRNGKey(0), 8))
    cmd = np.asarray(start.task["command"])
    assert (np.abs(cmd) <= env.command_limit).all() and np.ptp(cmd, axis=0).min() > 0
    np.testing.assert_allclose(np.asarray(start.task["phase"]), [[0, np.pi]] * 8, atol=1e-6)
    # the gait clock advances by 2 pi (1.25-1.5 Hz) dt each step
    step_size = np.asarray(states[0].task["phase"] - start.task["phase"])[:, 0]
    lo, hi = 2 * np.pi * np.asarray(env.gait_hz) * env.dt
    assert (step_size >= lo - 1e-6).all() and (step_size <= hi + 1e-6).all()
    # a kick is due before the 5th and 10th steps (every 5), 0.1-2 m/s in the plane, none between
    kicks = np.stack([np.linalg.norm(np.asarray(s.task["push"]), axis=-1) for s in states[:11]])
    due = np.zeros(11, bool)
    due[[3, 8]] = True  # the task after step k holds the kick of step k + 1 (counted from 0)
    assert (kicks[~due] == 0).all() and ((kicks[due] >= 0.1) & (kicks[due] <= 2.0 + 1e-6)).all()
    # the 12-step episodes end together; the next has fresh commands and a restarted clock
    before, end = states[-2], states[-1]
    assert not np.asarray(before.done).any() and np.asarray(end.truncated).all()
    assert not np.allclose(np.asarray(end.task["command"]), np.asarray(before.task["command"]))
    np.testing.assert_allclose(np.asarray(end.task["phase"]), [[0, np.pi]] * 8, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(end.task["last_action"]), 0.0)
    again = _run(reset, step, 0, 8, actions)
    jax.tree.map(np.testing.assert_array_equal, states[-1], again[-1])


def test_humanoid_joystick_steps_as_mujoco_c_with_its_kicks_and_foot_sensors(x64):
    """20 control steps of random actions, with a kick every 5 steps: fastrl's qpos, observation
    (noise off, nominal parameters) and foot contacts against MuJoCo C stepping the same scene
    with the same servo targets and kicks, observed through its own IMU and foot sensors."""
    env = envs.make("humanoid_joystick", randomization=NOMINAL, observation_noise=0.0)
    env.push_seconds = (0.1, 0.1)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(5))
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    feet = [mj.sensor(f"{f}_foot1_floor_found").adr[0] for f in "lr"]
    rng = np.random.default_rng(1)
    kicked, touched = 0, []
    for _ in range(20):
        action = rng.uniform(-1, 1, 12)
        md.qvel[:2] += np.asarray(state.task["push"])
        kicked += bool(np.any(np.asarray(state.task["push"]) != 0))
        md.ctrl[:] = np.asarray(env._control(jnp.asarray(action), state.task))
        state = step(state, jnp.asarray(action))
        for _ in range(env.frame_skip):
            mujoco.mj_step(mj, md)
        np.testing.assert_allclose(np.asarray(state.data.qpos), md.qpos, atol=1e-9)
        np.testing.assert_allclose(
            np.asarray(state.obs), env.observation_from_mujoco(md, state.task), atol=1e-9
        )
        np.testing.assert_array_equal(np.asarray(state.task["last_contact"]), md.sensordata[feet] > 0)
        touched.append(md.sensordata[feet] > 0)
    assert kicked == 4 and np.any(touched) and not bool(state.done)


@pytest.fixture(scope="module")
def leap():
    return _batched("leap_cube_reorient", episode_length=8)


def test_leap_cube_reorient_api_turning_targets_auto_reset_and_determinism(leap):
    env, reset, step = leap
    assert (env.observation_size, env.action_size, env.dt) == (57, 16, pytest.approx(0.05))
    assert env.eval_metrics == ("targets_reached",) and env.mjx_caps
    start = reset(jax.random.split(jax.random.PRNGKey(0), 4))
    # a target the cube will match after the first step (the goal does not change the physics) is
    # reached there: the bonus, a count, and the target starts turning
    cube = step(start, jnp.zeros((4, 16))).data.xquat[:, env._cube]
    matched = start.replace(task={**start.task, "goal": cube})
    actions = jnp.zeros((8, 4, 16))
    states = _run(lambda _: matched, step, 0, 4, actions)
    first = states[0]
    np.testing.assert_array_equal(np.asarray(first.metrics["reward_success"]), 100.0)
    np.testing.assert_array_equal(np.asarray(first.task["targets_reached"]), 1.0)
    spin = np.asarray(first.task["goal_spin"])
    assert ((spin >= 1) & (spin <= 5)).all()  # Playground's 3 + U(-2, 2) per axis
    turned = np.asarray(jax.vmap(env._angle_to_goal)(first.task["goal"], cube))
    np.testing.assert_allclose(turned, np.linalg.norm(spin, axis=-1) * 2 * env.dt, rtol=1e-4)
    np.testing.assert_allclose(np.asarray(states[1].task["goal_spin"]), 0.8 * spin, rtol=1e-6)
    terms = [k for k in first.metrics if k.startswith("reward_")]
    assert set(terms) == {f"reward_{k}" for k in env.default_weights}
    for s in states:  # the named terms sum to the reward
        total = sum(np.asarray(s.metrics[k]) for k in terms)
        np.testing.assert_allclose(total, np.asarray(s.reward), rtol=1e-5)
    # each step moves a servo target by at most action_scale
    rng = np.random.default_rng(0)
    moved = step(start, jnp.asarray(rng.uniform(-1, 1, (4, 16)), jnp.float32))
    assert np.abs(np.asarray(moved.task["ctrl"] - start.task["ctrl"])).max() <= env.action_scale + 1e-6
    # the 8-step episodes end together: fresh targets, counts and servo targets; same keys, same run
    before, end = states[-2], states[-1]
    assert not np.asarray(before.done).any() and np.asarray(end.truncated).all()
    assert not np.allclose(np.asarray(end.task["goal"]), np.asarray(before.task["goal"]))
    np.testing.assert_array_equal(np.asarray(end.task["targets_reached"]), 0.0)
    np.testing.assert_array_equal(np.asarray(end.task["ctrl"]), np.asarray(end.data.qpos)[:, :16])
    assert (np.asarray(end.episode_length) == 8).all()
    again = _run(lambda _: matched, step, 0, 4, actions)
    jax.tree.map(np.testing.assert_array_equal, states[-1], again[-1])


def test_leap_cube_reorient_privileged_critic_state_follows_the_policys_observation(leap):
    """``privileged_critic=True`` appends Playground's privileged state after the policy's 57
    entries, which stay as they were: the noise-free joint angles, palm-to-cube offset and
    rotation to the target, the joint and cube velocities and the fingertips from the palm."""
    env, reset, step = leap
    priv = envs.make(env.name, privileged_critic=True)
    assert (priv.policy_observation_size, priv.observation_size) == (57, 57 + 16 + 3 + 6 + 22 + 12)
    rng = np.random.default_rng(0)
    state = _run(reset, step, 2, 4, jnp.asarray(rng.uniform(-1, 1, (3, 4, 16)), jnp.float32))[-1]
    obs = np.asarray(
        jax.jit(jax.vmap(priv._observe_task, in_axes=(None, 0, 0)))(priv.model, state.data, state.task)
    )
    np.testing.assert_allclose(obs[:, :57], np.asarray(state.obs), atol=1e-6)  # (another program's rounding)
    qpos, qvel = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    np.testing.assert_allclose(obs[:, 57:73], qpos[:, :16], atol=1e-6)  # no joint noise
    cube, palm = np.asarray(state.data.xpos[:, env._cube]), np.asarray(state.data.site_xpos[:, env._palm])
    np.testing.assert_allclose(obs[:, 73:76], palm - cube, atol=1e-6)  # no position noise
    np.testing.assert_array_equal(obs[:, 82:104], qvel)
    assert np.abs(qvel).max() > 0  # the hand moved
    tips = np.asarray(state.data.site_xpos[:, env._tips]) - palm[:, None]
    np.testing.assert_allclose(obs[:, 104:], tips.reshape(4, 12), atol=1e-6)
    # the rotation from the target to the cube (its last two rows), without the policy's noise
    for i, (quat, goal) in enumerate(
        zip(np.asarray(state.data.xquat[:, env._cube]), np.asarray(state.task["goal"]), strict=True)
    ):
        inv, diff, mat = np.zeros(4), np.zeros(4), np.zeros(9)
        mujoco.mju_negQuat(inv, goal.astype(np.float64))
        mujoco.mju_mulQuat(diff, quat.astype(np.float64), inv)
        mujoco.mju_quat2Mat(mat, diff)
        np.testing.assert_allclose(obs[i, 76:82], mat[3:], atol=1e-5)
    assert np.abs(obs[:, 76:82] - obs[:, 35:41]).max() > 1e-3  # the policy's copy is noisy


def test_leap_cube_reorient_near_targets_aid_training_and_evaluation_leaves_them_out(leap):
    """``near_targets``: in that fraction of episodes the target is redrawn within
    ``near_angle`` of the cube once it has settled (``settle_steps``); the other episodes and
    ``for_evaluation`` (which the evaluator uses) are the task's."""
    env, reset, step = leap
    start = reset(jax.random.split(jax.random.PRNGKey(0), 1))
    data = jax.tree.map(lambda x: x[0], start.data)
    keys = jax.random.split(jax.random.PRNGKey(1), 2048)
    aided = envs.make(env.name, episode_length=8, near_targets=0.5, near_angle=0.5)
    draw = lambda e: jax.jit(jax.vmap(e._sample_task, in_axes=(0, None, None)))(keys, e.model, data)  # noqa: E731
    tasks = draw(aided)
    near = np.asarray(tasks["near_in"]) == aided.settle_steps
    assert 0.45 < near.mean() < 0.55 and (np.asarray(tasks["near_in"])[~near] == 0).all()
    plain = draw(env)
    jax.tree.map(np.testing.assert_array_equal, draw(aided.for_evaluation()), plain)
    assert env.for_evaluation() is env and aided.near_targets == 0.5
    jax.tree.map(np.testing.assert_array_equal, {k: v for k, v in tasks.items() if k != "near_in"}, plain)

    # the countdown: at 1 the target is redrawn near the cube; before and after, it stays
    cube = data.xquat[env._cube]

    def reward_step(left, key):
        task = {**jax.tree.map(lambda x: x[0], tasks), "near_in": left}
        return aided._reward_task(aided.model, data, data, jnp.zeros(16), task, key)[3]

    angle = jax.vmap(aided._angle_to_goal, in_axes=(None, 0))
    for left in (0, 1, 2):
        after = jax.jit(jax.vmap(reward_step, in_axes=(None, 0)))(jnp.int32(left), keys)
        np.testing.assert_array_equal(np.asarray(after["near_in"]), max(left - 1, 0))
        turned = np.asarray(angle(cube, after["goal"]))
        if left == 1:
            assert turned.max() <= 0.5 + 1e-5 and 0.4 < np.mean(turned < 0.25) < 0.6
        else:  # the episode's first target, untouched (no success yet, so it does not turn)
            np.testing.assert_allclose(
                np.asarray(after["goal"]), np.asarray(tasks["goal"])[:1].repeat(2048, 0), atol=1e-6
            )
    for bad in ({"near_targets": 1.5}, {"near_angle": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            envs.make(env.name, **bad)


def test_evaluator_and_rollout_score_the_env_for_evaluation():
    """The evaluator and rollouts step ``env.for_evaluation()`` (here: shorter episodes)."""
    env = envs.make("inverted_pendulum", episode_length=6)
    scored = envs.make("inverted_pendulum", episode_length=3)
    env.for_evaluation = lambda: scored
    act = lambda params, obs: jnp.zeros(obs.shape[:-1] + (1,))  # noqa: E731
    _, lengths, _ = agents.make_evaluator(env, act, 2)(None, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(np.asarray(lengths), 3)
    qpos, _, _, _ = agents.make_rollout(env, act)(None, jax.random.PRNGKey(0))
    assert qpos.shape[0] == 3 + 1


def test_leap_cube_reorient_steps_as_mujoco_c_without_the_mjx_caps(x64):
    """20 control steps of random actions from a reset state (nominal parameters, noise off, the
    scene as MuJoCo C steps it): fastrl's qpos and observation against MuJoCo C with the same
    servo targets and goal cube, observed through the scene's own sensors."""
    env = envs.make("leap_cube_reorient", randomization=NOMINAL, observation_noise=0.0, mjx_caps=False)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(5))
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = np.asarray(state.data.qpos), np.asarray(state.data.qvel)
    md.mocap_pos[:] = mj.key("home").mpos.reshape(1, 3)
    rng = np.random.default_rng(1)
    for _ in range(20):
        action = rng.uniform(-1, 1, 16)
        md.ctrl[:] = np.asarray(env._control(jnp.asarray(action), state.task))
        md.mocap_quat[:] = np.asarray(state.task["goal"])[None]
        state = step(state, jnp.asarray(action))
        for _ in range(env.frame_skip):
            mujoco.mj_step(mj, md)
        np.testing.assert_allclose(np.asarray(state.data.qpos), md.qpos, atol=1e-9)
        np.testing.assert_allclose(
            np.asarray(state.obs), env.observation_from_mujoco(md, state.task), atol=1e-9
        )
    assert not bool(state.done) and md.ncon > 0
