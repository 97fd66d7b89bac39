"""A run's device layout, decided in one place.

A run uses every device its process has (``fastrl.runtime.devices.mesh``: GPUs, or CPU devices
made with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``). What this module decides is
how, from what the learner and the env declare (``Algorithm.splits_over_devices`` with its
config's ``splits_evenly``, ``Env.splits_over_devices``):

- ``learner_splits``: whether a single run's learner splits its own work over the devices (PPO:
  each device steps its slice of the envs and computes its share of every minibatch gradient,
  with ``shard_map``). XLA's automatic partitioning does not find that split: it ran PPO's
  minibatch gradients in full on every device, so 2 CPU devices were no faster than one.
- ``cpu_devices``: how many CPU devices the command line makes for a run, before JAX starts: as
  many as the learner splits evenly over, up to the cores, and one where it does not split.
- ``state_shardings``: the training state's layout over the devices: an agent batch that
  divides evenly is split by agent; otherwise each env state is split by environment and
  everything else replicated. XLA inserts the gradient all-reduce; the math is that of the
  one-device program up to summation order.
"""

from __future__ import annotations

from typing import Any

import jax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from fastrl import agents, envs
from fastrl.envs.episode import State
from fastrl.runtime.devices import DEVICE_AXIS
from fastrl.training import scale
from fastrl.training.config import RunConfig

__all__ = ["cpu_devices", "describe", "learner_mesh", "learner_splits", "state_shardings"]


def learner_splits(cfg: RunConfig, n_agents: int, devices: int) -> bool:
    """Whether the learner of ``cfg``, training ``n_agents`` agents, splits its own work over
    ``devices`` devices: only a single run's learner that can (``agents.splits_evenly``: its
    env batch and minibatch divide evenly over them). An agent batch is laid out by
    ``state_shardings`` alone."""
    return n_agents == 1 and devices > 1 and agents.splits_evenly(cfg.algo_name, cfg.algo, devices)


def learner_mesh(cfg: RunConfig, n_agents: int, m: Mesh | None) -> Mesh | None:
    """The mesh the learner splits its own work over (``learner_splits``), or None."""
    return m if m is not None and learner_splits(cfg, n_agents, m.devices.size) else None


def cpu_devices(cfg: RunConfig, cores: int) -> int:
    """How many XLA CPU devices to give a run on a host with ``cores`` cores.

    XLA:CPU runs one program's operations on a thread pool, but the physics step is thousands
    of small fused loops that keep only about 1.45 of 2 cores busy (the Ant's step at batch
    1024); split over 2 devices, each device's copy runs on its own core (2.07x one core). A
    learner that splits its own work (``learner_splits``) gets one device per core, as many as
    it splits evenly over; other learners, and agent batches, keep one device. Envs whose step
    runs slower split than on one device (``Env.splits_over_devices``: three of the robot
    tasks, measured in ``robot_throughput.md``) keep one device too.
    """
    if not envs.env_class(cfg.env.name).splits_over_devices:
        return 1
    n_agents = len(scale.expand(cfg))
    n = max(1, cores)
    while n > 1 and not learner_splits(cfg, n_agents, n):
        n -= 1
    return n


def state_shardings(state: Any, m: Mesh, n_agents: int, num_envs: int | None) -> Any:
    """Per-leaf ``NamedSharding`` of a training state on mesh ``m``.

    Agent batches that divide evenly over the devices split every leaf's leading (agent) axis.
    Otherwise the env batch is split: the leaves of the state's env states (each ``envs.State``
    in it, found by type) whose env axis (axis 0, or 1 after an agent axis) has ``num_envs``
    (``Learner.num_envs``) entries divisible by the device count. The rest is replicated.
    """
    ndev = m.devices.size
    replicated = NamedSharding(m, PartitionSpec())
    axis = 1 if n_agents > 1 else 0
    by_agent = n_agents > 1 and n_agents % ndev == 0
    by_env = NamedSharding(m, PartitionSpec(*([None] * axis), DEVICE_AXIS))
    envs_split = bool(num_envs) and num_envs % ndev == 0

    def one(x, env_leaf: bool):
        if x.size == 0:  # empty buffers (no sites, no contacts): nothing to split
            return replicated
        if by_agent:
            return NamedSharding(m, PartitionSpec(DEVICE_AXIS))
        if env_leaf and envs_split and x.ndim > axis and x.shape[axis] == num_envs:
            return by_env
        return replicated

    def node(x):
        if isinstance(x, State):
            return jax.tree.map(lambda leaf: one(leaf, True), x)
        return one(x, False)

    return jax.tree.map(node, state, is_leaf=lambda x: isinstance(x, State))


def describe(shardings: Any, m: Mesh | None) -> str:
    """One line for the run's banner: devices and how many state leaves are split."""
    if m is None:
        return f"1 device ({jax.devices()[0].platform})"
    leaves = jax.tree.leaves(shardings)
    split = sum(1 for s in leaves if any(p is not None for p in s.spec))
    return f"{m.devices.size} {jax.devices()[0].platform} devices, {split}/{len(leaves)} state leaves split"
