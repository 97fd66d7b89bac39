"""Device meshes: the one home of fastrl's helpers for splitting work over several devices.

Every split in fastrl is over one mesh axis, ``DEVICE_AXIS``, spanning all devices (GPUs, or CPU
devices made with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``). Envs use it to step a
batch on every device (``over_devices``), learners to split their minibatch gradients, and the
training runner to lay out the training state (``fastrl.training.scale``).
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
