"""What every learner returns, and the policy parameters evaluation and ``load_policy`` use."""

from __future__ import annotations

from typing import NamedTuple

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
    """

    init: object
    update: object
    policy_params: object
    act: object
    env_steps_per_update: int
