"""Each fastrl env against Gymnasium's own v5 env running fastrl's asset, step by step.

Both start from the same state (Gymnasium's reset, copied into fastrl), take the same random
actions for 20 steps, and must report the same observations, rewards and termination. fastrl
runs in float32, Gymnasium in float64: contact-free envs agree to float32 rounding; contact envs
within the contact solver's agreement (see tests/physics/test_contact.py).
"""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import envs
from fastrl.envs.base import ASSETS

# name -> (Gymnasium id, relative tolerance on obs/reward, absolute tolerance)
CASES = {
    "inverted_pendulum": ("InvertedPendulum-v5", 1e-4, 1e-4),
    "inverted_double_pendulum": ("InvertedDoublePendulum-v5", 1e-4, 1e-4),
    "reacher": ("Reacher-v5", 1e-4, 1e-4),
    "swimmer": ("Swimmer-v5", 1e-4, 1e-4),
    "halfcheetah": ("HalfCheetah-v5", 1e-3, 1e-3),
    "hopper": ("Hopper-v5", 1e-3, 1e-3),
    "walker2d": ("Walker2d-v5", 1e-3, 1e-3),
    "ant": ("Ant-v5", 1e-3, 1e-3),
    "humanoid": ("Humanoid-v5", 1e-3, 1e-3),
    "humanoidstandup": ("HumanoidStandup-v5", 1e-3, 1e-3),
    "pusher": ("Pusher-v5", 1e-4, 1e-4),
}
STEPS = 20


@pytest.mark.parametrize("name", sorted(CASES))
def test_matches_gymnasium_v5(name):
    gym_id, rtol, atol = CASES[name]
    env = envs.make(name)
    genv = gymnasium.make(gym_id, xml_file=str(ASSETS / env.asset))
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float64)
    assert genv.observation_space == obs_space
    low, high = env.action_bounds
    assert genv.action_space == gymnasium.spaces.Box(low, high, dtype=np.float32)
    assert env.dt == pytest.approx(genv.unwrapped.dt)
    assert env.episode_length == genv.spec.max_episode_steps

    gobs, _ = genv.reset(seed=3)
    data = genv.unwrapped.data
    # Copies: jnp.asarray may alias MuJoCo's buffers, which the next mj_step overwrites.
    state = jax.jit(env.reset_to)(jnp.array(data.qpos.copy()), jnp.array(data.qvel.copy()))
    np.testing.assert_allclose(state.obs, gobs, rtol=rtol, atol=atol)
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    for t in range(STEPS):
        action = rng.uniform(low, high).astype(np.float32)
        gobs, greward, gterm, _, _ = genv.step(action)
        state = step(state, jnp.asarray(action))
        err = f"{name} step {t}"
        np.testing.assert_allclose(state.final_obs, gobs, rtol=rtol, atol=atol, err_msg=err)
        np.testing.assert_allclose(state.reward, greward, rtol=rtol, atol=atol, err_msg=err)
        assert bool(state.terminated) == gterm, err
        if gterm:
            break
