"""Learners as pure function pairs: ``make_x(config, env, network) -> Learner(init, update, ...)``.

``init(key)`` builds the whole training state (a pytree: params, optimiser state, normaliser,
env states, RNG, counters); ``update(state) -> (state, metrics)`` is one iteration with the
simulator fused in. The runner jits a ``lax.scan`` of ``update``; a checkpoint is the state.
"""

from __future__ import annotations

import dataclasses

from fastrl.agents.evaluation import make_evaluator
from fastrl.agents.networks import NetworkConfig
from fastrl.agents.ppo import Learner, PolicyParams, PPOConfig, make_ppo

ALGORITHMS = {"ppo": (PPOConfig, make_ppo)}


def config_class(name: str):
    """The frozen config dataclass of algorithm ``name``."""
    try:
        return ALGORITHMS[name][0]
    except KeyError:
        choices = ", ".join(sorted(ALGORITHMS))
        raise ValueError(f"unknown algorithm {name!r}; choose one of: {choices}") from None


def make_learner(name: str, config, env, network: NetworkConfig, total_updates: int) -> Learner:
    """Builds the learner ``name`` from its config dataclass."""
    cls, factory = ALGORITHMS[name]
    if not isinstance(config, cls):
        raise TypeError(f"{name} expects a {cls.__name__}, got {type(config).__name__}")
    return factory(config, env, network, total_updates)


def config_fields(name: str) -> list[str]:
    return [f.name for f in dataclasses.fields(config_class(name))]


__all__ = [
    "ALGORITHMS",
    "Learner",
    "NetworkConfig",
    "PPOConfig",
    "PolicyParams",
    "config_class",
    "config_fields",
    "make_evaluator",
    "make_learner",
    "make_ppo",
]
