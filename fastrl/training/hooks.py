"""What the runner calls between chunks, and what it shows them: ``Callback`` (``on_start``,
``on_chunk``, ``on_end``), ``RunInfo`` (the run) and ``ChunkInfo`` (the chunk just run)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from fastrl.agents.base import Learner
from fastrl.training.config import RunConfig
from fastrl.training.progress import Progress
from fastrl.training.run_setup import Setup

__all__ = ["Callback", "ChunkInfo", "RunInfo"]


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """What a callback sees of a run.

    Fields:
      setup    what the run is (``run_setup.Setup``): config, env, agents, learner, total
               updates, devices
      run_dir  the run's folder
      outputs  each agent's folder and config: the run folder for a single run,
               ``agents/<tag>/`` for each agent of a batch
    """

    setup: Setup
    run_dir: Path
    outputs: tuple[tuple[Path, RunConfig], ...]

    @property
    def cfg(self) -> RunConfig:
        return self.setup.cfg

    @property
    def env(self) -> Any:
        return self.setup.env

    @property
    def learner(self) -> Learner:
        """The run's learner (``act``, ``policy_params``): of one agent, over a batch's states."""
        return self.setup.learner

    @property
    def batched(self) -> bool:
        """The state's leaves have a leading agent axis (a batch of agents)."""
        return self.setup.agents.batched


@dataclasses.dataclass(frozen=True)
class ChunkInfo:
    """What ``Callback.on_chunk`` sees of the chunk just run.

    Fields:
      index     the chunk's number (chunks done so far)
      updates   learner updates it ran
      last      the run's budget ends with it
      state     the training state after it
      rows      each agent's row of it (one for a single run). A callback may add entries (the
                evaluation adds ``eval/*``): the rows are logged once every callback has run
      progress  where the run stands; the evaluation records its collapse watch and
                ``train.stop_at_return`` record there, which every checkpoint saves, the
                runner stops on and the summary reports
    """

    index: int
    updates: int
    last: bool
    state: Any
    rows: list[dict]
    progress: Progress


class Callback:
    """A piece the caller hands ``train`` to look at the run; each hook does nothing unless
    overridden. Hooks run on every process of a multi-host run: one that writes checks
    ``jax.process_index()``."""

    def on_start(self, run: RunInfo) -> None:
        """After the run's first line, before its first chunk."""

    def on_chunk(self, run: RunInfo, chunk: ChunkInfo) -> None:
        """After each chunk and its progress line, before its rows are logged and its checkpoint
        saved; in the order the callbacks were handed in."""

    def on_end(self, run: RunInfo) -> None:
        """When the run ends (as it returns or raises), before its logs are closed."""
