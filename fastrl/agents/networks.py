"""Policy and value networks (flax), and the squashed-Gaussian action distribution."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

_ACTIVATIONS = {"tanh": nn.tanh, "relu": nn.relu, "swish": nn.swish, "elu": nn.elu}


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the networks (Hydra group ``network``).

    Fields:
      policy_hidden   hidden layer widths of the policy MLP; [] makes the policy linear in the
                      (normalised) observation, as in augmented random search
      value_hidden    hidden layer widths of the value (or Q) MLP ([] likewise linear)
      activation      one of tanh, relu, swish, elu
    """

    policy_hidden: tuple[int, ...] = (32, 32, 32, 32)
    value_hidden: tuple[int, ...] = (256, 256, 256, 256, 256)
    activation: str = "swish"

    def __post_init__(self):
        if self.activation not in _ACTIVATIONS:
            raise ValueError(f"network.activation={self.activation!r}; choose one of {sorted(_ACTIVATIONS)}")
        for name in ("policy_hidden", "value_hidden"):
            sizes = tuple(getattr(self, name))
            if any(int(s) < 1 for s in sizes):
                raise ValueError(f"network.{name}={list(sizes)} must be positive widths ([]: linear)")
            object.__setattr__(self, name, tuple(int(s) for s in sizes))


class MLP(nn.Module):
    """Fully connected network; the last layer is linear with a small initialisation."""

    hidden: Sequence[int]
    out: int
    activation: str = "swish"
    final_scale: float = 0.01

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = _ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = act(nn.Dense(width, kernel_init=nn.initializers.lecun_uniform())(x))
        init = nn.initializers.variance_scaling(self.final_scale, "fan_in", "uniform")
        return nn.Dense(self.out, kernel_init=init)(x)


class TanhGaussian:
    """A Gaussian squashed by tanh into (-1, 1), then scaled to the action bounds.

    The network outputs ``2 * nu`` numbers: the mean and a pre-softplus scale. Log-probabilities
    include the tanh change of variables. ``entropy`` is the Gaussian's (before squashing);
    ``squashed_entropy`` adds the change of variables at one reparameterised sample, a one-sample
    estimate of the entropy of the action itself, which (unlike the Gaussian's) stops growing
    once the Gaussian is wide enough to saturate tanh.
    """

    min_std = 1e-3

    def __init__(self, low: jax.Array, high: jax.Array, init_std: float | None = None):
        """``init_std``: the pre-tanh scale where the network outputs 0 (at initialisation, since
        the last layer starts near 0); None keeps softplus(0) + min_std = 0.694."""
        self.center = (high + low) / 2.0
        self.half = (high - low) / 2.0
        if init_std is not None and not init_std > self.min_std:
            raise ValueError(f"init_std={init_std} must be > {self.min_std}")
        # softplus(raw + shift) + min_std = init_std at raw = 0.
        self.shift = 0.0 if init_std is None else math.log(math.expm1(init_std - self.min_std))

    def _split(self, out: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean, raw = jnp.split(out, 2, axis=-1)
        return mean, jax.nn.softplus(raw + self.shift) + self.min_std

    def sample_raw(self, out: jax.Array, key: jax.Array) -> jax.Array:
        """A pre-tanh sample u; the action is ``postprocess(u)``."""
        mean, std = self._split(out)
        return mean + std * jax.random.normal(key, mean.shape, mean.dtype)

    @staticmethod
    def _log_jacobian(raw: jax.Array) -> jax.Array:
        # log |d tanh(u)/du| = log(1 - tanh(u)^2), written stably.
        return 2.0 * (jnp.log(2.0) - raw - jax.nn.softplus(-2.0 * raw))

    def mode_raw(self, out: jax.Array) -> jax.Array:
        return self._split(out)[0]

    def postprocess(self, raw: jax.Array) -> jax.Array:
        return self.center + self.half * jnp.tanh(raw)

    def log_prob(self, out: jax.Array, raw: jax.Array) -> jax.Array:
        mean, std = self._split(out)
        z = (raw - mean) / std
        gauss = -0.5 * z**2 - jnp.log(std) - 0.5 * jnp.log(2 * jnp.pi)
        return jnp.sum(gauss - self._log_jacobian(raw), axis=-1)

    def entropy(self, out: jax.Array) -> jax.Array:
        _, std = self._split(out)
        return jnp.sum(0.5 + 0.5 * jnp.log(2 * jnp.pi) + jnp.log(std), axis=-1)

    def squashed_entropy(self, out: jax.Array, key: jax.Array) -> jax.Array:
        """Entropy of tanh(u) (up to the constant log of the bounds' half-widths), estimated at
        one reparameterised sample of u, so it has gradients through both mean and scale."""
        mean, _ = self._split(out)
        return self.squashed_entropy_at(out, jax.random.normal(key, mean.shape, mean.dtype))

    def squashed_entropy_at(self, out: jax.Array, noise: jax.Array) -> jax.Array:
        """``squashed_entropy`` at the given standard-normal draws (shaped like the mean)."""
        mean, std = self._split(out)
        return self.entropy(out) + jnp.sum(self._log_jacobian(mean + std * noise), axis=-1)
