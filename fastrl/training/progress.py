"""Where a run stands between chunks: its position (saved with every checkpoint) with the
collapse watch and the ``stop_at_return`` record that the evaluation keeps there
(``fastrl.training.evaluation``), divergence, and why the run ends."""

from __future__ import annotations

import dataclasses
import math
import sys
import time

from fastrl.runtime import devices
from fastrl.training.run_setup import Agents, Setup


@dataclasses.dataclass
class Progress:
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
    def fresh(cls, n_agents: int) -> Progress:
        return cls(0, 0, 0.0, CollapseWatch(n_agents), [None] * n_agents, [False] * n_agents, 0)

    @classmethod
    def from_meta(cls, meta: dict, n_agents: int) -> Progress:
        chunk, wall = int(meta["chunk"]), float(meta["wall_s"])
        watch = CollapseWatch(n_agents, history=meta["eval_history"])
        reached = list(meta["reached"])
        return cls(chunk, int(meta["updates"]), wall, watch, reached, [False] * n_agents, chunk, wall)

    def advance(self, seconds: float, updates: int) -> None:
        self.chunk += 1
        self.updates += updates
        self.wall += seconds

    def done(self, setup: Setup) -> bool:
        return self.updates >= setup.total_updates

    def meta(self, config: dict, env_steps: int) -> dict:
        """The checkpoint's metadata: the config, this position and the time of saving
        (``saved_at``, seconds since the Unix epoch)."""
        return {"config": config, "chunk": self.chunk, "updates": self.updates,
                "env_steps": env_steps, "wall_s": self.wall, "eval_history": self.watch.history(),
                "reached": self.reached, "saved_at": time.time()}  # fmt: skip


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


def diverged(agents_: Agents, progress: Progress, rows: list[dict]) -> bool:
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


class Clock:
    """This invocation's time limit (``train.max_seconds``), counted from its start."""

    def __init__(self, limit: float | None):
        self.limit, self.start = limit, time.perf_counter()

    def left(self) -> float:
        """Seconds left (infinite without a limit)."""
        return math.inf if self.limit is None else self.limit - (time.perf_counter() - self.start)

    def out(self) -> bool:
        """Whether the limit is reached (process 0's clock decides for all processes)."""
        return self.limit is not None and bool(devices.agreed(self.left() <= 0))


def stop_reason(setup: Setup, progress: Progress, interrupted: bool, clock: Clock) -> str | None:
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
