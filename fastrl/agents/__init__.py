"""Learners as pure function pairs: ``make_x(config, env, network) -> Learner(init, update, ...)``.

``init(key)`` builds the whole training state (a pytree: params, optimiser state, normaliser,
env states, RNG, counters); ``update(state) -> (state, metrics)`` is one iteration with the
simulator fused in. The runner jits a ``lax.fori_loop`` of ``update`` (its trip count, the updates
per chunk, a traced argument); a checkpoint is the state.
"""

from __future__ import annotations

from fastrl.agents import apg, es, off_policy, ppo
from fastrl.agents.apg import APGConfig, UnsuitableEnvError, make_apg
from fastrl.agents.base import Algorithm, Learner, PolicyParams, SplitsOverDevices
from fastrl.agents.es import ESConfig, make_es
from fastrl.agents.evaluation import make_evaluator, make_rollout
from fastrl.agents.fasttd3 import FastTD3Config, make_fasttd3
from fastrl.agents.networks import NetworkConfig
from fastrl.agents.ppo import PPOConfig, make_ppo
from fastrl.agents.sac import SACConfig, make_sac

ALGORITHMS = {
    "ppo": Algorithm(
        PPOConfig, make_ppo, ppo.env_steps_per_update, splits_over_devices=True, privileged_critic=True
    ),
    "sac": Algorithm(SACConfig, make_sac, off_policy.env_steps_per_update),
    "fasttd3": Algorithm(
        FastTD3Config, make_fasttd3, off_policy.env_steps_per_update, privileged_critic=True
    ),
    "es": Algorithm(ESConfig, make_es, es.env_steps_per_update),
    "apg": Algorithm(APGConfig, make_apg, apg.env_steps_per_update),
}


def config_class(name: str):
    """The frozen config dataclass of algorithm ``name``."""
    try:
        return ALGORITHMS[name].config
    except KeyError:
        choices = ", ".join(sorted(ALGORITHMS))
        raise ValueError(f"unknown algorithm {name!r}; choose one of: {choices}") from None


def env_steps_per_update(name: str, config, env) -> int:
    """Env steps one update of learner ``name`` with ``config`` takes on ``env`` (what its
    ``Learner.env_steps_per_update`` will say), without building it."""
    return ALGORITHMS[name].env_steps(config, env)


def splits_evenly(name: str, config, devices: int) -> bool:
    """Whether learner ``name`` with ``config`` can split its own work over ``devices`` devices
    (False for a learner that never splits it: ``Algorithm.splits_over_devices``)."""
    if not ALGORITHMS[name].splits_over_devices:
        return False
    split: SplitsOverDevices = config
    return split.splits_evenly(devices)


def make_learner(name: str, config, env, network: NetworkConfig, total_updates: int, mesh=None) -> Learner:
    """Builds the learner ``name`` from its config dataclass (``mesh``: see ``splits_over_devices``)."""
    algorithm = ALGORITHMS[name]
    if not isinstance(config, algorithm.config):
        raise TypeError(f"{name} expects a {algorithm.config.__name__}, got {type(config).__name__}")
    if env.policy_observation_size != env.observation_size and not algorithm.privileged_critic:
        raise UnsuitableEnvError(
            f"{name} cannot train {env.name} made with a privileged critic state (its observation "
            f"appends {env.observation_size - env.policy_observation_size} entries that only a "
            f"critic may read, and {name} has no separate critic input): make the env without "
            "it (env.options.privileged_critic=false), or train it with ppo"
        )
    if mesh is not None:
        if not algorithm.splits_over_devices:
            raise ValueError(f"{name} does not split its work over devices itself; pass mesh=None")
        return algorithm.make(config, env, network, total_updates, mesh=mesh)
    return algorithm.make(config, env, network, total_updates)


__all__ = [
    "ALGORITHMS",
    "Algorithm",
    "SplitsOverDevices",
    "make_rollout",
    "env_steps_per_update",
    "splits_evenly",
    "APGConfig",
    "ESConfig",
    "FastTD3Config",
    "SACConfig",
    "UnsuitableEnvError",
    "make_apg",
    "make_es",
    "make_fasttd3",
    "make_sac",
    "Learner",
    "NetworkConfig",
    "PPOConfig",
    "PolicyParams",
    "config_class",
    "make_evaluator",
    "make_learner",
    "make_ppo",
]
