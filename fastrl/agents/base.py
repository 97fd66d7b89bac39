"""What every learner returns, and the policy parameters evaluation and ``load_policy`` use."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import jax

from fastrl.agents import normalizer
from fastrl.physics.dataclass import pytree_dataclass


@pytree_dataclass
class PolicyParams:
    """Everything a deterministic policy needs: network weights and observation statistics."""

    network: dict
    obs_stats: normalizer.RunningStats


class Learner(NamedTuple):
    """A learning algorithm as pure functions over its training-state pytree.

    Fields:
      init                  (key) -> state: params, optimiser, normaliser, env states, RNG, counters
      update                (state) -> (state, metrics): one iteration, simulator fused in
      policy_params         (state) -> PolicyParams
      act                   (PolicyParams, obs, key | None) -> action; key None = deterministic
      env_steps_per_update  environment steps one ``update`` takes (static)
      num_envs              the env batch of the state's env states (every ``envs.State`` in it
                            has this leading axis), or None where the state holds none (ES)
    """

    init: Callable[[jax.Array], Any]
    update: Callable[[Any], tuple[Any, dict[str, jax.Array]]]
    policy_params: Callable[[Any], PolicyParams]
    act: Callable[..., jax.Array]
    env_steps_per_update: int
    num_envs: int | None = None


class SplitsOverDevices(Protocol):
    """The config of a learner that splits its own work over a device mesh (its factory takes
    ``mesh=``): it says which device counts divide its batches evenly."""

    def splits_evenly(self, devices: int) -> bool: ...


class Algorithm(NamedTuple):
    """One learning algorithm as the registry knows it.

    Fields:
      config               the frozen config dataclass
      make                 ``make(config, env, network, total_updates[, mesh=]) -> Learner``
      env_steps            ``env_steps(config, env) -> int``: env steps one update takes, known
                           before the learner is built (``total_updates`` follows from it)
      splits_over_devices  ``make`` takes a device mesh and splits its env batch and minibatch
                           gradients itself; ``config`` is then a ``SplitsOverDevices``
      privileged_critic    it trains envs whose observation appends privileged state after
                           the policy's part (``Env.policy_observation_size``): its critic reads
                           all of it, its policy only that part
    """

    config: type
    make: Callable[..., Learner]
    env_steps: Callable[[Any, Any], int]
    splits_over_devices: bool = False
    privileged_critic: bool = False


def observation_normalizer(enabled: bool) -> Callable[[normalizer.RunningStats, jax.Array], jax.Array]:
    """``norm(stats, obs)``: the normalised observation, or ``obs`` itself when disabled."""

    def norm(stats: normalizer.RunningStats, obs: jax.Array) -> jax.Array:
        return normalizer.normalize(stats, obs) if enabled else obs

    return norm


def make_act(
    policy_net,
    dist,
    norm,
    to_env: Callable[[jax.Array], jax.Array] | None = None,
    policy_obs: int | None = None,
):
    """``act(policy_params, obs, key=None)``: the policy's mode (key None) or a sample, in env units.

    ``policy_obs``: the policy reads only the observation's first ``policy_obs`` entries (an env's
    ``policy_observation_size``, where the rest is privileged state for a critic); ``obs`` may
    then be the whole observation or just those entries."""

    def act(pp: PolicyParams, obs: jax.Array, key: jax.Array | None = None) -> jax.Array:
        stats = pp.obs_stats
        if policy_obs is not None:
            stats, obs = normalizer.head(stats, policy_obs), obs[..., :policy_obs]
        out = policy_net.apply(pp.network, norm(stats, obs))
        raw = dist.mode_raw(out) if key is None else dist.sample_raw(out, key)
        action = dist.postprocess(raw)
        return action if to_env is None else to_env(action)

    return act
