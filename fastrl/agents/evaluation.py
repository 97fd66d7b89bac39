"""Deterministic evaluation: one episode per env under the policy's mode, and one episode's frames."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.sharding import Mesh

from fastrl.envs.base import Env
from fastrl.runtime.devices import over_devices


def make_evaluator(env: Env, act, num_envs: int, mesh: Mesh | None = None):
    """Returns ``evaluate(policy_params, key) -> (returns, lengths, final)``.

    Each env runs until its first episode ends (termination or the time limit); later
    auto-reset episodes are masked out. ``act(policy_params, obs)`` must be deterministic.
    ``returns`` and ``lengths`` are (num_envs,); ``final`` maps each of the env's
    ``eval_metrics`` (e.g. ``success`` of a goal-reaching task) to its (num_envs,) value at the
    episode's last step. ``mesh``: split the environments over its devices (``num_envs`` must
    divide evenly), each device stepping its slice; None steps them all on one device.
    """
    if mesh is not None and num_envs % mesh.devices.size:
        raise ValueError(f"{num_envs} evaluation envs do not divide over {mesh.devices.size} devices")
    env = env.for_evaluation()
    names = tuple(getattr(env, "eval_metrics", ()))
    reset = jax.vmap(env.reset)
    step = over_devices(jax.vmap(env.step), mesh)

    def evaluate(policy_params, key):
        state = reset(jax.random.split(key, num_envs))

        def one(carry, _):
            state, ret, length, alive, final = carry
            nxt = step(state, act(policy_params, state.obs))
            ret = ret + jnp.where(alive, nxt.reward, 0.0)
            length = length + alive.astype(jnp.int32)
            final = {k: jnp.where(alive, nxt.metrics[k], v) for k, v in final.items()}
            return (nxt, ret, length, alive & ~nxt.done, final), None

        zeros = jnp.zeros(num_envs)
        final = {k: zeros for k in names}
        init = (state, zeros, jnp.zeros(num_envs, jnp.int32), jnp.ones(num_envs, bool), final)
        (_, ret, length, _, final), _ = jax.lax.scan(one, init, None, length=env.episode_length)
        return ret, length, final

    return evaluate


def make_rollout(env, act, length: int | None = None):
    """A jittable ``(params, key) -> (qpos, alive, markers, overflow)`` of one deterministic episode.

    Args:
      env: the env; act: the learner's deterministic ``act(params, obs)``.
      length: env steps to run (default and at most: the env's episode length).
    Returns:
      The function; its outputs are (length + 1, nq) positions from the reset on, a
      (length + 1,) mask of the frames that belong to the episode, and the (length + 1, M, 3)
      positions of the env's ``markers`` (its goals) per frame, and (length + 1,) the contacts
      the scene's budgets dropped in the step that led to each frame (the env's
      ``contact_overflow`` metric; zeros where it has none). The step that ends the episode is
      masked out: its state already holds the next episode's reset.
    """
    env = env.for_evaluation()
    length = env.episode_length if length is None else min(length, env.episode_length)

    def rollout(params, key):
        state = env.reset(key)

        def one(carry, _):
            s, alive = carry
            nxt = env.step(s, act(params, s.obs))
            alive = alive & ~nxt.done
            dropped = nxt.metrics.get("contact_overflow", jnp.zeros(()))
            return (nxt, alive), (nxt.data.qpos, alive, env.markers(nxt.task), dropped)

        scan = jax.lax.scan(one, (state, jnp.ones((), bool)), None, length=length)
        qpos, alive, marks, dropped = scan[1]
        first = lambda x, xs: jnp.concatenate([x[None], xs])  # noqa: E731
        marks = first(env.markers(state.task), marks)
        dropped = first(jnp.zeros((), dropped.dtype), dropped)
        return first(state.data.qpos, qpos), first(jnp.ones((), bool), alive), marks, dropped

    return rollout
