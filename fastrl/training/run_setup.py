"""What a run is, decided before anything is traced: its env, its agents (a single run is a
batch of one), its learner, built once for the run's total updates, and its state's layout."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from fastrl import agents
from fastrl.agents.base import Learner
from fastrl.runtime import devices
from fastrl.runtime.devices import to_host
from fastrl.training import layout, scale
from fastrl.training.config import RunConfig


@dataclasses.dataclass(frozen=True)
class Agents:
    """The run's agents as the host sees them. A single run is a batch of one: only its state's
    layout differs (a batch's leaves have a leading agent axis), and these methods hide that."""

    specs: list[scale.AgentSpec]

    @property
    def n(self) -> int:
        return len(self.specs)

    @property
    def batched(self) -> bool:
        return self.n > 1

    def who(self, i: int) -> str:
        """How messages name agent ``i`` (nothing for a single run)."""
        return f"agent {self.specs[i].tag} " if self.batched else ""

    def rows(self, sums: dict, n: int) -> list[dict[str, float]]:
        """Per agent, the chunk's scalars from the update metrics summed over its ``n`` updates
        (each leaf with a leading agent axis in a batch)."""
        sums = to_host(sums)
        if not self.batched:
            return [reduce_sums(sums, n)]
        return [reduce_sums(jax.tree.map(lambda x, i=i: x[i], sums), n) for i in range(self.n)]

    def eval_key(self, chunk: int) -> jax.Array:
        """The key of the evaluation after ``chunk``: per agent, from its own seed."""
        keys = [jax.random.fold_in(jax.random.PRNGKey(s.seed + 1), chunk) for s in self.specs]
        return jnp.stack(keys) if self.batched else keys[0]

    def env_steps(self, state, agent: int | None = None) -> int:
        """Env steps so far: of one agent, or the most of any agent."""
        steps = np.asarray(to_host(state.env_steps))
        return int(steps.reshape(-1)[agent] if agent is not None else steps.max())

    def result(self, per_agent: list) -> Any:
        """A per-agent list as the summary reports it: the list for a batch, the value for one agent."""
        return per_agent if self.batched else per_agent[0]


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a run is, decided before anything is traced: its env, agents, learner and layout."""

    cfg: RunConfig
    config: dict  # cfg.to_dict(), saved with every checkpoint
    env: Any
    agents: Agents
    learner: Learner
    init_key: jax.Array
    steps_per_update: int
    total_updates: int
    mesh: Mesh | None
    shardings: Any  # per-leaf NamedSharding of the state, or None on one device
    abstract: Any  # the state's shapes, dtypes and layout (ShapeDtypeStructs), known before it exists

    @property
    def total_steps(self) -> int:
        """Env steps of the whole run (per agent)."""
        return self.total_updates * self.steps_per_update

    @property
    def fixed_chunks(self) -> int | None:
        """The run's chunk count when ``train.updates_per_chunk`` fixes it (None: sized by time)."""
        k = self.cfg.train.updates_per_chunk
        return None if k is None else self.total_updates // k


def make_setup(cfg: RunConfig) -> Setup:
    """The run's env, agents, learner (built once, for the run's total updates, which follow
    from its env steps per update) and the state's layout over the devices (``layout``)."""
    env = cfg.env.make()
    specs = scale.expand(cfg)
    steps_per_update = agents.env_steps_per_update(cfg.algo_name, cfg.algo, env)
    total_updates = max(1, math.ceil(cfg.train.total_env_steps / steps_per_update))
    if (k := cfg.train.updates_per_chunk) is not None:  # fixed chunks: the budget in whole chunks
        total_updates = math.ceil(total_updates / k) * k
    mesh = devices.mesh()
    learner_mesh = layout.learner_mesh(cfg, len(specs), mesh)
    learner, init_key = scale.run_learner(cfg, specs, env, total_updates, learner_mesh)
    shardings, abstract = None, jax.eval_shape(learner.init, init_key)
    if mesh is not None:
        shardings = layout.state_shardings(abstract, mesh, len(specs), learner.num_envs)
        laid_out = lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s)  # noqa: E731
        abstract = jax.tree.map(laid_out, abstract, shardings)
    return Setup(cfg=cfg, config=cfg.to_dict(), env=env, agents=Agents(specs), learner=learner,
                  init_key=init_key, steps_per_update=steps_per_update, total_updates=total_updates,
                  mesh=mesh, shardings=shardings, abstract=abstract)  # fmt: skip


def reduce_sums(sums: dict, n: int) -> dict[str, float]:
    """Per-chunk scalars from the update metrics summed over the chunk's ``n`` updates: episode
    counts and returns add up, every other metric is its mean over the updates (and over any
    axes of its own)."""
    m = {k: np.asarray(v) for k, v in sums.items()}
    out = {}
    episodes = float(m.pop("train/episodes").sum())
    ret_sum = float(m.pop("train/episode_return_sum").sum())
    out["train/episodes"] = episodes
    if episodes > 0:
        out["train/episode_return"] = ret_sum / episodes
    for k, v in m.items():
        out[k] = float(np.mean(v)) / n
    return out
