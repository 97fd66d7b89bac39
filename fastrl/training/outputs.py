"""A run's outputs: each chunk's rows (one per agent), the progress line, TensorBoard and
``metrics.csv`` (rows truncated on resume, damaged rows set aside)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

from fastrl.training import files
from fastrl.training.config import RunConfig
from fastrl.training.progress import Progress
from fastrl.training.run_setup import Setup


def open_outputs(setup: Setup, run_dir: Path, chunk: int, env_steps: int) -> list[Outputs]:
    """Each agent's outputs: the run folder's own for a single run, ``agents/<tag>/`` (with the
    agent's own config.json) for each agent of a batch."""
    if not setup.agents.batched:
        return [Outputs(run_dir, setup.cfg, chunk, env_steps)]
    outs = []
    for agent_dir, config in agent_dirs(setup, run_dir):
        agent_dir.mkdir(parents=True, exist_ok=True)
        files.write_text(agent_dir / "config.json", json.dumps(config.to_dict(), indent=2))
        outs.append(Outputs(agent_dir, config, chunk, env_steps))
    return outs


def agent_dirs(setup: Setup, run_dir: Path) -> tuple[tuple[Path, RunConfig], ...]:
    """Each agent's folder and config: the run folder for a single run, ``agents/<tag>/`` in a batch."""
    if not setup.agents.batched:
        return ((run_dir, setup.cfg),)
    return tuple((run_dir / "agents" / spec.tag, spec.config) for spec in setup.agents.specs)


def report_chunk(setup: Setup, progress: Progress, rows: list[dict], state, dt: float, n: int,
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
    row = mean_row(rows, setup.agents.n) if setup.agents.batched else rows[0]
    progress.train_return = row.get("train/episode_return", progress.train_return)
    if setup.cfg.logger.progress and jax.process_index() == 0:
        print(progress_line(row, setup.total_steps, progress.wall, progress.train_return), flush=True)
    if row.get("env/contact_overflow", 0) > 0 and not progress.overflowed and jax.process_index() == 0:
        progress.overflowed = True
        print(f"[fastrl] warning: chunk {progress.chunk}: the scene's contact budgets dropped contacts "
              f"(env/contact_overflow {row['env/contact_overflow']:.3g}, the mean over envs; "
              "more contact slots: +env.options.nconmax=N; docs/physics.md)",
              file=sys.stderr, flush=True)  # fmt: skip


def write_rows(setup: Setup, rows: list[dict], outs: list[Outputs]) -> dict:
    """Writes each agent's completed row (evaluation included) to its outputs; returns the run's
    row (a batch's means)."""
    for r, out in zip(rows, outs, strict=True):
        out.log(r)
    return mean_row(rows, setup.agents.n) if setup.agents.batched else rows[0]


def close_outputs(outs: list[Outputs]) -> None:
    """Closes each agent's logs. Logs that cannot be flushed (the full disk that ended the run)
    are said to be not updated."""
    for out in outs:
        try:
            out.close()
        except OSError as e:
            print(f"[fastrl] warning: the outputs of {out.run_dir} were not updated: {e.strerror or e}",
                  file=sys.stderr)  # fmt: skip


def mean_row(rows: list[dict], n_agents: int) -> dict:
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


class Outputs:
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
        header, rows, damaged = read_csv(self.csv_path)
        if damaged:
            aside = self.csv_path.with_name(f"{self.csv_path.name}.damaged-{time.strftime('%Y%m%d-%H%M%S')}")
            files.write_text(aside, "".join(damaged))
            print(f"[fastrl] warning: {len(damaged)} damaged row(s) of {self.csv_path} (a write cut short) "
                  f"set aside in {aside.name}; the run continues", file=sys.stderr)  # fmt: skip
        if header is None:
            return
        chunks = header.index("chunk")
        keep = [r for r in rows if int(r[chunks]) <= chunk]
        files.write_text(self.csv_path, csv_text([header, *keep]))

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
            _, rows, _ = read_csv(self.csv_path)
            table = [fields + extra, *(r + [""] * len(extra) for r in rows)]
            files.write_text(self.csv_path, csv_text(table))
        lines = [] if fields else [extra]
        fields = fields + extra
        lines.append([row.get(k, "") for k in fields])
        files.append_text(self.csv_path, csv_text(lines))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def read_csv(path: Path) -> tuple[list[str] | None, list[list[str]], list[str]]:
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


def csv_text(rows: list[list[str]]) -> str:
    """``rows`` as CSV text."""
    buf = io.StringIO()
    csv.writer(buf).writerows(rows)
    return buf.getvalue()


def progress_line(row: dict, total_steps: int, elapsed: float, train_return: float) -> str:
    """The progress line of a chunk's row: bar, env steps, throughput, training return, time."""
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
