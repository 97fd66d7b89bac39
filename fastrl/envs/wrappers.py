"""What a step does around its task, as wrappers: each takes a step ``(state, action) -> state``
and returns another. ``Env.step`` is ``Env.task_step`` (the physics, the task's reward and its
observation) under the divergence guard, the episode count and the auto-reset, in that order;
each is a short pure function, traced into the one step program, and branch-free.

    step = auto_reset(count_episodes(guard_divergence(env.task_step, True), 1000), env.reset, carried)

Domain randomisation is ``envs.randomization`` (drawn at reset, applied inside ``task_step``);
a task's training aids belong to the task, and ``Env.for_evaluation`` leaves them out.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from fastrl.envs.episode import State

Step = Callable[[State, jax.Array], State]

# Metrics the physics reports about itself (what the contact budgets dropped): a diverged step
# keeps them, since they may be why it diverged; the task's own metrics read 0 there.
PHYSICS_METRICS = ("contact_overflow",)


def guard_divergence(step: Step, terminate_when_unhealthy: bool) -> Step:
    """A diverged env (the physics says so, or its observation or reward is not finite) is ended,
    its observation, reward and task metrics zeroed, so its NaNs never reach a learner. Where
    ``terminate_when_unhealthy`` is False the task's own termination rule is dropped, and only a
    divergence ends an episode early. Adds the metric ``diverged`` (0 or 1)."""

    def guarded(state: State, action: jax.Array) -> State:
        s = step(state, action)
        diverged = s.data.diverged | ~jnp.all(jnp.isfinite(s.obs)) | ~jnp.isfinite(s.reward)
        obs = jnp.where(diverged, 0.0, s.obs)
        zeroed = lambda k, v: v if k in PHYSICS_METRICS else jnp.where(diverged, 0.0, v)  # noqa: E731
        metrics = {k: zeroed(k, v) for k, v in s.metrics.items()}
        metrics["diverged"] = diverged.astype(obs.dtype)
        return s.replace(
            obs=obs, final_obs=obs, reward=jnp.where(diverged, 0.0, s.reward).astype(obs.dtype),
            terminated=(s.terminated & terminate_when_unhealthy) | diverged, metrics=metrics,
        )  # fmt: skip

    return guarded


def count_episodes(step: Step, episode_length: int) -> Step:
    """The episode's length and return after each step, counted afresh after a done step, and
    ``truncated`` where the length reaches the time limit ``episode_length``."""

    def counted(state: State, action: jax.Array) -> State:
        s = step(state, action)
        prev_done = state.done
        length = jnp.where(prev_done, 0, state.episode_length) + 1
        ret = jnp.where(prev_done, 0.0, state.episode_return) + s.reward
        return s.replace(episode_length=length, episode_return=ret, truncated=length >= episode_length)

    return counted


def auto_reset(step: Step, reset: Callable[[jax.Array], State], carried: tuple[str, ...]) -> Step:
    """Auto-reset, branch-free: where a step ends its episode, a new episode ``reset(key)``, drawn
    from the state's own key, takes its place: its observation, parameters, key, task and the
    ``Data`` fields ``carried`` names (the other derived fields keep the finished episode's
    values until the next step recomputes them). ``final_obs`` keeps the finished episode's
    last observation. Elsewhere the key moves on."""

    def resetting(state: State, action: jax.Array) -> State:
        stepped = step(state, action)
        fresh, done = reset(state.rng), stepped.done
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

    return resetting
