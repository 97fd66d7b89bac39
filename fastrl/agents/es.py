"""Evolution strategies (Salimans et al., 2017), the population evaluated as one batch.

Each ``update`` perturbs the flat policy parameters with ``population_size / 2`` antithetic
Gaussian pairs, runs one deterministic episode per member (all members in one ``vmap``, the
episode a ``lax.scan`` with finished episodes masked out), shapes the returns into centred
ranks, and feeds the search-gradient estimate to an optax optimiser. Antithetic twins share
their reset key (common random numbers), which lowers the estimator's variance. Observation
statistics are shared across the population and updated from every member's visited states.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from fastrl.agents import normalizer
from fastrl.agents.base import Learner, PolicyParams, make_act, observation_normalizer
from fastrl.agents.networks import MLP, NetworkConfig, TanhGaussian
from fastrl.envs.base import Env
from fastrl.physics.dataclass import pytree_dataclass


@dataclasses.dataclass(frozen=True)
class ESConfig:
    """ES hyperparameters (``algo=es``).

    Fields:
      population_size         members per update (even: antithetic pairs)
      sigma                   perturbation scale
      learning_rate           optimiser step size on the flat parameters
      weight_decay            L2 coefficient added to the gradient (OpenAI ES uses 0.005)
      fitness_shaping         "centered_rank" or "normalized" (z-scored returns)
      normalize_observations  shared running observation statistics
    """

    population_size: int = 256
    sigma: float = 0.02
    learning_rate: float = 0.01
    weight_decay: float = 0.0
    fitness_shaping: str = "centered_rank"
    normalize_observations: bool = True

    def __post_init__(self):
        if self.population_size < 2 or self.population_size % 2:
            raise ValueError(
                f"algo.population_size={self.population_size} must be even and >= 2 (antithetic pairs)"
            )
        if self.sigma <= 0 or self.learning_rate <= 0:
            raise ValueError("algo.sigma and algo.learning_rate must be > 0")
        if self.fitness_shaping not in ("centered_rank", "normalized"):
            raise ValueError(
                f"algo.fitness_shaping={self.fitness_shaping!r}; choose 'centered_rank' or 'normalized'"
            )


@pytree_dataclass
class ESState:
    """Fields: theta (D,) flat parameters, opt_state, obs_stats, rng, env_steps, updates."""

    theta: jax.Array
    opt_state: optax.OptState
    obs_stats: normalizer.RunningStats
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array


def centered_ranks(x: jax.Array) -> jax.Array:
    """Ranks of ``x`` mapped linearly onto [-0.5, 0.5] (ties broken by position)."""
    ranks = jnp.argsort(jnp.argsort(x)).astype(jnp.float32)
    return ranks / (x.shape[0] - 1) - 0.5


def es_gradient(fitness: jax.Array, eps: jax.Array, sigma: float) -> jax.Array:
    """Search-gradient estimate of E[F(theta + sigma eps)] from antithetic samples.

    Args:
      fitness: (P,) shaped fitness, members ordered [+eps_0..+eps_{P/2-1}, -eps_0..].
      eps: (P/2, D) the perturbation directions.
    """
    half = eps.shape[0]
    return (fitness[:half] - fitness[half:]) @ eps / (2 * half * sigma)


def env_steps_per_update(config: ESConfig, env: Env) -> int:
    """Env steps one update takes: an episode of ``env.episode_length`` steps per member."""
    return config.population_size * env.episode_length


def make_es(config: ESConfig, env: Env, network: NetworkConfig, total_updates: int = 1) -> Learner:
    """Builds ES for ``env`` (one episode of ``env.episode_length`` steps per member)."""
    del total_updates
    obs_size, nu = env.observation_size, env.action_size
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    dist = TanhGaussian(low, high)
    policy_net = MLP(network.policy_hidden, 2 * nu, network.activation)
    template = policy_net.init(jax.random.PRNGKey(0), jnp.zeros((1, obs_size)))
    _, unravel = ravel_pytree(template)
    optimizer = optax.adam(config.learning_rate)
    horizon = env.episode_length
    pop = config.population_size

    norm = observation_normalizer(config.normalize_observations)
    episode = _episode_fn(env, policy_net, dist, norm, unravel)

    def init(key: jax.Array) -> ESState:
        k_pi, k_rng = jax.random.split(key)
        theta, _ = ravel_pytree(policy_net.init(k_pi, jnp.zeros((1, obs_size))))
        zero = jnp.zeros((), jnp.int32)
        return ESState(theta=theta, opt_state=optimizer.init(theta), obs_stats=normalizer.init(obs_size),
                       rng=k_rng, env_steps=zero, updates=zero)  # fmt: skip

    def update(state: ESState) -> tuple[ESState, dict]:
        rng, k_eps, k_env = jax.random.split(state.rng, 3)
        eps = jax.random.normal(k_eps, (pop // 2, state.theta.shape[0]))
        thetas = state.theta + config.sigma * jnp.concatenate([eps, -eps])
        keys = jax.random.split(k_env, pop // 2)
        returns, (n, total, sq) = jax.vmap(episode, in_axes=(0, None, 0))(
            thetas, state.obs_stats, jnp.concatenate([keys, keys])
        )
        grad = es_gradient(_fitness(config, returns), eps, config.sigma) - config.weight_decay * state.theta
        upd, opt_state = optimizer.update(-grad, state.opt_state, state.theta)
        theta = optax.apply_updates(state.theta, upd)
        stats = state.obs_stats
        if config.normalize_observations:
            stats = _visited_stats(stats, n, total, sq)
        metrics = {
            "train/episode_return_sum": jnp.sum(returns),
            "train/episodes": jnp.asarray(pop, jnp.float32),
            "train/return_max": jnp.max(returns),
            "loss/grad_norm": jnp.linalg.norm(grad),
        }
        new = ESState(theta=theta, opt_state=opt_state, obs_stats=stats, rng=rng,
                      env_steps=state.env_steps + pop * horizon, updates=state.updates + 1)  # fmt: skip
        return new, metrics

    def policy_params(state: ESState) -> PolicyParams:
        return PolicyParams(network=unravel(state.theta), obs_stats=state.obs_stats)

    act = make_act(policy_net, dist, norm)

    return Learner(init=init, update=update, policy_params=policy_params, act=act,
                   env_steps_per_update=env_steps_per_update(config, env))  # fmt: skip


def _episode_fn(env: Env, policy_net: MLP, dist: TanhGaussian, norm, unravel):
    """``episode(theta, stats, key)``: the return of one deterministic episode of the policy with
    flat parameters ``theta`` (``env.episode_length`` steps, masked after it ends), and the
    moments (count, sum, sum of squares) of the observations it visited."""
    horizon, obs_size = env.episode_length, env.observation_size

    def episode(theta, stats, key):
        params = unravel(theta)
        state = env.reset(key)

        def one(carry, _):
            s, ret, alive, n, total, sq = carry
            a = dist.postprocess(dist.mode_raw(policy_net.apply(params, norm(stats, s.obs))))
            w = alive.astype(s.obs.dtype)
            n, total, sq = n + w, total + w * s.obs, sq + w * s.obs**2
            nxt = env.step(s, a)
            return (nxt, ret + w * nxt.reward, alive & ~nxt.done, n, total, sq), None

        z = jnp.zeros(obs_size)
        init = (state, jnp.zeros(()), jnp.ones((), bool), jnp.zeros(()), z, z)
        (_, ret, _, n, total, sq), _ = jax.lax.scan(one, init, None, length=horizon)
        return ret, (n, total, sq)

    return episode


def _fitness(config: ESConfig, returns: jax.Array) -> jax.Array:
    """(pop,) the returns shaped as ``config.fitness_shaping`` says: centred ranks or z-scores."""
    if config.fitness_shaping == "centered_rank":
        return centered_ranks(returns)
    return (returns - returns.mean()) / (returns.std() + 1e-8)


def _visited_stats(stats, n: jax.Array, total: jax.Array, sq: jax.Array):
    """The observation statistics updated with every member's visited observations: ``n`` (pop,)
    counts, ``total`` and ``sq`` (pop, obs_size) sums and sums of squares."""
    count = jnp.sum(n)
    mean = jnp.sum(total, 0) / jnp.maximum(count, 1.0)
    m2 = jnp.sum(sq, 0) - count * mean**2
    return normalizer.combine(stats, count, mean, jnp.maximum(m2, 0.0))
