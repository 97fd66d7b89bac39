"""The run's start: its folder locked and claimed, its checkpoints opened, and the state it
starts from, fresh or restored, in fresh buffers laid out for the mesh."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

from fastrl.training import files
from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer, CheckpointError
from fastrl.training.config import RunConfig
from fastrl.training.files import RunDirError
from fastrl.training.progress import Progress
from fastrl.training.run_setup import Setup

try:
    import fcntl
except ImportError:  # Windows: runs take no lock on their folder
    fcntl = None


def open_checkpoints(cfg: RunConfig, run_dir: Path, resume: bool) -> Checkpointer:
    """The run's checkpointer; a new run refuses a folder that holds another run's checkpoints."""
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR, keep=cfg.checkpoint.keep, tidy=True)
    if not resume and ckpt.latest_step() is not None:
        ckpt.close()
        raise CheckpointError(
            f"{run_dir} already holds checkpoints of a run; continue it with resume={run_dir}, or "
            "choose a new run dir (nothing was changed)"
        )
    return ckpt


def start_state(setup: Setup, ckpt: Checkpointer, run_dir: Path, resume: bool, resume_step: int | None,
           weights: dict | None = None):  # fmt: skip
    """The state and progress the run starts from: fresh (with ``weights``, the learned fields
    of ``init_from``, in place of the initial ones), or restored from a checkpoint (newer
    checkpoints than the one resumed are set aside)."""
    init = setup.learner.init
    jit_init = jax.jit(init) if setup.shardings is None else jax.jit(init, out_shardings=setup.shardings)
    state = jit_init(setup.init_key)
    if not resume:
        if weights:  # laid out as the fresh leaves (a run on several devices shards its state)
            place = lambda new, old: jax.device_put(new, old.sharding)  # noqa: E731
            state = dataclasses.replace(
                state, **{k: jax.tree.map(place, v, getattr(state, k)) for k, v in weights.items()}
            )
        return state, Progress.fresh(setup.agents.n)
    state, meta = ckpt.restore_newest(lambda step: ckpt.restore(state, setup.config, step), resume_step)
    progress = Progress.from_meta(meta, setup.agents.n)
    set_aside_after(ckpt, run_dir, progress.chunk)
    print(f"[fastrl] resumed {run_dir} at chunk {progress.chunk} ({int(meta['env_steps']):,d} env steps)")
    return state, progress


def claim_folder(run_dir: Path, config: dict, record: dict[str, str]) -> None:
    """Writes the run's config and the command line's record: the run is valid and owns its folder."""
    files.write_text(run_dir / "config.json", json.dumps(config, indent=2))
    for name, text in record.items():
        (run_dir / name).parent.mkdir(parents=True, exist_ok=True)
        files.write_text(run_dir / name, text)


def place_state(setup: Setup, state):
    """The state in fresh buffers (donation fails when two leaves share one), laid out for the mesh,
    by one jitted copy of the whole tree (a copy per leaf would compile a program per shape)."""
    fresh = lambda s: jax.tree.map(lambda x: jnp.array(x, copy=True), s)  # noqa: E731
    return jax.jit(fresh, out_shardings=setup.shardings)(state)


def set_aside_after(ckpt: Checkpointer, run_dir: Path, step: int) -> None:
    """Moves the checkpoints newer than ``step`` (unreadable ones, or a branch the user resumed
    from before) and a copy of ``metrics.csv`` out of the way, into
    ``run_dir/checkpoints_set_aside/<time>/``: the resumed run will save those step numbers
    again, and nothing a user saved is deleted."""
    aside = ckpt.set_aside_after(step, run_dir / "checkpoints_set_aside")
    if aside is None:
        return
    if (run_dir / "metrics.csv").exists():
        shutil.copy2(run_dir / "metrics.csv", aside / "metrics.csv")
    print(f"[fastrl] checkpoints after chunk {step} moved to {aside}", file=sys.stderr)


class RunDirLock:
    """Exclusive use of a run folder while a run writes into it.

    An ``flock`` on ``RUN_DIR/.lock``, which the OS releases when the process ends, however it
    ends, so a crashed run never leaves the folder locked. A second run started on the same
    folder (two runs in the same second, or a resume while the run is still going) fails at
    once, before writing anything. Only process 0 of a multi-host run takes it (the others
    share the folder), and where ``fcntl`` does not exist (Windows) no lock is taken.
    """

    def __init__(self, run_dir: Path):
        self.path = run_dir / ".lock"
        self._file = None

    def __enter__(self):
        if fcntl is None or jax.process_index() != 0:
            return self
        f = files.open_lock(self.path)  # never through a link: ``.lock -> file`` would truncate it
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.seek(0)
            owner = f.read().strip() or "another process"
            f.close()
            raise RunDirError(
                f"{self.path.parent} is in use by another fastrl run ({owner}); wait for it to end or "
                "choose another run dir (nothing was changed)"
            ) from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
        f.flush()
        self._file = f
        return self

    def __exit__(self, *exc):
        if self._file is not None:
            self._file.close()  # closing releases the flock
            self._file = None
