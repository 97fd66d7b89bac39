"""Checkpoints of the whole training state with orbax, plus the resolved config.

A checkpoint is the learner's state pytree (params, optimiser state, normaliser, env states,
RNG, counters: everything ``update`` reads) and a JSON ``meta`` item holding the resolved
config and the runner's position, so a resumed run is the same run. Orbax writes each step to
a temporary folder and renames it when complete, so an interrupted save never replaces the
last good checkpoint; restoring checks the config first and names every difference.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from fastrl.config import identity_diff


def _pack(tree: Any) -> dict[str, Any]:
    """The non-empty leaves by key path (orbax cannot store zero-size arrays, e.g. the contact
    buffers of a model without contacts)."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return {jax.tree_util.keystr(path): x for path, x in leaves if x.size}


def _unpack(packed: dict[str, Any], like: Any) -> Any:
    leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
    out = [
        packed[jax.tree_util.keystr(path)] if x.size else jnp.zeros(x.shape, x.dtype) for path, x in leaves
    ]
    return jax.tree_util.tree_unflatten(treedef, out)


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be restored into this run; the message says why."""


class Checkpointer:
    """Saves and restores ``(state, meta)`` under ``directory`` (one sub-folder per chunk)."""

    def __init__(self, directory: str | Path, keep: int = 3):
        self.directory = Path(directory).absolute()
        options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
        self._manager = ocp.CheckpointManager(self.directory, options=options)

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state: Any, meta: dict) -> None:
        """Saves and waits until the checkpoint is complete on disk."""
        args = ocp.args.Composite(state=ocp.args.StandardSave(_pack(state)), meta=ocp.args.JsonSave(meta))
        self._manager.save(step, args=args, force=True)
        self._manager.wait_until_finished()

    def read_meta(self, step: int | None = None) -> tuple[int, dict]:
        step = self._require_step(step)
        try:
            out = self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        except Exception as e:  # orbax raises many types for unreadable files
            raise CheckpointError(f"checkpoint {self.directory / str(step)} is unreadable: {e}") from e
        return step, dict(out["meta"])

    def restore(self, abstract_state: Any, config: dict, step: int | None = None) -> tuple[Any, dict]:
        """Restores the state saved at ``step`` (default: latest) for a run configured as ``config``.

        Raises:
          CheckpointError: no checkpoint, an incompatible config (listing each differing key),
            mismatched array shapes, or unreadable/corrupt files.
        """
        step, meta = self.read_meta(step)
        diffs = identity_diff(meta.get("config", {}), config)
        if diffs:
            raise CheckpointError(
                f"checkpoint {self.directory / str(step)} was made with a different configuration; "
                "resume with the same env/algo/network/seed settings, or start a new run. Differences "
                "(saved -> now):\n  " + "\n  ".join(diffs)
            )
        target = jax.tree.map(ocp.utils.to_shape_dtype_struct, _pack(abstract_state))
        try:
            out = self._manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(target)))
        except Exception as e:
            raise CheckpointError(
                f"checkpoint {self.directory / str(step)} could not be restored (corrupt or from an "
                f"incompatible fastrl version): {type(e).__name__}: {e}"
            ) from e
        return _unpack(out["state"], abstract_state), meta

    def _require_step(self, step: int | None) -> int:
        if step is None:
            step = self._manager.latest_step()
        if step is None:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        return step

    def close(self) -> None:
        self._manager.close()
