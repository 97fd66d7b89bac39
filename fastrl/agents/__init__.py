"""Learners as pure function pairs: ``make_x(config, env, network) -> Learner(init, update, ...)``.

``init(key)`` builds the whole training state (a pytree: params, optimiser state, normaliser,
env states, RNG, counters); ``update(state) -> (state, metrics)`` is one iteration with the
simulator fused in. The runner jits a ``lax.scan`` of ``update``; a checkpoint is the state.
"""

from __future__ import annotations

import dataclasses
import inspect

from fastrl.agents.apg import APGConfig, UnsuitableEnvError, make_apg
from fastrl.agents.base import Learner, PolicyParams
from fastrl.agents.es import ESConfig, make_es
from fastrl.agents.evaluation import make_evaluator
from fastrl.agents.networks import NetworkConfig
from fastrl.agents.ppo import PPOConfig, make_ppo
from fastrl.agents.sac import SACConfig, make_sac

ALGORITHMS = {
    "ppo": (PPOConfig, make_ppo),
    "sac": (SACConfig, make_sac),
    "es": (ESConfig, make_es),
    "apg": (APGConfig, make_apg),
}


def config_class(name: str):
    """The frozen config dataclass of algorithm ``name``."""
    try:
        return ALGORITHMS[name][0]
    except KeyError:
        choices = ", ".join(sorted(ALGORITHMS))
        raise ValueError(f"unknown algorithm {name!r}; choose one of: {choices}") from None


def splits_over_devices(name: str) -> bool:
    """Whether learner ``name`` takes a device mesh and splits its env batch and minibatches itself."""
    return "mesh" in inspect.signature(ALGORITHMS[name][1]).parameters


def make_learner(name: str, config, env, network: NetworkConfig, total_updates: int, mesh=None) -> Learner:
    """Builds the learner ``name`` from its config dataclass (``mesh``: see ``splits_over_devices``)."""
    cls, factory = ALGORITHMS[name]
    if not isinstance(config, cls):
        raise TypeError(f"{name} expects a {cls.__name__}, got {type(config).__name__}")
    if mesh is not None:
        if not splits_over_devices(name):
            raise ValueError(f"{name} does not split its work over devices itself; pass mesh=None")
        return factory(config, env, network, total_updates, mesh=mesh)
    return factory(config, env, network, total_updates)


def config_fields(name: str) -> list[str]:
    return [f.name for f in dataclasses.fields(config_class(name))]


__all__ = [
    "ALGORITHMS",
    "APGConfig",
    "ESConfig",
    "SACConfig",
    "UnsuitableEnvError",
    "make_apg",
    "make_es",
    "make_sac",
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
