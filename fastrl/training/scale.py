"""Many agents in one program.

``train.num_seeds=N`` and ``train.vmap_sweep={learning_rate: [a, b]}`` train every combination
of swept values and seeds as independent agents inside ONE compiled program: the learner's
``init`` and ``update`` are ``vmap``-ed over a leading agent axis of the whole training state. A
swept hyperparameter enters the program as a traced per-agent value (the learner is built inside
the vmapped function with that leaf replaced by a tracer), so only leaves that the learner uses
arithmetically can be swept: float-typed algorithm options such as learning rates, entropy costs
or discounts. Options that decide shapes or program structure (batch sizes, schedules, switches)
are refused; sweep those with Hydra multirun (``-m``). Agent ``i`` uses the same RNG stream as a
single run with its seed, so it reproduces that run. How a batch (or a single run) is laid out
over several devices is ``fastrl.training.layout``'s to decide.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from typing import Any

import jax
import jax.numpy as jnp
from jax.sharding import Mesh

from fastrl import agents
from fastrl.agents.base import Learner
from fastrl.training.config import ConfigError, RunConfig

__all__ = ["AgentSpec", "batch_learner", "expand", "init_keys", "run_learner", "sweepable_fields"]


def sweepable_fields(algo_name: str) -> list[str]:
    """Algorithm options that can differ between agents of one program (float-typed leaves)."""
    cls = agents.config_class(algo_name)
    return [f.name for f in dataclasses.fields(cls) if str(f.type).replace(" ", "") == "float"]


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """One agent of a batch: its tag (folder name), seed and the config of the equivalent single run."""

    tag: str
    seed: int
    values: dict
    config: RunConfig


def expand(cfg: RunConfig) -> list[AgentSpec]:
    """The agents of a run: every combination of ``train.vmap_sweep`` values, times the seeds.

    Seeds are ``cfg.seed, cfg.seed + 1, ...``. Each agent's ``config`` is the single-run config
    it reproduces (its swept values set, ``num_seeds=1`` and no sweep), validated like any run's.
    """
    sweep = dict(cfg.train.vmap_sweep or {})
    allowed = sweepable_fields(cfg.algo_name)
    for name, values in sweep.items():
        if name not in allowed:
            raise ConfigError(
                f"train.vmap_sweep.{name}: only float options of algo={cfg.algo_name} can vary inside one "
                f"program ({', '.join(allowed)}); sweep {name} with Hydra multirun instead, e.g. "
                f"python -m fastrl.train -m algo.{name}=A,B"
            )
        if not isinstance(values, list | tuple) or not values:
            raise ConfigError(f"train.vmap_sweep.{name}={values!r} should be a non-empty list of numbers")
        if any(isinstance(v, bool) or not isinstance(v, int | float) for v in values):
            raise ConfigError(f"train.vmap_sweep.{name}={list(values)!r} should hold numbers only")
    names = list(sweep)
    specs = []
    for combo in itertools.product(*(sweep[n] for n in names)):
        values = {n: float(v) for n, v in zip(names, combo, strict=True)}
        try:
            algo = dataclasses.replace(cfg.algo, **values)
        except (ValueError, TypeError) as e:
            raise ConfigError(f"train.vmap_sweep {values}: {e}") from None
        for s in range(cfg.train.num_seeds):
            seed = cfg.seed + s
            train = dataclasses.replace(cfg.train, num_seeds=1, vmap_sweep=None)
            single = dataclasses.replace(cfg, algo=algo, seed=seed, train=train)
            label = "-".join(f"{n}={v:g}" for n, v in values.items())
            tag = f"{len(specs):03d}-seed{seed}" + (f"-{label}" if label else "")
            specs.append(AgentSpec(tag=tag, seed=seed, values=values, config=single))
    return specs


def _with_leaves(algo: Any, values: dict) -> Any:
    """A copy of the frozen config ``algo`` whose ``values`` may be tracers (validation was done
    on the host by ``expand``; ``__post_init__`` cannot compare tracers, so it is bypassed)."""
    out = copy.copy(algo)
    for name, value in values.items():
        object.__setattr__(out, name, value)
    return out


def batch_learner(cfg: RunConfig, specs: list[AgentSpec], env, total_updates: int) -> Learner:
    """The learner of ``cfg`` vmapped over ``specs``: state leaves gain a leading agent axis.

    ``init`` takes the (n_agents, 2) stacked keys of ``init_keys``; ``update`` maps the state
    to the next state and metrics with a leading agent axis on every metric.
    """
    names = list(cfg.train.vmap_sweep or {})
    hp = {n: jnp.asarray([s.values[n] for s in specs], jnp.float32) for n in names}
    base = agents.make_learner(cfg.algo_name, cfg.algo, env, cfg.network, total_updates)

    def learner_for(values):
        algo = _with_leaves(cfg.algo, values)
        return agents.make_learner(cfg.algo_name, algo, env, cfg.network, total_updates)

    def init(keys):
        return jax.vmap(lambda k, v: learner_for(v).init(k))(keys, hp)

    def update(states):
        try:
            return jax.vmap(lambda s, v: learner_for(v).update(s))(states, hp)
        except (jax.errors.ConcretizationTypeError, jax.errors.TracerBoolConversionError) as e:
            raise ConfigError(
                f"train.vmap_sweep {names}: algo={cfg.algo_name} uses one of these to decide the "
                "program's structure, so it cannot vary inside one program; sweep it with Hydra "
                f"multirun (-m) instead ({type(e).__name__})"
            ) from None

    return Learner(
        init=init,
        update=update,
        policy_params=jax.vmap(base.policy_params),
        act=base.act,
        env_steps_per_update=base.env_steps_per_update,
        num_envs=base.num_envs,
    )


def init_keys(specs: list[AgentSpec]) -> jax.Array:
    """(n_agents, 2) keys: agent ``i`` starts from ``PRNGKey(seed_i)`` like its single run."""
    return jnp.stack([jax.random.PRNGKey(s.seed) for s in specs])


def run_learner(
    cfg: RunConfig, specs: list[AgentSpec], env, total_updates: int, learner_mesh: Mesh | None
) -> tuple[Learner, jax.Array]:
    """The learner a run trains and the key its ``init`` takes.

    A batch of agents is ``batch_learner`` with ``init_keys``; a single run (a batch of one,
    whose state has no agent axis) is its agent's learner (a ``vmap_sweep`` of one value sets
    that value) with ``PRNGKey(seed)``, splitting its own work over ``learner_mesh`` when given
    (``fastrl.training.layout.learner_mesh``).
    """
    if len(specs) > 1:
        return batch_learner(cfg, specs, env, total_updates), init_keys(specs)
    (one,) = specs
    algo = one.config.algo
    learner = agents.make_learner(cfg.algo_name, algo, env, cfg.network, total_updates, mesh=learner_mesh)
    return learner, jax.random.PRNGKey(one.seed)
