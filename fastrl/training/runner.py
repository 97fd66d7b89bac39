"""The training runner: a host loop over chunks, each chunk ONE compiled program.

A chunk is a loop of ``learner.update`` jitted once with the training state donated, so the
simulator and the learner run without a host round trip per step. The number of updates is an
argument of that one program: chunks are sized by time (about ``train.chunk_seconds`` each,
from the last chunk's speed; the first is one update, so the first progress line comes
seconds after the compile) unless ``train.updates_per_chunk`` fixes them, and a chunk boundary
costs one call. Between chunks the runner prints a progress line, calls its callbacks (the
evaluation of the deterministic policy on its own schedule among them), logs (TensorBoard,
``metrics.csv``) and checkpoints (by time or every ``checkpoint.every`` chunks).
Ctrl-C asks the run to stop after the chunk in flight; it then saves a checkpoint and exits (a
second Ctrl-C stops at once, without saving).

``_train`` is the run: its start (``_launch``), the loop over chunks (``_chunks``, each
chunk's host work in ``_after_chunk``) and its summary. Each concern is a small piece of its
own module: the run's setup (``run_setup``: agents, learner, layout), its start (``start``: the
folder's lock, a fresh or restored state), the compiled chunk and its size (``chunk``), where
the run stands (``progress``: its position, the collapse watch and the ``stop_at_return``
record, divergence, the decision to stop), outputs (``outputs``), signals (``signals``) and
checkpoints. A single run is a batch of one (``run_setup.Agents``): the loop never asks which
it is. Everything else comes from the caller as ``Callback`` objects (``hooks``): the
evaluation (``evaluation.Evaluation``, the default), and what looks at the run (viewer pages,
notes, learning curves: ``fastrl.tools.callbacks``, which the runner never imports).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from fastrl.runtime import devices
from fastrl.training import files, layout, policy
from fastrl.training.checkpoint import Checkpointer, quiet_library_logs
from fastrl.training.chunk import ChunkSizer, Program, compile_chunk
from fastrl.training.config import ConfigError, RunConfig
from fastrl.training.evaluation import Evaluation
from fastrl.training.hooks import Callback, ChunkInfo, RunInfo
from fastrl.training.outputs import Outputs, agent_dirs, close_outputs, open_outputs, report_chunk, write_rows
from fastrl.training.progress import Clock, Progress, diverged, stop_reason
from fastrl.training.run_setup import Setup, make_setup
from fastrl.training.signals import StopFlag
from fastrl.training.start import RunDirLock, claim_folder, open_checkpoints, place_state, start_state

__all__ = ["Callback", "ChunkInfo", "RunInfo", "train"]


def train(
    cfg: RunConfig,
    run_dir: str | Path,
    resume: bool = False,
    resume_step: int | None = None,
    record: dict[str, str] | None = None,
    callbacks: Sequence[Callback] | None = None,
) -> dict[str, Any]:
    """Runs (or resumes) training into ``run_dir``.

    With ``train.num_seeds > 1`` or a ``train.vmap_sweep`` the run is a batch of agents in one
    program (``fastrl.training.scale``): each agent logs into ``run_dir/agents/<tag>/`` (its config,
    metrics.csv, TensorBoard events, curve), and one checkpoint holds them all.

    Args:
      cfg: the typed run config.
      run_dir: the run's folder (config, checkpoints, logs, curve).
      resume: continue from the newest checkpoint in ``run_dir`` that can be read (an unreadable
        newer one is reported and set aside), or from ``resume_step``.
      resume_step: with ``resume``, the chunk to continue from; newer checkpoints are moved
        to ``run_dir/checkpoints_set_aside/`` (never deleted).
      record: ``{relative path: text}`` written into ``run_dir`` with ``config.json`` once the
        run owns the folder (the command line's record of itself, e.g. ``.hydra/overrides.yaml``).
      callbacks: called at the start, after every chunk and at the end, in this order (the
        command line's: ``fastrl.tools.callbacks.standard()``). None: the evaluation alone
        (``Evaluation()``). Without an ``Evaluation`` the run logs no evaluation, and
        ``train.stop_at_return`` is refused.

    Nothing is written into ``run_dir`` before the run is known to be valid: a rejected start
    (the folder holds another run's checkpoints, the config differs from the checkpoint's, the
    folder is in use by another process) leaves every file as it was. A run holds a lock on its
    folder while it runs.
    Returns:
      A summary: status ("done", "stopped", "diverged", or "reached" when every agent's
      evaluation return reached ``train.stop_at_return``), ``interrupted`` (stopped by
      Ctrl-C), chunks, env_steps, final metrics; with
      ``stop_at_return`` also ``reached``: per agent the chunk, env steps, training seconds and
      return of its first evaluation at or above it (None where it never got there).
    """
    callbacks = [Evaluation()] if callbacks is None else list(callbacks)
    if cfg.train.stop_at_return is not None and not any(isinstance(cb, Evaluation) for cb in callbacks):
        raise ConfigError(
            "train.stop_at_return is checked at evaluations, but no Evaluation is among the callbacks"
        )
    run_dir = Path(run_dir).absolute()
    run_dir.mkdir(parents=True, exist_ok=True)
    quiet_library_logs()
    with RunDirLock(run_dir):
        files.refuse_links(run_dir)  # a folder from elsewhere is untrusted: no writes through links
        ckpt = open_checkpoints(cfg, run_dir, resume)
        try:
            return _train(cfg, run_dir, ckpt, resume, resume_step, record or {}, callbacks)
        finally:
            ckpt.close()


def _train(cfg: RunConfig, run_dir: Path, ckpt: Checkpointer, resume: bool, resume_step: int | None,
           record: dict[str, str], callbacks: Sequence[Callback]) -> dict[str, Any]:  # fmt: skip
    """The run: its start, then one compiled chunk and the host's pieces at a time, until the
    budget or a stop; returns its summary."""
    clock = Clock(cfg.train.max_seconds)
    setup = make_setup(cfg)
    state, progress, program = _launch(setup, ckpt, run_dir, resume, resume_step, record)
    info = RunInfo(setup, run_dir, agent_dirs(setup, run_dir))
    loop = _Loop(setup, program, ckpt, clock, ChunkSizer(setup), info, callbacks)
    _announce_start(setup, program, run_dir)
    for cb in callbacks:
        cb.on_start(info)
    outs = open_outputs(setup, run_dir, progress.chunk, setup.agents.env_steps(state))
    stop = StopFlag()
    try:
        with stop:
            status, state, row = _chunks(loop, state, progress, outs, stop)
    except (OSError, files.WriteError) as e:  # a full disk, a read-only folder
        raise files.WriteError(_write_failure(e, ckpt, run_dir)) from None
    finally:
        _end(callbacks, info, outs)
    summary = _summary(setup, progress, status, state, row, program.compile_s, run_dir, stop.set)
    summary["signal"] = stop.signum
    return summary


def _launch(setup: Setup, ckpt: Checkpointer, run_dir: Path, resume: bool, resume_step: int | None,
            record: dict[str, str]) -> tuple[Any, Progress, Program]:  # fmt: skip
    """The state and progress the run starts from, placed for the compiled chunk, and that
    chunk: XLA compiles it on a worker thread while the state is made, and only once the start
    is known to be valid is anything written into the folder."""
    cfg, weights = setup.cfg, None
    if cfg.init_from is not None and not resume:  # before compiling: weights that misfit fail fast
        weights, line = policy.start_from(setup.abstract, cfg.init_from, cfg.algo_name, setup.agents.n)
        print(f"[fastrl] {line}", flush=True)
    compiling = compile_chunk(setup)  # XLA compiles it on a worker thread while the state is made
    try:
        state, progress = start_state(setup, ckpt, run_dir, resume, resume_step, weights)
    except BaseException:
        compiling.wait()  # a process that exits while XLA compiles on another thread aborts
        raise
    claim_folder(run_dir, setup.config, record)  # only now does anything get written into it
    state = place_state(setup, state)
    return state, progress, compiling.result()


@dataclasses.dataclass(frozen=True)
class _Loop:
    """What the loop over chunks works with, fixed for the run."""

    setup: Setup
    program: Program
    ckpt: Checkpointer
    clock: Clock
    sizer: ChunkSizer
    info: RunInfo  # what the callbacks see of the run
    callbacks: Sequence[Callback]


def _chunks(
    loop: _Loop, state, progress: Progress, outs: list[Outputs], stop: StopFlag
) -> tuple[str, Any, dict]:
    """Runs chunks until the budget is spent or the run stops; returns the status ("done",
    "diverged", "reached", "stopped"), the last state (a diverged one is reported, never saved)
    and the run's last row."""
    setup, row = loop.setup, {}
    while not progress.done(setup):
        n, t = loop.sizer.next(progress, loop.clock), time.perf_counter()
        new_state, sums = loop.program.run(state, np.int32(n))
        rows = setup.agents.rows(sums, n)
        if diverged(setup.agents, progress, rows):
            return "diverged", new_state, row
        state, dt = new_state, time.perf_counter() - t
        loop.sizer.observe(n, dt)
        progress.advance(dt, n)
        row, ending = _after_chunk(loop, state, progress, rows, outs, stop, dt, n)
        if ending:
            _announce_end(setup, progress, ending, stop.name, loop.info.run_dir)
            return ending, state, row
    return "done", state, row


def _after_chunk(loop: _Loop, state, progress: Progress, rows: list[dict], outs: list[Outputs],
                 stop: StopFlag, dt: float, n: int) -> tuple[dict, str | None]:  # fmt: skip
    """The host's work after a chunk of ``n`` updates in ``dt`` seconds: its report, callbacks
    (the evaluation among them), rows and checkpoint; returns the run's row and why the run ends
    here (or None)."""
    setup = loop.setup
    report_chunk(setup, progress, rows, state, dt, n, loop.program.compile_s)
    chunk = ChunkInfo(progress.chunk, n, progress.done(setup), state, rows, progress)
    for cb in loop.callbacks:
        cb.on_chunk(loop.info, chunk)
    row = write_rows(setup, rows, outs)
    stop.agree()  # a signal to one process stops them all
    ending = stop_reason(setup, progress, stop.set, loop.clock)
    with stop.saving():
        _checkpoint(loop.ckpt, setup, progress, state, ending is not None)
    return row, ending


def _announce_start(setup: Setup, program: Program, run_dir: Path) -> None:
    """The run's first line: size, compile, devices (process 0 of a multi-host run only)."""
    if jax.process_index() != 0:
        return
    cfg, n, k = setup.cfg, setup.agents.n, setup.cfg.train.updates_per_chunk
    batch_note = f" x {n} agents in one program" if setup.agents.batched else ""
    size = f"updates x {setup.steps_per_update:,d} env steps{batch_note}"
    if setup.fixed_chunks is not None:
        size = f"{setup.fixed_chunks:,d} chunks x {k} {size}"
    else:
        size = f"{setup.total_updates:,d} {size} in chunks of ~{cfg.train.chunk_seconds:g}s"
    print(
        f"[fastrl] {cfg.env.name} / {cfg.algo_name}: {size}; chunk compiled in "
        f"{program.compile_s:.1f}s ({program.note}) on {layout.describe(setup.shardings, setup.mesh)}; "
        f"run dir {run_dir}"
    )


def _checkpoint(ckpt: Checkpointer, setup: Setup, progress: Progress, state, ending: bool) -> None:
    """Saves the state after the chunk just done when the run ends here, at the last chunk, and
    every ``checkpoint.every`` chunks or (every None) once ``checkpoint.seconds`` of training
    have passed since the last save."""
    every, seconds = setup.cfg.checkpoint.every, setup.cfg.checkpoint.seconds
    if every is not None:
        due = progress.chunk % every == 0
    else:  # by time: process 0's clock decides for all processes (all of them save together)
        due = bool(devices.agreed(progress.wall - progress.saved_wall >= seconds))
    if ending or progress.done(setup) or due:
        ckpt.save(progress.chunk, state, progress.meta(setup.config, setup.agents.env_steps(state)))
        progress.saved_wall = progress.wall


def _announce_end(
    setup: Setup, progress: Progress, ending: str, signal_name: str | None, run_dir: Path
) -> None:
    """Says why the run stopped before its budget, and how to continue it."""
    train = setup.cfg.train
    if ending == "reached":
        who = "every agent's" if setup.agents.batched else "the"
        print(f"[fastrl] {who} evaluation return reached train.stop_at_return={train.stop_at_return:g} by "
              f"chunk {progress.chunk} ({progress.wall:.0f}s of training); stopping", flush=True)  # fmt: skip
        return
    after = train.stop_after_chunks
    if signal_name is not None:
        why = signal_name
    elif after is not None and progress.chunk - progress.start_chunk >= after:
        why = f"train.stop_after_chunks={after}"
    else:
        why = f"train.max_seconds={train.max_seconds:g}"
    of = f"({progress.updates:,d} of {setup.total_updates:,d} updates)"
    if setup.fixed_chunks is not None:
        of = f"of {setup.fixed_chunks}"
    print(f"[fastrl] stopped by {why} after chunk {progress.chunk} {of}, checkpoint saved; "
          f"continue with: python -m fastrl.train resume={run_dir}", flush=True)  # fmt: skip


def _summary(setup: Setup, progress: Progress, status: str, state, row: dict, compile_s: float,
             run_dir: Path, interrupted: bool) -> dict[str, Any]:  # fmt: skip
    """What ``train`` returns (see its docstring)."""
    agents_, watch = setup.agents, progress.watch
    summary = {"status": status, "chunks": progress.chunk, "env_steps": agents_.env_steps(state),
               "compile_s": compile_s, "wall_s": progress.wall, "last": row, "run_dir": str(run_dir),
               "interrupted": interrupted}  # fmt: skip
    summary["collapsed"] = agents_.result(watch.collapsed)
    summary["best_eval_return"] = agents_.result(watch.best)
    if setup.cfg.train.stop_at_return is not None:
        summary["reached"] = agents_.result(progress.reached)
    if agents_.batched:
        tags = [s.tag for s in agents_.specs]
        summary["agents"] = tags
        summary["diverged_agents"] = [t for t, d in zip(tags, progress.diverged, strict=True) if d]
        summary["collapsed_agents"] = [t for t, c in zip(tags, watch.collapsed, strict=True) if c]
    return summary


def _write_failure(e: BaseException, ckpt: Checkpointer, run_dir: Path) -> str:
    """The one line a failed write ends the run with: what, why, what is safe, what to do."""
    if isinstance(e, files.WriteError):
        what = str(e)
    else:
        what = f"could not write {e.filename or run_dir}: {e.strerror or e}; {ckpt.last_good()}"
    return f"{what}. Free space (or make the folder writable), then: python -m fastrl.train resume={run_dir}"


def _end(callbacks: Sequence[Callback], info: RunInfo, outs: list[Outputs]) -> None:
    """The callbacks' ends, then each agent's logs closed (even when a callback raises)."""
    try:
        for cb in callbacks:
            cb.on_end(info)
    finally:
        close_outputs(outs)
