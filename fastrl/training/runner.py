"""The training runner: a host loop over chunks, each chunk ONE compiled program.

A chunk is a loop of ``learner.update`` jitted once with the training state donated, so the
simulator and the learner run without a host round trip per step. The number of updates is an
argument of that one program: chunks are sized by time (about ``train.chunk_seconds`` each,
from the last chunk's speed; the first is one update, so the first progress line comes
seconds after the compile) unless ``train.updates_per_chunk`` fixes them, and a chunk boundary
costs one call. Between chunks the runner prints a progress line, evaluates the
deterministic policy on its own schedule (``train.num_evals`` or ``train.eval_every``), logs
(TensorBoard, ``metrics.csv``) and checkpoints (by time or every ``checkpoint.every`` chunks).
Ctrl-C asks the run to stop after the chunk in flight; it then saves a checkpoint and exits (a
second Ctrl-C stops at once, without saving).

``_train`` is the loop; each concern is a small piece it calls: the run's setup (``_setup``:
agents, learner, layout), its start (``_start``: a fresh or restored state), the compiled chunk
(``_compile_chunk``), divergence (``_diverged``), evaluation with the collapse watch and the
``stop_at_return`` record (``_Evaluation``), outputs (``_Outputs``, ``_report_chunk``,
``_write_rows``), checkpoints and the decision to stop (``_stop_reason``). A single run is a
batch of one (``_Agents``): the loop never asks which it is. What looks at the run (viewer
pages, notes, learning curves) comes from the caller as ``Callback`` objects: the runner
imports none of those tools.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import shutil
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from fastrl import agents
from fastrl.agents.base import Learner
from fastrl.runtime import compile_cache, devices
from fastrl.runtime.devices import to_host
from fastrl.training import files, policy, scale
from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer, CheckpointError, quiet_library_logs
from fastrl.training.config import RunConfig
from fastrl.training.files import RunDirError

try:
    import fcntl
except ImportError:  # Windows: runs take no lock on their folder
    fcntl = None

__all__ = ["CHECKPOINT_DIR", "Callback", "CollapseWatch", "RunDirError", "RunDirLock", "RunInfo", "train"]


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """What a callback sees of a run.

    Fields:
      cfg      the run's config
      env      its env
      learner  its learner (``act``, ``policy_params``): of one agent, over a batch's states
      batched  the state's leaves have a leading agent axis (a batch of agents)
      run_dir  the run's folder
      outputs  each agent's folder and config: the run folder for a single run,
               ``agents/<tag>/`` for each agent of a batch
    """

    cfg: RunConfig
    env: Any
    learner: Learner
    batched: bool
    run_dir: Path
    outputs: tuple[tuple[Path, RunConfig], ...]


class Callback:
    """A piece the caller hands ``train`` to look at the run; each hook does nothing unless
    overridden. Hooks run on every process of a multi-host run: one that writes checks
    ``jax.process_index()``."""

    def on_start(self, run: RunInfo) -> None:
        """After the run's first line, before its first chunk."""

    def on_chunk(self, run: RunInfo, state, chunk: int, last: bool) -> None:
        """After chunk ``chunk`` and its evaluation, before its row is written; ``last``: the
        run's budget ends with this chunk."""

    def on_end(self, run: RunInfo) -> None:
        """When the run ends (as it returns or raises), before its logs are closed."""


def train(
    cfg: RunConfig,
    run_dir: str | Path,
    resume: bool = False,
    on_chunk=None,
    resume_step: int | None = None,
    record: dict[str, str] | None = None,
    callbacks: Sequence[Callback] = (),
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
      on_chunk: optional callback ``(chunk, row)`` after every chunk (tests use it); for a batch
        ``row`` is the mean over agents and ``row["agents"]`` holds each agent's row.
      resume_step: with ``resume``, the chunk to continue from; newer checkpoints are moved
        to ``run_dir/checkpoints_set_aside/`` (never deleted).
      record: ``{relative path: text}`` written into ``run_dir`` with ``config.json`` once the
        run owns the folder (the command line's record of itself, e.g. ``.hydra/overrides.yaml``).
      callbacks: what looks at the run, called at the start, after every chunk and at the end
        (the command line's: ``fastrl.tools.callbacks.standard()``).

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
    run_dir = Path(run_dir).absolute()
    run_dir.mkdir(parents=True, exist_ok=True)
    quiet_library_logs()
    with RunDirLock(run_dir):
        files.refuse_links(run_dir)  # a folder from elsewhere is untrusted: no writes through links
        ckpt = _open_checkpoints(cfg, run_dir, resume)
        try:
            return _train(cfg, run_dir, ckpt, resume, on_chunk, resume_step, record or {}, callbacks)
        finally:
            ckpt.close()


def _train(cfg: RunConfig, run_dir: Path, ckpt: Checkpointer, resume: bool, on_chunk, resume_step,
           record: dict[str, str], callbacks: Sequence[Callback]) -> dict[str, Any]:  # fmt: skip
    """The loop: one compiled chunk, then the host's pieces, until the budget or a stop."""
    clock = _Clock(cfg.train.max_seconds)
    setup = _setup(cfg)
    weights = None
    if cfg.init_from is not None and not resume:  # before compiling: weights that misfit fail fast
        weights, line = policy.start_from(setup.abstract, cfg.init_from, cfg.algo_name, setup.agents.n)
        print(f"[fastrl] {line}", flush=True)
    compiling = _compile_chunk(setup)  # XLA compiles it on a worker thread while the state is made
    try:
        state, progress = _start(setup, ckpt, run_dir, resume, resume_step, weights)
    except BaseException:
        compiling.wait()  # a process that exits while XLA compiles on another thread aborts
        raise
    _claim_folder(run_dir, setup.config, record)  # only now does anything get written into it
    state = _place(setup, state)
    program = compiling.result()
    evaluation, sizer = _Evaluation(setup), _ChunkSizer(setup)
    info = RunInfo(
        setup.cfg, setup.env, setup.learner, setup.agents.batched, run_dir, _agent_dirs(setup, run_dir)
    )
    _announce_start(setup, program, run_dir)
    for cb in callbacks:
        cb.on_start(info)
    outs = _open_outputs(setup, run_dir, progress.chunk, setup.agents.env_steps(state))
    status, row = "done", {}
    stop = _StopFlag()
    try:
        with stop:
            while not progress.done(setup):
                n, t = sizer.next(progress, clock), time.perf_counter()
                new_state, sums = program.run(state, np.int32(n))
                rows = setup.agents.rows(sums, n)
                if _diverged(setup.agents, progress, rows):
                    status, state = "diverged", new_state  # reported, never saved
                    break
                state, dt = new_state, time.perf_counter() - t
                sizer.observe(n, dt)
                progress.advance(dt, n)
                _report_chunk(setup, progress, rows, state, dt, n, program.compile_s)
                if evaluation.due(progress, n):
                    evaluation(state, rows, progress)
                for cb in callbacks:
                    cb.on_chunk(info, state, progress.chunk, progress.done(setup))
                row = _write_rows(setup, rows, outs)
                if on_chunk is not None:
                    on_chunk(progress.chunk, row)
                stop.agree()  # a signal to one process stops them all
                ending = _stop_reason(setup, progress, stop.set, clock)
                with stop.saving():
                    _checkpoint(ckpt, setup, progress, state, ending is not None)
                if ending:
                    status = ending
                    _announce_end(setup, progress, ending, stop.name, run_dir)
                    break
    except (OSError, files.WriteError) as e:  # a full disk, a read-only folder
        raise files.WriteError(_write_failure(e, ckpt, run_dir)) from None
    finally:
        _end(callbacks, info, outs)
    summary = _summary(setup, progress, status, state, row, program.compile_s, run_dir, stop.set)
    summary["signal"] = stop.signum
    return summary


# ----------------------------------------------------------------------------- the run's parts


@dataclasses.dataclass(frozen=True)
class _Agents:
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
            return [_reduce(sums, n)]
        return [_reduce(jax.tree.map(lambda x, i=i: x[i], sums), n) for i in range(self.n)]

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
class _Setup:
    """What a run is, decided before anything is traced: its env, agents, learner and layout."""

    cfg: RunConfig
    config: dict  # cfg.to_dict(), saved with every checkpoint
    env: Any
    agents: _Agents
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


def _setup(cfg: RunConfig) -> _Setup:
    """The run's env, agents, learner (built for the run's total updates) and state layout."""
    env = cfg.env.make()
    specs = scale.expand(cfg)
    # The learner is built twice: first to learn its env steps per update, then with the run's
    # total updates (which set learning-rate schedules). Building is cheap; nothing is traced.
    steps_per_update = agents.make_learner(cfg.algo_name, cfg.algo, env, cfg.network, 1).env_steps_per_update
    total_updates = max(1, math.ceil(cfg.train.total_env_steps / steps_per_update))
    if (k := cfg.train.updates_per_chunk) is not None:  # fixed chunks: the budget in whole chunks
        total_updates = math.ceil(total_updates / k) * k
    mesh = devices.mesh()
    learner, init_key = scale.run_learner(cfg, specs, env, total_updates, mesh)
    shardings, abstract = None, jax.eval_shape(learner.init, init_key)
    if mesh is not None:
        shardings = scale.state_shardings(abstract, mesh, len(specs), learner.num_envs)
        laid_out = lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s)  # noqa: E731
        abstract = jax.tree.map(laid_out, abstract, shardings)
    return _Setup(cfg=cfg, config=cfg.to_dict(), env=env, agents=_Agents(specs), learner=learner,
                  init_key=init_key, steps_per_update=steps_per_update, total_updates=total_updates,
                  mesh=mesh, shardings=shardings, abstract=abstract)  # fmt: skip


@dataclasses.dataclass
class _Progress:
    """Where the run stands on the host. Saved in every checkpoint's metadata (``meta``), so a
    resumed run judges collapse and ``stop_at_return`` as the run that stopped would have.

    Fields:
      chunk        chunks done
      updates      learner updates done
      wall         seconds of training (chunks only: no compile, evaluation or saving)
      saved_wall   ``wall`` at the last checkpoint
      train_return the training return of the latest chunk in which episodes ended
      watch        the collapse watch over evaluation returns
      reached      per agent: where its evaluation return first reached train.stop_at_return
      diverged     per agent: its losses went non-finite in this invocation (never saved)
      start_chunk  the chunk this invocation started from
      overflowed   whether this invocation has said that the contact budgets dropped contacts
    """

    chunk: int
    updates: int
    wall: float
    watch: CollapseWatch
    reached: list[dict | None]
    diverged: list[bool]
    start_chunk: int
    saved_wall: float = 0.0
    train_return: float = math.nan  # the latest chunk's in which an episode ended (not saved)
    overflowed: bool = False  # (not saved)

    @classmethod
    def fresh(cls, n_agents: int) -> _Progress:
        return cls(0, 0, 0.0, CollapseWatch(n_agents), [None] * n_agents, [False] * n_agents, 0)

    @classmethod
    def from_meta(cls, meta: dict, n_agents: int) -> _Progress:
        chunk, wall = int(meta["chunk"]), float(meta["wall_s"])
        # checkpoints from before time-sized chunks: every chunk was updates_per_chunk updates
        updates = meta.get("updates")
        if updates is None:
            updates = chunk * int(meta["config"]["train"]["updates_per_chunk"])
        watch = CollapseWatch(n_agents, history=meta.get("eval_history"))
        reached = list(meta.get("reached") or [None] * n_agents)
        return cls(chunk, int(updates), wall, watch, reached, [False] * n_agents, chunk, wall)

    def advance(self, seconds: float, updates: int) -> None:
        self.chunk += 1
        self.updates += updates
        self.wall += seconds

    def done(self, setup: _Setup) -> bool:
        return self.updates >= setup.total_updates

    def meta(self, config: dict, env_steps: int) -> dict:
        """The checkpoint's metadata: the config, this position and the time of saving
        (``saved_at``, seconds since the Unix epoch)."""
        return {"config": config, "chunk": self.chunk, "updates": self.updates,
                "env_steps": env_steps, "wall_s": self.wall, "eval_history": self.watch.history(),
                "reached": self.reached, "saved_at": time.time()}  # fmt: skip


class _Clock:
    """This invocation's time limit (``train.max_seconds``), counted from its start."""

    def __init__(self, limit: float | None):
        self.limit, self.start = limit, time.perf_counter()

    def left(self) -> float:
        """Seconds left (infinite without a limit)."""
        return math.inf if self.limit is None else self.limit - (time.perf_counter() - self.start)

    def out(self) -> bool:
        """Whether the limit is reached (process 0's clock decides for all processes)."""
        return self.limit is not None and bool(devices.agreed(self.left() <= 0))


class _ChunkSizer:
    """How many updates the next chunk runs: ``train.updates_per_chunk`` when fixed; else one
    update first, then as many as the last chunk's speed fits in ``train.chunk_seconds``. Under
    a time limit a chunk is cut short to end at it, once the speed is known."""

    def __init__(self, setup: _Setup):
        self.fixed, self.seconds = setup.cfg.train.updates_per_chunk, setup.cfg.train.chunk_seconds
        self.total = setup.total_updates
        self.per_update: float | None = None

    def next(self, progress: _Progress, clock: _Clock) -> int:
        if self.fixed is not None:
            n = self.fixed
        elif self.per_update is None:
            n = 1
        else:  # by time: process 0's measurement decides for all processes
            n = devices.agreed(max(1, round(min(self.seconds, clock.left()) / self.per_update)))
        return min(n, self.total - progress.updates)

    def observe(self, n: int, seconds: float) -> None:
        self.per_update = seconds / n


def _open_checkpoints(cfg: RunConfig, run_dir: Path, resume: bool) -> Checkpointer:
    """The run's checkpointer; a new run refuses a folder that holds another run's checkpoints."""
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR, keep=cfg.checkpoint.keep, tidy=True)
    if not resume and ckpt.latest_step() is not None:
        ckpt.close()
        raise CheckpointError(
            f"{run_dir} already holds checkpoints of a run; continue it with resume={run_dir}, or "
            "choose a new run dir (nothing was changed)"
        )
    return ckpt


def _start(setup: _Setup, ckpt: Checkpointer, run_dir: Path, resume: bool, resume_step: int | None,
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
        return state, _Progress.fresh(setup.agents.n)
    state, meta = ckpt.restore_newest(lambda step: ckpt.restore(state, setup.config, step), resume_step)
    progress = _Progress.from_meta(meta, setup.agents.n)
    _set_aside_after(ckpt, run_dir, progress.chunk)
    print(f"[fastrl] resumed {run_dir} at chunk {progress.chunk} ({int(meta['env_steps']):,d} env steps)")
    return state, progress


def _claim_folder(run_dir: Path, config: dict, record: dict[str, str]) -> None:
    """Writes the run's config and the command line's record: the run is valid and owns its folder."""
    files.write_text(run_dir / "config.json", json.dumps(config, indent=2))
    for name, text in record.items():
        (run_dir / name).parent.mkdir(parents=True, exist_ok=True)
        files.write_text(run_dir / name, text)


def _place(setup: _Setup, state):
    """The state in fresh buffers (donation fails when two leaves share one), laid out for the mesh,
    by one jitted copy of the whole tree (a copy per leaf would compile a program per shape)."""
    fresh = lambda s: jax.tree.map(lambda x: jnp.array(x, copy=True), s)  # noqa: E731
    return jax.jit(fresh, out_shardings=setup.shardings)(state)


@dataclasses.dataclass(frozen=True)
class _Program:
    """The compiled chunk and how compiling it went."""

    run: Callable
    compile_s: float
    note: str


class _Compiling:
    """The chunk's XLA compile on a worker thread; ``result()`` waits for it (and re-raises).

    XLA releases the GIL while it compiles, so the main thread meanwhile builds the initial state
    (tracing, compiling and running the learner's ``init``). The thread is a daemon: a run that
    fails before it needs the program exits without waiting for the compile. ``wrap`` adapts the
    compiled callable to ``run(state, n)``; ``t0`` is when tracing began (the reported compile
    time includes it).
    """

    def __init__(self, lowered, t0: float, traced_note: str, wrap: Callable = lambda run: run):
        self._out: list = []
        args = (lowered, t0, traced_note, wrap)
        self._thread = threading.Thread(target=self._run, args=args, name="fastrl-compile", daemon=True)
        self._thread.start()

    def _run(self, lowered, t0: float, traced_note: str, wrap: Callable) -> None:
        try:
            before = compile_cache.counts()  # this thread's: the compile's own cache use
            run = wrap(lowered.compile())
            cache_note = compile_cache.describe(before, compile_cache.is_enabled())
            self._out.append(_Program(run, time.perf_counter() - t0, f"{traced_note}, {cache_note}"))
        except BaseException as e:  # handed to the main thread by result()
            self._out.append(e)

    def wait(self) -> None:
        """Waits for the compile to end (whatever its outcome), so the process can exit cleanly."""
        self._thread.join()

    def result(self) -> _Program:
        self._thread.join()
        (out,) = self._out
        if isinstance(out, BaseException):
            raise out
        return out


def _compile_chunk(setup: _Setup) -> _Compiling:
    """``n`` updates in a loop (``n`` a traced argument: every chunk size runs the same program),
    their metrics summed; jitted once with the state donated. Traced here from the state's shapes
    and layout (``setup.abstract``) and compiled on a worker thread. With the compilation cache on,
    an identical launch reads the traced program from it (``compile_cache.exported``) instead of
    tracing, and its compiled form from JAX's cache."""
    shardings, t0, state = setup.shardings, time.perf_counter(), setup.abstract

    def chunk_fn():
        # jit's trace cache: eval_shape traces the update once, the loop body reuses that trace
        update = jax.jit(setup.learner.update)
        metrics_shape = jax.eval_shape(update, state)[1]

        def run_chunk(s, n):
            def body(_, carry):
                s, sums = carry
                s, metrics = update(s)
                return s, jax.tree.map(lambda a, m: a + m.astype(a.dtype), sums, metrics)

            zeros = jax.tree.map(
                lambda m: jnp.zeros(m.shape, jnp.result_type(m.dtype, jnp.float32)), metrics_shape
            )
            s, sums = jax.lax.fori_loop(0, n, body, (s, zeros))
            if shardings is not None:  # keep the layout fixed from chunk to chunk
                s = jax.lax.with_sharding_constraint(s, shardings)
            return s, sums

        return run_chunk

    count = jax.ShapeDtypeStruct((), jnp.int32)
    if not compile_cache.is_enabled() or jax.process_count() > 1:
        lowered = jax.jit(chunk_fn(), donate_argnums=0).lower(state, count)
        return _Compiling(lowered, t0, f"{time.perf_counter() - t0:.1f}s tracing")
    # With the cache: the chunk as a function of the state's leaves, exported (jax.export keeps
    # builtin containers only), read back by an identical launch without tracing
    leaves, treedef = jax.tree.flatten(state)

    def export():
        run_chunk = chunk_fn()

        def flat(xs, n):
            s, sums = run_chunk(jax.tree.unflatten(treedef, xs), n)
            return jax.tree.leaves(s), sums

        return jax.export.export(jax.jit(flat))(leaves, count)

    key = compile_cache.program_key((setup.config, getattr(setup.env, "model", None)), state)
    exported, read = compile_cache.exported(key, export)
    traced_note = "traced program read from the cache" if read else f"{time.perf_counter() - t0:.1f}s tracing"
    lowered = jax.jit(exported.call, donate_argnums=0).lower(leaves, count)

    def wrap(program):
        def run(s, n):
            out, sums = program(jax.tree.leaves(s), n)
            return jax.tree.unflatten(treedef, out), sums

        return run

    return _Compiling(lowered, t0, traced_note, wrap)


def _announce_start(setup: _Setup, program: _Program, run_dir: Path) -> None:
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
        f"{program.compile_s:.1f}s ({program.note}) on {scale.describe(setup.shardings, setup.mesh)}; "
        f"run dir {run_dir}"
    )


def _diverged(agents_: _Agents, progress: _Progress, rows: list[dict]) -> bool:
    """Marks (and reports) the agents whose losses went non-finite in the chunk just run; True
    when every agent has diverged, and the run stops without saving."""
    for i, r in enumerate(rows):
        losses = [v for key, v in r.items() if key.startswith("loss/")]
        if not progress.diverged[i] and not all(math.isfinite(v) for v in losses):
            progress.diverged[i] = True
            print(f"[fastrl] {agents_.who(i)}training diverged (non-finite loss) in chunk "
                  f"{progress.chunk + 1}", file=sys.stderr)  # fmt: skip
    if not all(progress.diverged):
        return False
    print("[fastrl] the last good checkpoint is kept. Try a smaller learning rate or batch.", file=sys.stderr)
    return True


class _Evaluation:
    """The deterministic policy's evaluation between chunks: ``eval/*`` into each agent's row,
    then the collapse watch and the ``train.stop_at_return`` record."""

    def __init__(self, setup: _Setup):
        self.setup = setup
        cfg, mesh = setup.cfg, setup.mesh
        # A single run's evaluation steps its envs on every device (an Ant evaluation is 1000
        # sequential steps of a small batch: on one of 2 CPU devices it took ~12 s per chunk).
        split = not setup.agents.batched and mesh is not None and cfg.train.eval_envs % mesh.devices.size == 0
        evaluate = agents.make_evaluator(
            setup.env, setup.learner.act, cfg.train.eval_envs, mesh=mesh if split else None
        )
        self._evaluate = jax.jit(jax.vmap(evaluate) if setup.agents.batched else evaluate)

    def due(self, progress: _Progress, n: int) -> bool:
        """Whether the chunk just done (of ``n`` updates) ends with an evaluation: the last always
        does; then every ``train.eval_every`` chunks and chunk 1, or, with eval_every None, the
        chunks that cross one of ``train.num_evals`` evenly spaced points of the run."""
        train, total = self.setup.cfg.train, self.setup.total_updates
        if progress.done(self.setup):
            return True
        if train.eval_every is not None:
            every = train.eval_every
            return progress.chunk == 1 or bool(every and progress.chunk % every == 0)
        before, after = progress.updates - n, progress.updates
        return before * train.num_evals // total < after * train.num_evals // total

    def __call__(self, state, rows: list[dict], progress: _Progress) -> None:
        setup, n = self.setup, self.setup.agents.n
        key, t0 = setup.agents.eval_key(progress.chunk), time.perf_counter()
        ret, length, final = to_host(self._evaluate(setup.learner.policy_params(state), key))
        ret, length = (np.asarray(x).reshape(n, -1) for x in (ret, length))
        final = {k: np.asarray(v).reshape(n, -1) for k, v in final.items()}
        for i, r in enumerate(rows):
            r.update({"eval/episode_return": float(ret[i].mean()),
                      "eval/episode_return_std": float(ret[i].std()),
                      "eval/episode_length": float(length[i].mean())})  # fmt: skip
            r.update({f"eval/{k}": float(v[i].mean()) for k, v in final.items()})
        self._watch_collapse(rows, progress)
        self._note_reached(state, rows, progress)
        if setup.cfg.logger.progress and jax.process_index() == 0:
            mean = float(np.mean([r["eval/episode_return"] for r in rows]))
            who = f"mean of {n} agents " if setup.agents.batched else ""
            print(f"[fastrl] evaluation at {setup.agents.env_steps(state):,d} steps: {who}return "
                  f"{mean:.2f} ({setup.cfg.train.eval_envs} episodes, {time.perf_counter() - t0:.1f}s)",
                  flush=True)  # fmt: skip

    def _watch_collapse(self, rows: list[dict], progress: _Progress) -> None:
        watch = progress.watch
        for i, r in enumerate(rows):
            was = watch.collapsed[i]
            if watch.update(i, r["eval/episode_return"]) and not was:
                who = self.setup.agents.who(i)
                print(f"[fastrl] {who}training collapsed in chunk {progress.chunk}: eval return "
                      f"{r['eval/episode_return']:.4g}, best {watch.best[i]:.4g}, first "
                      f"{watch.first[i]:.4g}", file=sys.stderr)  # fmt: skip
            r["train/collapsed"] = float(watch.collapsed[i])

    def _note_reached(self, state, rows: list[dict], progress: _Progress) -> None:
        target = self.setup.cfg.train.stop_at_return
        if target is None:
            return
        for i, r in enumerate(rows):
            if progress.reached[i] is None and r["eval/episode_return"] >= target:
                steps = self.setup.agents.env_steps(state, i)
                progress.reached[i] = {"chunk": progress.chunk, "env_steps": steps, "wall_s": progress.wall,
                                       "eval_return": r["eval/episode_return"]}  # fmt: skip


def _open_outputs(setup: _Setup, run_dir: Path, chunk: int, env_steps: int) -> list[_Outputs]:
    """Each agent's outputs: the run folder's own for a single run, ``agents/<tag>/`` (with the
    agent's own config.json) for each agent of a batch."""
    if not setup.agents.batched:
        return [_Outputs(run_dir, setup.cfg, chunk, env_steps)]
    outs = []
    for agent_dir, config in _agent_dirs(setup, run_dir):
        agent_dir.mkdir(parents=True, exist_ok=True)
        files.write_text(agent_dir / "config.json", json.dumps(config.to_dict(), indent=2))
        outs.append(_Outputs(agent_dir, config, chunk, env_steps))
    return outs


def _agent_dirs(setup: _Setup, run_dir: Path) -> tuple[tuple[Path, RunConfig], ...]:
    """Each agent's folder and config: the run folder for a single run, ``agents/<tag>/`` in a batch."""
    if not setup.agents.batched:
        return ((run_dir, setup.cfg),)
    return tuple((run_dir / "agents" / spec.tag, spec.config) for spec in setup.agents.specs)


def _report_chunk(setup: _Setup, progress: _Progress, rows: list[dict], state, dt: float, n: int,
                  compile_s: float) -> None:  # fmt: skip
    """Completes each agent's row of the chunk just run (``n`` updates in ``dt`` seconds) and
    prints the progress line at once, before any evaluation."""
    for i, r in enumerate(rows):
        r.update(chunk=progress.chunk, env_steps=setup.agents.env_steps(state, i), wall_s=progress.wall,
                 time_unix=time.time())  # fmt: skip
        r["perf/env_steps_per_s"] = n * setup.steps_per_update / dt
        r["perf/compile_s"] = compile_s
        if setup.agents.batched:
            r["train/diverged"] = float(progress.diverged[i])
    row = _mean_row(rows, setup.agents.n) if setup.agents.batched else rows[0]
    progress.train_return = row.get("train/episode_return", progress.train_return)
    if setup.cfg.logger.progress and jax.process_index() == 0:
        print(_progress(row, setup.total_steps, progress.wall, progress.train_return), flush=True)
    if row.get("env/contact_overflow", 0) > 0 and not progress.overflowed and jax.process_index() == 0:
        progress.overflowed = True
        print(f"[fastrl] warning: chunk {progress.chunk}: the scene's contact budgets dropped contacts "
              f"(env/contact_overflow {row['env/contact_overflow']:.3g}, the mean over envs; "
              "more contact slots: +env.options.nconmax=N; docs/physics.md)",
              file=sys.stderr, flush=True)  # fmt: skip


def _write_rows(setup: _Setup, rows: list[dict], outs: list[_Outputs]) -> dict:
    """Writes each agent's completed row (evaluation included) to its outputs; returns the run's
    row (a batch's means)."""
    for r, out in zip(rows, outs, strict=True):
        out.log(r)
    return _mean_row(rows, setup.agents.n) if setup.agents.batched else rows[0]


def _checkpoint(ckpt: Checkpointer, setup: _Setup, progress: _Progress, state, ending: bool) -> None:
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


def _stop_reason(setup: _Setup, progress: _Progress, interrupted: bool, clock: _Clock) -> str | None:
    """Why the run ends after this chunk, before its budget: "reached" (every agent's evaluation
    return reached ``train.stop_at_return``), "stopped" (Ctrl-C, ``train.stop_after_chunks``,
    ``train.max_seconds``), or None to go on."""
    train = setup.cfg.train
    if train.stop_at_return is not None and all(x is not None for x in progress.reached):
        return "reached"
    after = train.stop_after_chunks
    if interrupted or (after is not None and progress.chunk - progress.start_chunk >= after):
        return "stopped"
    if not progress.done(setup) and clock.out():  # a run that has just finished is "done"
        return "stopped"
    return None


def _announce_end(
    setup: _Setup, progress: _Progress, ending: str, signal_name: str | None, run_dir: Path
) -> None:
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


def _summary(setup: _Setup, progress: _Progress, status: str, state, row: dict, compile_s: float,
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


# ----------------------------------------------------------------------------- host helpers


class _StopFlag:
    """Stops the run cleanly on Ctrl-C (SIGINT), SIGTERM (Slurm, ``docker stop``, ``kill``, a CI
    cancel) and SIGHUP (a closed terminal): the first sets the flag, and the run stops after the
    chunk in flight and saves a checkpoint. A second signal stops at once without saving, except
    while a checkpoint is being written: that save is completed first (an interrupted save
    would leave nothing but a partial folder). A first signal during a periodic save stops the
    run after the next chunk."""

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self):
        self.signum: int | None = None
        self._saving = False
        self._previous: dict[int, Any] = {}

    @property
    def set(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str | None:
        """How the stop was asked for, as the user would say it."""
        if self.signum is None:
            return None
        return "Ctrl-C" if self.signum == signal.SIGINT else signal.Signals(self.signum).name

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        for name in self.SIGNALS:
            num = getattr(signal, name, None)  # Windows has no SIGHUP
            if num is not None and signal.getsignal(num) is not None:
                self._previous[num] = signal.signal(num, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.set and self._saving:
            print("\n[fastrl] a checkpoint is being saved: the run ends once it is complete",
                  file=sys.stderr, flush=True)  # fmt: skip
            return
        if self.set:
            raise KeyboardInterrupt
        self.signum = signum
        print(f"\n[fastrl] {self.name}: stopping after this chunk and saving a checkpoint (again to abort)",
              file=sys.stderr, flush=True)  # fmt: skip

    def agree(self) -> None:
        """A stop asked of any process of a multi-host run stops them all (as SIGINT where this
        process received none)."""
        if devices.any_process(self.set) and not self.set:
            self.signum = signal.SIGINT

    @contextlib.contextmanager
    def saving(self):
        """Holds a second signal back while a checkpoint is written."""
        self._saving = True
        try:
            yield
        finally:
            self._saving = False

    def __exit__(self, *exc):
        for num, previous in self._previous.items():
            signal.signal(num, previous)
        self._previous = {}


def _write_failure(e: BaseException, ckpt: Checkpointer, run_dir: Path) -> str:
    """The one line a failed write ends the run with: what, why, what is safe, what to do."""
    if isinstance(e, files.WriteError):
        what = str(e)
    else:
        what = f"could not write {e.filename or run_dir}: {e.strerror or e}; {ckpt.last_good()}"
    return f"{what}. Free space (or make the folder writable), then: python -m fastrl.train resume={run_dir}"


def _end(callbacks: Sequence[Callback], info: RunInfo, outs: list[_Outputs]) -> None:
    """The callbacks' ends, then each agent's logs closed (even when a callback raises)."""
    try:
        for cb in callbacks:
            cb.on_end(info)
    finally:
        _close_outputs(outs)


def _close_outputs(outs: list[_Outputs]) -> None:
    """Closes each agent's logs. Logs that cannot be flushed (the full disk that ended the run)
    are said to be not updated."""
    for out in outs:
        try:
            out.close()
        except OSError as e:
            print(f"[fastrl] warning: the outputs of {out.run_dir} were not updated: {e.strerror or e}",
                  file=sys.stderr)  # fmt: skip


def _reduce(sums: dict, n: int) -> dict[str, float]:
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


class _Outputs:
    """TensorBoard and metrics.csv of one run folder."""

    def __init__(self, run_dir: Path, cfg: RunConfig, resumed_chunk: int, env_steps: int):
        if jax.process_index() != 0:  # multi-host runs: one process writes the run's outputs
            quiet = dict(tensorboard=False, csv=False, plot=False, progress=False)
            cfg = dataclasses.replace(cfg, logger=dataclasses.replace(cfg.logger, **quiet))
        self.run_dir, self.cfg = run_dir, cfg
        self.csv_path = run_dir / "metrics.csv"
        self.writer = None
        if cfg.logger.tensorboard:
            from tensorboardX import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=env_steps if resumed_chunk else None)
        if cfg.logger.csv and self.csv_path.exists():
            self._truncate_csv(resumed_chunk)

    def _truncate_csv(self, chunk: int) -> None:
        """Drops rows logged after the checkpoint being resumed, so the curve has no duplicates.
        Rows that cannot be read back (a crash or a full disk mid-append leaves a last row cut
        short, without its line end) are set aside in ``metrics.csv.damaged-<time>``, with a note."""
        header, rows, damaged = _read_csv(self.csv_path)
        if damaged:
            aside = self.csv_path.with_name(f"{self.csv_path.name}.damaged-{time.strftime('%Y%m%d-%H%M%S')}")
            files.write_text(aside, "".join(damaged))
            print(f"[fastrl] warning: {len(damaged)} damaged row(s) of {self.csv_path} (a write cut short) "
                  f"set aside in {aside.name}; the run continues", file=sys.stderr)  # fmt: skip
        if header is None:
            return
        chunks = header.index("chunk")
        keep = [r for r in rows if int(r[chunks]) <= chunk]
        files.write_text(self.csv_path, _csv_text([header, *keep]))

    def log(self, row: dict[str, float]) -> None:
        step = int(row["env_steps"])
        if self.writer is not None:
            for k, v in row.items():
                if "/" in k and math.isfinite(v):
                    self.writer.add_scalar(k, v, step)
            self.writer.flush()
        if self.cfg.logger.csv:
            self._append_csv(row)

    def _append_csv(self, row: dict) -> None:
        """Appends ``row`` whole or not at all; a column first seen now (the first evaluation's,
        an episode return) extends the header, the earlier rows keeping it empty."""
        fields = []
        if self.csv_path.exists():  # the header only: the whole file is read when it grows a column
            with self.csv_path.open(newline="") as f:
                fields = next(csv.reader(f), [])
        extra = [k for k in row if k != "agents" and k not in fields]
        if extra and fields:
            _, rows, _ = _read_csv(self.csv_path)
            table = [fields + extra, *(r + [""] * len(extra) for r in rows)]
            files.write_text(self.csv_path, _csv_text(table))
        lines = [] if fields else [extra]
        fields = fields + extra
        lines.append([row.get(k, "") for k in fields])
        files.append_text(self.csv_path, _csv_text(lines))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _read_csv(path: Path) -> tuple[list[str] | None, list[list[str]], list[str]]:
    """A ``metrics.csv``'s header, its readable rows, and the raw lines of the damaged ones: a
    last line without its line end (an append cut short), or a row of another width or without
    a whole chunk number. A damaged header leaves no header and every line damaged."""
    with path.open(newline="") as f:
        lines = f.read().splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n"
        cut = [lines.pop()]
    else:
        cut = []
    if not lines:
        return None, [], cut
    header = next(csv.reader([lines[0]]))
    if "chunk" not in header:
        return None, [], lines + cut
    chunks, rows, damaged = header.index("chunk"), [], []
    for line in lines[1:]:
        row = next(csv.reader([line]), [])
        if len(row) == len(header) and row[chunks].isdigit():
            rows.append(row)
        else:
            damaged.append(line)
    return header, rows, damaged + cut


def _csv_text(rows: list[list[str]]) -> str:
    buf = io.StringIO()
    csv.writer(buf).writerows(rows)
    return buf.getvalue()


def _progress(row: dict, total_steps: int, elapsed: float, train_return: float) -> str:
    steps = int(row["env_steps"])
    frac = min(1.0, steps / total_steps)
    rate = row.get("perf/env_steps_per_s", float("nan"))
    eta = (total_steps - steps) / rate if rate and rate > 0 else float("nan")
    bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
    # nan until a training episode has ended (e.g. the first 1000 steps of each env): say so
    ret = f"train return {train_return:9.2f}" if math.isfinite(train_return) else "no episode ended yet"
    return (
        f"[{bar}] {100 * frac:5.1f}% {steps:>11,d} steps | {rate:>9,.0f} steps/s | "
        f"{ret} | {elapsed:7.0f}s elapsed, ETA {eta:6.0f}s"
    )


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


def _set_aside_after(ckpt: Checkpointer, run_dir: Path, step: int) -> None:
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


class CollapseWatch:
    """Flags agents whose evaluation return collapsed: after improving on the first evaluation by
    a real margin (``min_gain`` of the first return's size, plus 1), the latest evaluation fell
    back more than ``fraction`` of the way from the best to the first, and by more than
    ``min_fall`` of the best return's size (plus 1). The last condition keeps the ordinary
    wobble of a task with a large baseline from counting: the Ant earns ~1000 for standing,
    and a policy going 944 -> 1113 -> 988 has not collapsed. The gain must be real for the same
    reason: an untrained HalfCheetah scores about -160 to -210, and -180 -> -160 -> -208 (a gain of
    12%) is noise, not a policy that learned and collapsed; the Ant's 944 -> 1113 (18%) is real.
    A collapsed run keeps training (it may recover); the flag is logged as ``train/collapsed``
    and in the summary. The history is part of the checkpoint's metadata, so a resumed run
    judges the same way."""

    def __init__(self, n_agents: int, fraction=0.5, min_gain=0.15, min_fall=0.25, history=None):
        self.fraction, self.min_gain, self.min_fall = fraction, min_gain, min_fall
        h = history or {}
        self.first = list(h.get("first", [None] * n_agents))
        self.best = list(h.get("best", [None] * n_agents))
        self.collapsed = list(h.get("collapsed", [False] * n_agents))
        self.ever = list(h.get("ever", [False] * n_agents))

    def update(self, i: int, ret: float) -> bool:
        """Records agent ``i``'s evaluation return; True when it is collapsed now."""
        if not math.isfinite(ret):
            return self.collapsed[i]
        if self.first[i] is None:
            self.first[i] = self.best[i] = ret
        self.best[i] = max(self.best[i], ret)
        gain = self.best[i] - self.first[i]
        real = gain > self.min_gain * abs(self.first[i]) + 1.0
        fall = self.best[i] - ret
        big = fall > self.min_fall * abs(self.best[i]) + 1.0
        self.collapsed[i] = bool(real and big and fall > self.fraction * gain)
        self.ever[i] = self.ever[i] or self.collapsed[i]
        return self.collapsed[i]

    def history(self) -> dict:
        return {"first": self.first, "best": self.best, "collapsed": self.collapsed, "ever": self.ever}


def _mean_row(rows: list[dict], n_agents: int) -> dict:
    """The batch's progress row: means over agents, total throughput over all of them."""
    out: dict = {"agents": rows}
    for key in rows[0]:
        vals = [r[key] for r in rows if key in r and isinstance(r[key], int | float)]
        vals = [v for v in vals if math.isfinite(v)]
        if vals:
            out[key] = float(np.mean(vals))
    out["perf/env_steps_per_s"] = rows[0]["perf/env_steps_per_s"] * n_agents
    out["env_steps"] = rows[0]["env_steps"]
    return out
