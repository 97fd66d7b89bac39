"""The compiled chunk: a loop of ``learner.update`` jitted once with the training state donated,
compiled on a worker thread, and how many updates the next chunk runs."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp

from fastrl.runtime import compile_cache, devices
from fastrl.training.progress import Clock, Progress
from fastrl.training.run_setup import Setup


@dataclasses.dataclass(frozen=True)
class Program:
    """The compiled chunk and how compiling it went."""

    run: Callable
    compile_s: float
    note: str


class Compiling:
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
            self._out.append(Program(run, time.perf_counter() - t0, f"{traced_note}, {cache_note}"))
        except BaseException as e:  # handed to the main thread by result()
            self._out.append(e)

    def wait(self) -> None:
        """Waits for the compile to end (whatever its outcome), so the process can exit cleanly."""
        self._thread.join()

    def result(self) -> Program:
        self._thread.join()
        (out,) = self._out
        if isinstance(out, BaseException):
            raise out
        return out


def compile_chunk(setup: Setup) -> Compiling:
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
        return Compiling(lowered, t0, f"{time.perf_counter() - t0:.1f}s tracing")
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

    return Compiling(lowered, t0, traced_note, wrap)


class ChunkSizer:
    """How many updates the next chunk runs: ``train.updates_per_chunk`` when fixed; else one
    update first, then as many as the last chunk's speed fits in ``train.chunk_seconds``. Under
    a time limit a chunk is cut short to end at it, once the speed is known."""

    def __init__(self, setup: Setup):
        self.fixed, self.seconds = setup.cfg.train.updates_per_chunk, setup.cfg.train.chunk_seconds
        self.total = setup.total_updates
        self.per_update: float | None = None

    def next(self, progress: Progress, clock: Clock) -> int:
        if self.fixed is not None:
            n = self.fixed
        elif self.per_update is None:
            n = 1
        else:  # by time: process 0's measurement decides for all processes
            n = devices.agreed(max(1, round(min(self.seconds, clock.left()) / self.per_update)))
        return min(n, self.total - progress.updates)

    def observe(self, n: int, seconds: float) -> None:
        self.per_update = seconds / n
