"""Deterministic evaluation: one episode per env under the policy's mode."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.envs.base import Env


def make_evaluator(env: Env, act, num_envs: int):
    """Returns ``evaluate(policy_params, key) -> (returns (num_envs,), lengths (num_envs,))``.

    Each env runs until its first episode ends (termination or the time limit); later
    auto-reset episodes are masked out. ``act(policy_params, obs)`` must be deterministic.
    """
    reset = jax.vmap(env.reset)
    step = jax.vmap(env.step)

    def evaluate(policy_params, key):
        state = reset(jax.random.split(key, num_envs))

        def one(carry, _):
            state, ret, length, alive = carry
            nxt = step(state, act(policy_params, state.obs))
            ret = ret + jnp.where(alive, nxt.reward, 0.0)
            length = length + alive.astype(jnp.int32)
            return (nxt, ret, length, alive & ~nxt.done), None

        zeros = jnp.zeros(num_envs)
        init = (state, zeros, jnp.zeros(num_envs, jnp.int32), jnp.ones(num_envs, bool))
        (_, ret, length, _), _ = jax.lax.scan(one, init, None, length=env.episode_length)
        return ret, length

    return evaluate
