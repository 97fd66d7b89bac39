"""The deterministic policy's evaluation between chunks, as one of the runner's callbacks.

``Evaluation`` is the callback the runner uses when its caller names none, and the first the
command line hands it (``fastrl.tools.callbacks.standard``). Its results go three ways: the
``eval/*`` entries of each agent's row (logged with it), and the collapse watch and the
``train.stop_at_return`` record of the run's ``Progress``, which every checkpoint saves, the
runner stops on ("reached") and the summary reports (``collapsed``, ``best_eval_return``,
``reached``). A run without it logs no evaluation, and one with ``train.stop_at_return`` is
refused by the runner.
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

from fastrl import agents
from fastrl.runtime.devices import to_host
from fastrl.training.hooks import Callback, ChunkInfo, RunInfo
from fastrl.training.progress import Progress
from fastrl.training.run_setup import Setup

__all__ = ["Evaluation"]


class Evaluation(Callback):
    """Evaluates the deterministic policy on its schedule (``train.num_evals`` or
    ``train.eval_every``, and after the last chunk): ``eval/*`` into each agent's row, then the
    collapse watch and the ``train.stop_at_return`` record."""

    def on_start(self, run: RunInfo) -> None:
        setup = self.setup = run.setup
        cfg, mesh = setup.cfg, setup.mesh
        # A single run's evaluation steps its envs on every device (an Ant evaluation is 1000
        # sequential steps of a small batch: on one of 2 CPU devices it took ~12 s per chunk).
        split = not setup.agents.batched and mesh is not None and cfg.train.eval_envs % mesh.devices.size == 0
        evaluate = agents.make_evaluator(
            setup.env, setup.learner.act, cfg.train.eval_envs, mesh=mesh if split else None
        )
        self._evaluate = jax.jit(jax.vmap(evaluate) if setup.agents.batched else evaluate)

    def on_chunk(self, run: RunInfo, chunk: ChunkInfo) -> None:
        if due(self.setup, chunk.progress, chunk.updates):
            self.evaluate(chunk.state, chunk.rows, chunk.progress)

    def evaluate(self, state, rows: list[dict], progress: Progress) -> None:
        """Evaluates ``state``'s policy into ``rows``, then watches and records the returns."""
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

    def _watch_collapse(self, rows: list[dict], progress: Progress) -> None:
        watch = progress.watch
        for i, r in enumerate(rows):
            was = watch.collapsed[i]
            if watch.update(i, r["eval/episode_return"]) and not was:
                who = self.setup.agents.who(i)
                print(f"[fastrl] {who}training collapsed in chunk {progress.chunk}: eval return "
                      f"{r['eval/episode_return']:.4g}, best {watch.best[i]:.4g}, first "
                      f"{watch.first[i]:.4g}", file=sys.stderr)  # fmt: skip
            r["train/collapsed"] = float(watch.collapsed[i])

    def _note_reached(self, state, rows: list[dict], progress: Progress) -> None:
        target = self.setup.cfg.train.stop_at_return
        if target is None:
            return
        for i, r in enumerate(rows):
            if progress.reached[i] is None and r["eval/episode_return"] >= target:
                steps = self.setup.agents.env_steps(state, i)
                progress.reached[i] = {"chunk": progress.chunk, "env_steps": steps, "wall_s": progress.wall,
                                       "eval_return": r["eval/episode_return"]}  # fmt: skip


def due(setup: Setup, progress: Progress, n: int) -> bool:
    """Whether the chunk just done (of ``n`` updates) ends with an evaluation: the last always
    does; then every ``train.eval_every`` chunks and chunk 1 (none with eval_every 0), or, with
    eval_every None, the chunks that cross one of ``train.num_evals`` evenly spaced points of the
    run."""
    train, total = setup.cfg.train, setup.total_updates
    if progress.done(setup):
        return True
    if train.eval_every is not None:
        every = train.eval_every
        return every > 0 and (progress.chunk == 1 or progress.chunk % every == 0)
    before, after = progress.updates - n, progress.updates
    return before * train.num_evals // total < after * train.num_evals // total
