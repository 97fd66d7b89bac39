"""On-device replay buffer: a ring buffer with a modular write index.

Insertion scatters a batch at ``(ptr + arange(n)) % capacity``; under ``jit`` with the training
state donated, XLA updates the buffer in place, so no step copies the whole buffer. Sampling
draws uniform indices below ``size``. The buffer is a pytree inside the training state, so it is
checkpointed with everything else and a resumed SAC run samples exactly what it would have.
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
