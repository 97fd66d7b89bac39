"""Checkpoints of the whole training state with orbax, plus the resolved config.

A checkpoint is the learner's state pytree (params, optimiser state, normaliser, env states,
RNG, counters: everything ``update`` reads) and a JSON ``meta`` item holding the resolved
config and the runner's position, so a resumed run is the same run. Orbax writes each step to
a temporary folder and renames it when complete, so an interrupted save never replaces the
last good checkpoint; restoring checks the config first and names every difference. A
checkpoint is read only in the layout this fastrl saves: one of an earlier layout (metadata,
config or state leaves that this version does not write) is refused, naming what differs.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from fastrl.training.config import identity_diff, missing_identity_keys
from fastrl.training.files import WriteError

__all__ = [
    "CHECKPOINT_DIR",
    "CheckpointError",
    "Checkpointer",
    "ConfigMismatch",
    "EarlierLayout",
    "UnreadableCheckpoint",
    "quiet_library_logs",
]

T = TypeVar("T")
# The folder of a run directory that holds its checkpoints (one sub-folder per saved chunk).
CHECKPOINT_DIR = "checkpoints"
# Orbax logs every save step at INFO, JAX its backend probing: the command line quiets them.
_QUIET_LOGGERS = ("absl", "jax._src.xla_bridge")
# A failed checkpoint write fails many of orbax's asyncio futures at once, each logged with the
# whole tensorstore spec; the save's own error says what happened, in one line.
_SILENT_LOGGERS = ("asyncio",)


def quiet_library_logs() -> None:
    """Raises orbax's and JAX's backend loggers to WARNING, so a run's output stays readable.
    Called when a run or the evaluation command starts, never at import."""
    for name in _QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    for name in _SILENT_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _pack(tree: Any) -> dict[str, Any]:
    """The non-empty leaves by key path (orbax cannot store zero-size arrays, e.g. the contact
    buffers of a model without contacts)."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return {jax.tree_util.keystr(path): x for path, x in leaves if x.size}


def _unpack(packed: dict[str, Any], like: Any) -> Any:
    """``like``'s tree from the packed leaves; a zero-size leaf (never saved) is zeros."""
    leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
    out = []
    for path, x in leaves:
        key = jax.tree_util.keystr(path)
        out.append(packed[key] if x.size else jnp.zeros(x.shape, x.dtype))
    return jax.tree_util.tree_unflatten(treedef, out)


def _check_leaves(target: dict[str, Any], saved: dict[str, Any] | None, where: Path) -> None:
    """Refuses a checkpoint whose state leaves (``saved``: key -> metadata; None when unknown,
    and the restore then says what is wrong) are not those this fastrl's learner makes."""
    if saved is None:
        return
    other = [k for k in target if k not in saved] + [k for k in saved if k not in target]
    if other:
        raise EarlierLayout(
            f"checkpoint {where} holds other state leaves than this fastrl's learner makes, "
            f"{', '.join(other[:6])}{' ...' if len(other) > 6 else ''}: {EarlierLayout.hint}"
        )


def _target(abstract: Any) -> dict[str, jax.ShapeDtypeStruct]:
    """What to restore each packed leaf as: its shape, dtype and a sharding on THIS process's
    devices. A leaf that carries a sharding (a live state laid out for this run's mesh) keeps
    it; an abstract leaf (``jax.eval_shape``) goes to the first local device. Without a target
    sharding orbax re-creates the saving run's layout, which fails on another device count."""
    default = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])

    def one(x):
        sharding = getattr(x, "sharding", None) or default
        return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)

    return jax.tree.map(one, _pack(abstract))


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be restored into this run; the message says why."""


class ConfigMismatch(CheckpointError):
    """The checkpoint belongs to a run with other identity settings (env, algo, network, seed)."""


class UnreadableCheckpoint(CheckpointError):
    """The checkpoint's files cannot be read back (corrupt, truncated, or partly deleted)."""


class EarlierLayout(CheckpointError):
    """The checkpoint was saved in a layout this fastrl does not read (an earlier version's)."""

    hint = (
        "it was saved in an earlier layout, which this fastrl does not read; start a new run, or "
        "use the fastrl version that saved it"
    )


class Checkpointer:
    """Saves and restores ``(state, meta)`` under ``directory`` (one sub-folder per chunk)."""

    def __init__(self, directory: str | Path, keep: int = 3, tidy: bool = False):
        """``tidy``: remove the partial ``N.orbax-checkpoint-tmp`` folders of saves cut off by a
        kill (only the run that owns the folder does; loading and evaluating change nothing)."""
        self.directory = Path(directory).absolute()
        options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True, cleanup_tmp_directories=tidy)
        self._manager = ocp.CheckpointManager(self.directory, options=options)
        self._failed = False
        self._held = contextlib.ExitStack()  # a failed save's stderr filter, undone at close

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state: Any, meta: dict) -> None:
        """Saves and waits until the checkpoint is complete on disk.

        Raises:
          WriteError: the save failed (a full disk, a read-only folder): the message names the
            folder, the cause and the newest complete checkpoint, which is left as it was; the
            failed save's partial folder is removed.
        """
        args = ocp.args.Composite(state=ocp.args.StandardSave(_pack(state)), meta=ocp.args.JsonSave(meta))
        absl = logging.getLogger("absl")
        level = absl.level
        absl.setLevel(logging.CRITICAL)  # orbax logs each failing writer thread's traceback
        try:
            with contextlib.ExitStack() as capture:  # a failed save's pending writes print one each
                capture.enter_context(_without_closed_loop_noise())
                try:
                    self._manager.save(step, args=args, force=True)
                    self._manager.wait_until_finished()
                except Exception:
                    # The failed save's writers still in flight fail one by one until orbax is
                    # closed, each printing an "Event loop is closed" traceback: the capture goes
                    # on, with no gap, until ``close``.
                    self._held.enter_context(capture.pop_all())
                    raise
        except Exception as e:
            self._failed = True
            with contextlib.suppress(Exception):
                self._manager.wait_until_finished()
            for partial in self.directory.glob(f"{step}.orbax-checkpoint-tmp*"):
                shutil.rmtree(partial, ignore_errors=True)
            raise WriteError(
                f"could not save checkpoint {self.directory / str(step)}: {_cause(e)}; {self.last_good()}"
            ) from None
        finally:
            absl.setLevel(level)

    def last_good(self) -> str:
        """Names the newest complete checkpoint folder, for messages about a failed write."""
        steps = sorted(s for s in (_step_of(p) for p in self.directory.iterdir()) if s is not None)
        if not steps:
            return "no earlier checkpoint of this run was saved"
        return f"the last good checkpoint is {self.directory / str(steps[-1])}"

    def steps(self) -> list[int]:
        """The saved steps, newest first."""
        return sorted(self._manager.all_steps(), reverse=True)

    def read_meta(self, step: int | None = None) -> tuple[int, dict]:
        step = self._require_step(step)
        try:
            out = self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        except Exception as e:  # orbax raises many types for unreadable files
            raise UnreadableCheckpoint(
                f"checkpoint {self.directory / str(step)} is unreadable: {_first_line(e)}"
            ) from None
        meta = out["meta"]
        problem = _meta_problem(meta)
        if problem:
            raise UnreadableCheckpoint(
                f"checkpoint {self.directory / str(step)} has damaged metadata: {problem}"
            )
        missing = [k for k in _META_KEYS if k not in meta] + missing_identity_keys(meta["config"])
        if missing:
            raise EarlierLayout(
                f"checkpoint {self.directory / str(step)} lacks {', '.join(missing)}: {EarlierLayout.hint}"
            )
        return step, dict(meta)

    def restore_newest(self, attempt: Callable[[int], T], step: int | None = None) -> T:
        """``attempt(step)`` for ``step``, or (``step=None``) for the newest checkpoint it succeeds
        on: an unreadable newest checkpoint (a crash mid-write outside orbax's atomic rename, a
        disk error, a deleted file) falls back to the one before it, saying so on stderr, so
        one bad file never blocks a resume or an evaluation. A configuration mismatch is not
        a reason to fall back: it is raised at once.
        """
        with _without_closed_loop_noise():
            return self._restore_newest(attempt, step)

    def _restore_newest(self, attempt: Callable[[int], T], step: int | None) -> T:
        if step is not None:
            return attempt(step)
        steps = self.steps()
        if not steps:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        errors = []
        for s in steps:
            try:
                out = attempt(s)
            except UnreadableCheckpoint as e:
                errors.append(str(e))
                continue
            if errors:
                print(
                    f"[fastrl] warning: {len(errors)} newer checkpoint(s) could not be read, using step "
                    f"{s} instead:\n  " + "\n  ".join(errors),
                    file=sys.stderr,
                )
            return out
        raise UnreadableCheckpoint(
            f"no checkpoint in {self.directory} can be read:\n  " + "\n  ".join(errors)
        )

    def restore(self, abstract_state: Any, config: dict, step: int | None = None) -> tuple[Any, dict]:
        """Restores the state saved at ``step`` (default: latest) for a run configured as ``config``.

        Raises:
          CheckpointError: no checkpoint, an incompatible config (listing each differing key),
            mismatched array shapes, or unreadable/corrupt files.
        """
        step, meta = self.read_meta(step)
        diffs = identity_diff(meta.get("config", {}), config)
        if diffs:
            raise ConfigMismatch(
                f"checkpoint {self.directory / str(step)} was made with a different configuration; "
                "resume with the same env/algo/network/seed settings, or start a new run. Differences "
                "(saved -> now):\n  " + "\n  ".join(diffs)
            )
        target = _target(abstract_state)
        _check_leaves(target, self._saved_leaves(step), self.directory / str(step))
        try:
            out = self._manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(target)))
        except Exception as e:
            raise UnreadableCheckpoint(
                f"checkpoint {self.directory / str(step)} could not be restored (damaged files, or "
                f"saved by an incompatible fastrl version): {type(e).__name__}: {_first_line(e)}"
            ) from None
        return _unpack(out["state"], abstract_state), meta

    def _saved_leaves(self, step: int) -> dict[str, Any] | None:
        """The state leaves saved at ``step`` (key -> orbax's array metadata), or None when the
        metadata cannot be read (the restore then reports what is wrong)."""
        absl = logging.getLogger("absl")
        level = absl.level
        absl.setLevel(logging.ERROR)  # orbax warns that the item has no step metadata of its own
        try:
            tree = ocp.StandardCheckpointer().metadata(self.directory / str(step) / "state").item_metadata
            return dict(tree)
        except Exception:
            return None
        finally:
            absl.setLevel(level)

    def _require_step(self, step: int | None) -> int:
        if step is None:
            step = self._manager.latest_step()
        if step is None:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        if step not in self._manager.all_steps():
            raise CheckpointError(f"no checkpoint of step {step} in {self.directory}; saved: {self.steps()}")
        return step

    def set_aside_after(self, step: int, aside_root: Path) -> Path | None:
        """Moves every saved step newer than ``step`` into a new ``aside_root/<time>/`` folder
        (returned; None when there was none), so a run resumed from ``step`` can save those step
        numbers again without deleting anything."""
        newer = [s for s in self.steps() if s > step]
        if not newer:
            return None
        aside = aside_root / time.strftime("%Y-%m-%d_%H-%M-%S")
        n = 1
        while aside.exists():
            aside, n = aside_root / f"{time.strftime('%Y-%m-%d_%H-%M-%S')}-{n}", n + 1
        aside.mkdir(parents=True)
        for s in newer:
            shutil.move(str(self.directory / str(s)), str(aside / str(s)))
        self._manager.reload()
        return aside

    def close(self) -> None:
        """Ends orbax's background work; after a failed save (already reported) its error is not
        raised a second time."""
        with self._held:
            try:
                self._manager.close()
            except Exception:
                if not self._failed:
                    raise


@contextlib.contextmanager
def _without_closed_loop_noise():
    """Holds back "RuntimeError: Event loop is closed" tracebacks while checkpoints are read.

    After a failed restore, tensorstore completes the read's other pending futures on its own
    threads and calls back into orbax's already-closed asyncio loop; each callback prints such a
    traceback straight to the process's stderr, burying the one message that matters. The
    stderr file descriptor is captured for the duration and written back without them.
    """
    try:
        fd = sys.__stderr__.fileno()
    except (AttributeError, OSError, ValueError):  # no real stderr (embedded interpreters)
        yield
        return
    sys.__stderr__.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            sys.__stderr__.flush()
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            kept = _drop_loop_closed(tmp.read().decode(errors="replace"))
            if kept:
                sys.__stderr__.write(kept)
                sys.__stderr__.flush()


_LOOP_CLOSED = "Event loop is closed"
_LOOP_CLOSED_FRAMES = (
    "asyncio/base_events.py",
    "self._check_closed()",
    "raise RuntimeError('Event loop is closed')",
)
_HEADER = "Traceback (most recent call last):"


def _drop_loop_closed(text: str) -> str:
    """``text`` without the "Event loop is closed" tracebacks. Several threads print them at
    once, so their pieces interleave even within a line ("RuntimeErrorTraceback ..."): per
    such error one "Traceback" header, its "RuntimeError" name and message are cut out wherever
    they are, and its frame lines and the blank lines left behind. Every other line is kept."""
    n = text.count(_LOOP_CLOSED)
    if not n:
        return text
    lines = text.splitlines(keepends=True)
    text = "".join(x for x in lines if not any(f in x for f in _LOOP_CLOSED_FRAMES))
    text = text.replace(f"RuntimeError: {_LOOP_CLOSED}", "").replace(f": {_LOOP_CLOSED}", "")
    text = text.replace(_LOOP_CLOSED, "").replace("RuntimeError", "", n).replace(_HEADER, "", n)
    return "".join(x for x in text.splitlines(keepends=True) if x.strip())


# What every checkpoint's ``meta`` item holds besides the run's config: its number of env steps
# (without it the metadata is damaged) and the runner's position (``Progress.meta``).
_META_NUMBERS = ("env_steps",)
_META_KEYS = ("chunk", "updates", "wall_s", "eval_history", "reached")


def _meta_problem(meta: Any) -> str | None:
    """Why a checkpoint's metadata cannot be used, or None: a JSON object with the run's config
    and its number of env steps."""
    if not isinstance(meta, dict):
        return f"a JSON object was expected, not {type(meta).__name__}"
    if not isinstance(meta.get("config"), dict):
        return "no run config in it"
    bad = [
        k for k in _META_NUMBERS if isinstance(meta.get(k), bool) or not isinstance(meta.get(k), int | float)
    ]
    return f"no number for {', '.join(bad)}" if bad else None


def _step_of(path: Path) -> int | None:
    """The step of a complete checkpoint folder (orbax writes ``N.orbax-checkpoint-tmp...`` first,
    then renames it ``N``), else None."""
    return int(path.name) if path.name.isdigit() and path.is_dir() else None


def _cause(e: Exception) -> str:
    """Why a write failed, in one line: the OS's words where the error carries them."""
    if isinstance(e, OSError) and e.strerror:
        return f"{e.strerror} ({e.filename})" if e.filename else e.strerror
    lines = str(e).strip().splitlines()
    text = lines[0].split(" [tensorstore_spec")[0] if lines else type(e).__name__
    for marker in ("Failed to write", "Failed to open", "Failed writing", "Error writing"):
        if marker in text:
            text = text[text.index(marker) :]
            break
    return text[:300]


def _first_line(e: Exception) -> str:
    """The gist of an orbax/tensorstore error: its first line, without the C++ stack dump that
    tensorstore appends."""
    text = str(e).strip().splitlines()
    return text[0].split(" [tensorstore_spec")[0][:400] if text else type(e).__name__
