"""What the replay learners (SAC, FastTD3) share: their env steps per update, optimisers, the
action scaling from [-1, 1] to the env's bounds, the warm-up mask and the per-update metrics."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax

from fastrl.envs.base import Env


def env_steps_per_update(config, env: Env) -> int:
    """Env steps one update takes: ``config.env_steps_per_update`` steps of each of ``num_envs`` envs."""
    del env
    return config.num_envs * config.env_steps_per_update


def optimizer(learning_rate: float, max_grad_norm: float | None, weight_decay: float = 0.0):
    """Adam (AdamW where ``weight_decay`` > 0), after a global gradient-norm clip where one is set."""
    clip = [optax.clip_by_global_norm(max_grad_norm)] if max_grad_norm else []
    adam = (
        optax.adamw(learning_rate, weight_decay=weight_decay) if weight_decay else optax.adam(learning_rate)
    )
    return optax.chain(*clip, adam)


def to_env_bounds(env: Env) -> Callable[[jax.Array], jax.Array]:
    """Maps actions in [-1, 1] onto the env's action bounds."""
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    return lambda u: (high + low) / 2 + (high - low) / 2 * u


def unless_warming_up(ready: jax.Array, new, old):
    """``new`` once ``ready``, else ``old`` (leaf by leaf, branch-free): no learning until the
    random warm-up has filled the buffer."""
    return jax.tree.map(lambda a, b: jnp.where(ready, a, b), new, old)


def update_metrics(info: dict, done: jax.Array, episode_return: jax.Array, reward: jax.Array) -> dict:
    """The gradient steps' losses (means over the update) and the collected episodes' metrics."""
    done = done.astype(jnp.float32)
    metrics = {f"loss/{k}": jnp.mean(v) for k, v in info.items()}
    metrics["train/episode_return_sum"] = jnp.sum(episode_return * done)
    metrics["train/episodes"] = jnp.sum(done)
    metrics["train/reward_mean"] = jnp.mean(reward)
    return metrics
