"""The tools as the training runner's callbacks: what the command line hands ``runner.train``
(``standard()``: the evaluation, ``fastrl.training.evaluation.Evaluation``, first, then these).

- ``PhysicsNote``: at the start, a note when the run's physics is not its env's own (the
  evaluation returns are then at this run's physics, and ``--reference`` scores the policy in
  the reference simulator).
- ``ViewerPages``: a rollout's 3D page every ``logger.viewer_every`` chunks and at the last
  (agent 0 of a batch).
- ``Curves``: each agent's learning curve (``curve.png``) drawn from its ``metrics.csv`` at the
  end.
"""

from __future__ import annotations

import sys

import jax

from fastrl.runtime.devices import to_host
from fastrl.tools import reference, viewer
from fastrl.tools.curve import plot_run
from fastrl.training.evaluation import Evaluation
from fastrl.training.hooks import Callback, ChunkInfo, RunInfo

__all__ = ["Curves", "PhysicsNote", "ViewerPages", "standard"]


def standard() -> list[Callback]:
    """The command line's callbacks, each doing what the run's config asks of it: the
    evaluation first (its ``eval/*`` entries reach the rows the others see)."""
    return [Evaluation(), PhysicsNote(), ViewerPages(), Curves()]


class PhysicsNote(Callback):
    """Where the run's physics is not its env's own (an integrator, solver iterations or timestep
    of its own), says so after the run's first line (process 0 of a multi-host run only)."""

    def on_start(self, run: RunInfo) -> None:
        if jax.process_index() != 0:
            return
        if any(getattr(run.cfg.env, k) is not None for k in ("integrator", "solver_iterations", "timestep")):
            physics_note = reference.physics_label(run.env)
            print(f"[fastrl] evaluation returns are at this run's physics ({physics_note}); the score in the "
                  f"reference simulator: python -m fastrl.evaluate {run.run_dir} --reference")  # fmt: skip


class ViewerPages(Callback):
    """A rollout's 3D page every ``logger.viewer_every`` chunks and at the last (agent 0 of a batch)."""

    def __init__(self):
        self.write, self.every = None, 0

    def on_start(self, run: RunInfo) -> None:
        self.every = run.cfg.logger.viewer_every
        if self.every:
            title = f"{run.cfg.env.name} / {run.cfg.algo_name}"
            self.write = viewer.make_run_writer(run.env, run.learner.act, title, batched=run.batched)

    def on_chunk(self, run: RunInfo, chunk: ChunkInfo) -> None:
        if self.write is None or not (chunk.last or chunk.index % self.every == 0):
            return
        params = to_host(run.learner.policy_params(chunk.state))  # every process gathers
        if jax.process_index() == 0:
            self.write(run.run_dir, chunk.index, params, jax.random.PRNGKey(run.cfg.seed + 1))


class Curves(Callback):
    """Draws each agent's curve from its ``metrics.csv`` at the end. A curve that cannot be
    written (the full disk that ended the run) keeps the previous one, and says so."""

    def on_end(self, run: RunInfo) -> None:
        if jax.process_index() != 0:  # multi-host runs: one process writes the run's outputs
            return
        for folder, cfg in run.outputs:
            if not (cfg.logger.plot and cfg.logger.csv and (folder / "metrics.csv").exists()):
                continue
            try:
                plot_run(
                    folder / "metrics.csv", folder / "curve.png", title=f"{cfg.env.name} / {cfg.algo_name}"
                )
            except OSError as e:
                print(f"[fastrl] warning: the outputs of {folder} were not updated: {e.strerror or e}",
                      file=sys.stderr)  # fmt: skip
