"""On-device replay buffer: a ring buffer with a modular write index.

Insertion scatters a batch at ``(ptr + arange(n)) % capacity``; under ``jit`` with the training
state donated, XLA updates the buffer in place, so no step copies the whole buffer. Sampling
draws uniform indices below ``size``. The buffer is a pytree inside the training state, so it is
checkpointed with everything else and a resumed SAC run samples exactly what it would have.

``TrajectoryBuffer`` keeps every env's steps in order (a ring over time, one column per env), so
that n-step returns can be read back without crossing an episode's end.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.physics.dataclass import pytree_dataclass


@pytree_dataclass
class ReplayBuffer:
    """Fields: data {name: (capacity, ...)}, ptr () next write slot, size () valid entries."""

    data: dict
    ptr: jax.Array
    size: jax.Array


def init(capacity: int, example: dict) -> ReplayBuffer:
    """An empty buffer holding ``capacity`` items shaped like ``example``'s leaves (one item)."""
    data = {k: jnp.zeros((capacity,) + jnp.shape(v), jnp.asarray(v).dtype) for k, v in example.items()}
    return ReplayBuffer(data=data, ptr=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))


def capacity(buf: ReplayBuffer) -> int:
    return next(iter(buf.data.values())).shape[0]


def insert(buf: ReplayBuffer, batch: dict) -> ReplayBuffer:
    """Writes a batch {name: (n, ...)} after the last write, wrapping around."""
    cap = capacity(buf)
    n = next(iter(batch.values())).shape[0]
    idx = (buf.ptr + jnp.arange(n, dtype=jnp.int32)) % cap
    data = {k: buf.data[k].at[idx].set(batch[k].astype(buf.data[k].dtype)) for k in buf.data}
    return ReplayBuffer(data=data, ptr=(buf.ptr + n) % cap, size=jnp.minimum(buf.size + n, cap))


def sample(buf: ReplayBuffer, key: jax.Array, batch_size: int) -> dict:
    """``batch_size`` items drawn uniformly (with replacement) from the valid entries."""
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buf.size, 1))
    return {k: v[idx] for k, v in buf.data.items()}


@pytree_dataclass
class TrajectoryBuffer:
    """A ring over time of every env's transitions, kept in step order so that n-step returns can
    be read back.

    Fields: data {name: (length, num_envs, ...)}, ptr () next time slot, size () valid steps."""

    data: dict
    ptr: jax.Array
    size: jax.Array


def init_trajectories(length: int, num_envs: int, example: dict) -> TrajectoryBuffer:
    """An empty buffer of ``length`` steps of ``num_envs`` envs, items shaped like ``example``."""
    data = {k: jnp.zeros((length, num_envs) + jnp.shape(v), jnp.asarray(v).dtype) for k, v in example.items()}
    return TrajectoryBuffer(data=data, ptr=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))


def append(buf: TrajectoryBuffer, steps: dict) -> TrajectoryBuffer:
    """Writes consecutive steps of every env ``{name: (steps, num_envs, ...)}`` after the newest,
    wrapping around."""
    length = next(iter(buf.data.values())).shape[0]
    n = next(iter(steps.values())).shape[0]
    idx = (buf.ptr + jnp.arange(n, dtype=jnp.int32)) % length
    data = {k: buf.data[k].at[idx].set(steps[k].astype(buf.data[k].dtype)) for k in buf.data}
    return TrajectoryBuffer(data=data, ptr=(buf.ptr + n) % length, size=jnp.minimum(buf.size + n, length))


def sample_n_step(buf: TrajectoryBuffer, key: jax.Array, batch_size: int, n: int, gamma: float) -> dict:
    """``batch_size`` n-step transitions drawn uniformly over envs and over the start steps whose
    next ``n - 1`` steps are stored.

    Each needs the fields ``obs``, ``action``, ``reward``, ``terminated``, ``done`` (the episode
    ended at that step, by termination or time limit) and ``next_obs`` (the observation after the
    step, before any reset). The window stops at the first step that ends an episode. Returns
    ``obs`` and ``action`` of the first step; ``reward``, the discounted sum over the window;
    ``next_obs`` after its last step; and ``discount``, ``gamma ** steps`` times 0 where the
    last step terminated (a time limit is not a terminal state, so it still bootstraps).
    """
    length, num_envs = next(iter(buf.data.values())).shape[:2]
    k_t, k_e = jax.random.split(key)
    starts = jnp.maximum(buf.size - n + 1, 1)
    first = (buf.ptr - buf.size + jax.random.randint(k_t, (batch_size,), 0, starts)) % length
    env = jax.random.randint(k_e, (batch_size,), 0, num_envs)
    times = (first[:, None] + jnp.arange(n)[None]) % length  # (batch, n)
    at = lambda name: buf.data[name][times, env[:, None]]  # noqa: E731 - (batch, n, ...)
    done = at("done").astype(jnp.float32)
    alive = jnp.cumprod(jnp.concatenate([jnp.ones((batch_size, 1)), 1.0 - done[:, :-1]], 1), axis=1)
    powers = gamma ** jnp.arange(n, dtype=jnp.float32)
    last = jnp.sum(alive, axis=1).astype(jnp.int32) - 1  # the window's final step
    rows = jnp.arange(batch_size)
    terminated = buf.data["terminated"][times[rows, last], env].astype(jnp.float32)
    return {
        "obs": buf.data["obs"][first, env],
        "action": buf.data["action"][first, env],
        "reward": jnp.sum(at("reward") * alive * powers, axis=1),
        "next_obs": buf.data["next_obs"][times[rows, last], env],
        "discount": gamma ** (last + 1.0) * (1.0 - terminated),
    }
