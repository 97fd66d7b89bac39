"""Device meshes: the one home of fastrl's helpers for splitting work over several devices.

Every split in fastrl is over one mesh axis, ``DEVICE_AXIS``, spanning all devices (GPUs, or CPU
devices made with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``). Envs use it to step a
batch on every device (``over_devices``), learners to split their minibatch gradients, and the
training runner to lay out the training state (``fastrl.training.layout``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, PartitionSpec

DEVICE_AXIS = "devices"


def mesh() -> Mesh | None:
    """A one-axis mesh (axis ``DEVICE_AXIS``) over all devices, or None with a single device."""
    devices = jax.devices()
    return Mesh(np.array(devices), (DEVICE_AXIS,)) if len(devices) > 1 else None


def batch_mesh(batch: int) -> Mesh | None:
    """A one-axis mesh (``DEVICE_AXIS``) over all devices when there are several and they divide
    ``batch`` evenly; else None."""
    m = mesh()
    return None if m is None or batch % m.devices.size else m


def over_devices(fn: Callable, mesh: Mesh | None) -> Callable:
    """``fn`` with every argument's and result's leading (batch) axis split over ``mesh``'s devices.

    Each device runs ``fn`` on its slice (``shard_map``), so a per-environment function such as
    a vmapped ``env.step`` runs on all devices at once with no communication. With ``mesh=None``
    this is ``fn`` itself.
    """
    if mesh is None:
        return fn
    split = PartitionSpec(DEVICE_AXIS)
    return jax.shard_map(fn, mesh=mesh, in_specs=split, out_specs=split, check_vma=False)


def to_host(tree: Any) -> Any:
    """``tree`` as numpy arrays; with several processes, each array gathered from all of them."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    return multihost_utils.process_allgather(tree, tiled=True)


def agreed(value: int) -> int:
    """Process 0's ``value`` in every process (``value`` itself with one process): host-side
    decisions that every process must take alike, such as how many updates the next chunk runs
    or whether to save now, are taken by process 0."""
    if jax.process_count() == 1:
        return value
    return int(multihost_utils.broadcast_one_to_all(np.int32(value)))


def any_process(flag: bool) -> bool:
    """Whether ``flag`` is set in any process (``flag`` itself with one process)."""
    if jax.process_count() == 1:
        return flag
    return bool(np.any(multihost_utils.process_allgather(np.int32(flag))))
