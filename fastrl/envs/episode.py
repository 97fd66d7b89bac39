"""An env's ``State``, and what a step does around its task: the divergence guard, the episode's
bookkeeping and metrics, and the branch-free auto-reset. ``Env.step`` composes them around the
physics and the task's reward and observation; each is a short pure function, traced into the
step."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

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


def guard_divergence(
    after: Data, obs: jax.Array, reward: jax.Array, terminated: jax.Array, terminate_when_unhealthy: bool
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """A diverged env (the physics says so, or its observation or reward is not finite) is ended
    and reset; its NaNs never reach the learner.

    Returns:
      obs (obs_size,) and reward () zeroed where diverged, terminated () (the task's rule where
      ``terminate_when_unhealthy``, or divergence) and diverged (), bools.
    """
    diverged = after.diverged | ~jnp.all(jnp.isfinite(obs)) | ~jnp.isfinite(reward)
    obs = jnp.where(diverged, 0.0, obs)
    reward = jnp.where(diverged, 0.0, reward).astype(obs.dtype)
    terminated = (terminated & terminate_when_unhealthy) | diverged
    return obs, reward, terminated, diverged


def count(state: State, reward: jax.Array, episode_length: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The episode's length and return after this step (a new count after a done step), and
    whether this step reaches the time limit ``episode_length`` (truncated), each ()."""
    prev_done = state.done
    length = jnp.where(prev_done, 0, state.episode_length) + 1
    ret = jnp.where(prev_done, 0.0, state.episode_return) + reward
    truncated = length >= episode_length
    return length, ret, truncated


def metrics(terms: dict, extra: dict, diverged: jax.Array, overflow: jax.Array | None, dtype) -> dict:
    """The step's ``State.metrics``: each reward term as ``reward_<term>`` and the task's extra
    quantities (zero where diverged), ``diverged``, and with ``overflow`` (each physics step's
    dropped contacts, None for a scene whose budgets cannot drop any) ``contact_overflow``, the
    most of them; all () of ``dtype``."""
    out = {f"reward_{k}": jnp.where(diverged, 0.0, v) for k, v in terms.items()}
    out.update({k: jnp.where(diverged, 0.0, v) for k, v in extra.items()})
    out["diverged"] = diverged.astype(dtype)
    if overflow is not None:
        out["contact_overflow"] = jnp.max(overflow)
    return {k: jnp.asarray(v, dtype) for k, v in out.items()}


def auto_reset(done: jax.Array, stepped: State, fresh: State, carried: tuple[str, ...]) -> State:
    """Auto-reset, branch-free: where ``done`` (``stepped.done``), the new episode ``fresh``
    (drawn from ``stepped``'s key) takes the place of ``stepped``'s: its observation, parameters,
    key, task and the ``Data`` fields ``carried`` names; ``final_obs`` keeps the finished
    episode's. Elsewhere the key moves on."""
    pick = lambda new, old: jnp.where(done, new, old)  # noqa: E731
    after = stepped.data
    data = after.replace(**{f: pick(getattr(fresh.data, f), getattr(after, f)) for f in carried})
    return stepped.replace(
        data=data,
        obs=pick(fresh.obs, stepped.obs),
        params=jax.tree.map(pick, fresh.params, stepped.params),
        rng=jnp.where(done, fresh.rng, jax.random.fold_in(stepped.rng, 1)),
        task=jax.tree.map(pick, fresh.task, stepped.task),
    )


# Data fields by role (``physics.Data``'s docstring): the state a step starts from, and the
# kinematics, which an auto-reset always carries (cheap, and what viewers and users read).
STATE_FIELDS = ("qpos", "qvel", "ctrl", "act", "time", "qfrc_applied", "qacc_warmstart", "mocap_pos",
                 "mocap_quat", "eq_active", "diverged")  # fmt: skip
KINEMATICS = ("xpos", "xquat", "xmat", "xipos", "ximat", "xanchor", "xaxis", "geom_xpos", "geom_xmat",
               "site_xpos", "site_xmat")  # fmt: skip


def fields_read(fn, data) -> tuple[str, ...]:
    """The fields of ``data`` (abstract ``Data``) that ``fn(data)`` reads, from its traced
    program: a field counts as read if any operation or output takes it (so a field passed
    into a nested loop counts, whether or not the loop uses it)."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(data)
    jaxpr = jax.make_jaxpr(lambda *leaves: fn(jax.tree.unflatten(treedef, leaves)))(
        *(x for _, x in paths)
    ).jaxpr
    used = {id(v) for eqn in jaxpr.eqns for v in eqn.invars} | {id(v) for v in jaxpr.outvars}
    return tuple(path[0].name for (path, _), var in zip(paths, jaxpr.invars, strict=True) if id(var) in used)
