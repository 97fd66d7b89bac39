"""An env's ``State`` between steps, and the ``Data`` fields an auto-reset always carries into
the new episode (``wrappers.auto_reset``)."""

from __future__ import annotations

import dataclasses

import jax

from fastrl.physics import Data
from fastrl.physics.dataclass import pytree_dataclass


@pytree_dataclass
class State:
    """One environment's state between steps (batched: every leaf gains a leading axis).

    Fields:
      data          physics ``Data`` (after ``mj_step``; kinematics from the last substep's start)
      obs           (obs_size,) observation of the current episode (the new one after a reset)
      reward        () reward of the last step (0 right after ``reset``)
      terminated    () bool, the last step ended the episode by the task's rule or divergence
      truncated     () bool, the last step hit the time limit
      final_obs     (obs_size,) observation the last step produced before any auto-reset;
                    equals ``obs`` when the episode goes on
      metrics       dict name -> () per-step quantities: each weighted reward term as
                    ``reward_<term>``, plus env-specific ones (``x_velocity``...) and ``diverged``;
                    ``contact_overflow`` where the scene's contact budgets can drop contacts:
                    the most any physics step of this env step dropped (``Data``)
      episode_return () return of the current episode so far; at a done step, the finished
                    episode's total (reset on the next step)
      episode_length () steps of the current episode so far (same convention)
      params        dict field -> array of per-env randomised model parameters (may be empty)
      rng           (2,) uint32 key the env draws its next reset from
      task          dict name -> array of task variables that are not physics (a goal-seeking
                    env's target); empty for the standard suite
    """

    data: Data
    obs: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    final_obs: jax.Array
    metrics: dict
    episode_return: jax.Array
    episode_length: jax.Array
    params: dict
    rng: jax.Array
    task: dict = dataclasses.field(default_factory=dict)

    @property
    def done(self) -> jax.Array:
        """() bool: the last step ended an episode (terminated or truncated)."""
        return self.terminated | self.truncated


# Data fields by role (``physics.Data``'s docstring): the state a step starts from, and the
# kinematics, which an auto-reset always carries (cheap, and what viewers and users read).
STATE_FIELDS = ("qpos", "qvel", "ctrl", "act", "time", "qfrc_applied", "qacc_warmstart", "mocap_pos",
                 "mocap_quat", "eq_active", "diverged")  # fmt: skip
KINEMATICS = ("xpos", "xquat", "xmat", "xipos", "ximat", "xanchor", "xaxis", "geom_xpos", "geom_xmat",
               "site_xpos", "site_xmat")  # fmt: skip
