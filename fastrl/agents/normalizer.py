"""Running observation statistics (parallel Welford), part of the training state."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.physics.dataclass import pytree_dataclass


@pytree_dataclass
class RunningStats:
    """Mean and variance of every observation seen so far.

    Fields:
      mean    (obs_size,)
      m2      (obs_size,) sum of squared deviations
      count   () number of observations (float, to avoid integer overflow)
    """

    mean: jax.Array
    m2: jax.Array
    count: jax.Array


def init(size: int, dtype=jnp.float32) -> RunningStats:
    return RunningStats(jnp.zeros(size, dtype), jnp.zeros(size, dtype), jnp.zeros((), dtype))


def update(stats: RunningStats, batch: jax.Array) -> RunningStats:
    """Adds a batch (..., obs_size) with Chan et al.'s parallel combination (stable in float32)."""
    x = batch.reshape(-1, batch.shape[-1]).astype(stats.mean.dtype)
    mean_b = jnp.mean(x, axis=0)
    return combine(
        stats, jnp.asarray(x.shape[0], stats.count.dtype), mean_b, jnp.sum((x - mean_b) ** 2, axis=0)
    )


def combine(stats: RunningStats, n: jax.Array, mean_b: jax.Array, m2_b: jax.Array) -> RunningStats:
    """Adds the moments (count, mean, sum of squared deviations) of another sample."""
    n = jnp.asarray(n, stats.count.dtype)
    total = jnp.maximum(stats.count + n, 1.0)
    delta = mean_b - stats.mean
    mean = stats.mean + delta * n / total
    m2 = stats.m2 + m2_b + delta**2 * stats.count * n / total
    return RunningStats(mean, m2, stats.count + n)


def head(stats: RunningStats, size: int) -> RunningStats:
    """The statistics of an observation's first ``size`` entries."""
    return RunningStats(stats.mean[:size], stats.m2[:size], stats.count)


def normalize(stats: RunningStats, x: jax.Array, clip: float = 10.0) -> jax.Array:
    """(x - mean) / std, clipped to [-clip, clip]; identity before any data."""
    var = jnp.where(stats.count > 1, stats.m2 / jnp.maximum(stats.count, 1.0), 1.0)
    std = jnp.sqrt(jnp.maximum(var, 1e-6))
    return jnp.clip((x - stats.mean) / std, -clip, clip)
