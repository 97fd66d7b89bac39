"""The training runner: a host loop over chunks, each chunk ONE compiled program.

A chunk is ``lax.scan(learner.update, updates_per_chunk)`` jitted with the training state
donated, so the simulator and the learner run without a host round trip per step. Between
chunks the runner logs (TensorBoard, ``metrics.csv``, a progress line), evaluates the
deterministic policy, and checkpoints. Ctrl-C asks the run to stop after the chunk in flight;
it then saves a checkpoint and exits (a second Ctrl-C stops at once, without saving).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import shutil
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fastrl import agents, compile_cache, reference, scale
from fastrl.checkpoint import Checkpointer, CheckpointError
from fastrl.config import RunConfig

CHECKPOINT_DIR = "checkpoints"
# Orbax logs every save step at INFO, JAX its backend probing: keep the run's output readable.
for _name in ("absl", "jax._src.xla_bridge"):
    logging.getLogger(_name).setLevel(logging.WARNING)


class _StopFlag:
    """First SIGINT sets the flag (stop after this chunk); the second raises as usual."""

    def __init__(self):
        self.set = False
        self._previous = None

    def __enter__(self):
        if signal.getsignal(signal.SIGINT) is not None and _main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.set:
            raise KeyboardInterrupt
        self.set = True
        print("\n[fastrl] Ctrl-C: stopping after this chunk and saving a checkpoint (again to abort)",
              file=sys.stderr, flush=True)  # fmt: skip

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _unalias(tree):
    """Fresh buffers for every leaf: donation fails when two leaves share one buffer."""
    return jax.tree.map(lambda x: jnp.array(x, copy=True), tree)


def _reduce(metrics: dict) -> dict[str, float]:
    """Per-chunk scalars from the (updates_per_chunk,) stacked update metrics."""
    m = {k: np.asarray(v) for k, v in scale.to_host(metrics).items()}
    out = {}
    episodes = float(m.pop("train/episodes").sum())
    ret_sum = float(m.pop("train/episode_return_sum").sum())
    out["train/episodes"] = episodes
    if episodes > 0:
        out["train/episode_return"] = ret_sum / episodes
    for k, v in m.items():
        out[k] = float(np.mean(v))
    return out


class _Outputs:
    """TensorBoard, metrics.csv and the curve PNG of one run folder."""

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
        """Drops rows logged after the checkpoint being resumed, so the curve has no duplicates."""
        with self.csv_path.open() as f:
            rows = list(csv.DictReader(f))
        if not rows:
            return
        fields = list(rows[0])
        keep = [r for r in rows if int(r["chunk"]) <= chunk]
        with self.csv_path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(keep)

    def log(self, row: dict[str, float]) -> None:
        step = int(row["env_steps"])
        if self.writer is not None:
            for k, v in row.items():
                if "/" in k and math.isfinite(v):
                    self.writer.add_scalar(k, v, step)
            self.writer.flush()
        if self.cfg.logger.csv:
            new = not self.csv_path.exists()
            fields = None if new else next(csv.reader(self.csv_path.open()))
            fields = fields or list(row)
            with self.csv_path.open("a", newline="") as f:
                w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
                if new:
                    w.writeheader()
                w.writerow({k: row.get(k, "") for k in fields})

    def plot(self) -> None:
        if not (self.cfg.logger.plot and self.cfg.logger.csv and self.csv_path.exists()):
            return
        from fastrl.report import plot_run

        plot_run(
            self.csv_path, self.run_dir / "curve.png", title=f"{self.cfg.env.name} / {self.cfg.algo_name}"
        )

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _progress(row: dict, total_steps: int, elapsed: float) -> str:
    steps = int(row["env_steps"])
    frac = min(1.0, steps / total_steps)
    rate = row.get("perf/env_steps_per_s", float("nan"))
    eta = (total_steps - steps) / rate if rate and rate > 0 else float("nan")
    bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
    ret = row.get("eval/episode_return", row.get("train/episode_return", float("nan")))
    which = "eval" if "eval/episode_return" in row else "train"
    return (
        f"[{bar}] {100 * frac:5.1f}% {steps:>11,d} steps | {rate:>9,.0f} steps/s | "
        f"{which} return {ret:9.2f} | {elapsed:7.0f}s elapsed, ETA {eta:6.0f}s"
    )


def train(
    cfg: RunConfig,
    run_dir: str | Path,
    resume: bool = False,
    on_chunk=None,
    resume_step: int | None = None,
    record: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Runs (or resumes) training into ``run_dir``.

    With ``train.num_seeds > 1`` or a ``train.vmap_sweep`` the run is a batch of agents in one
    program (``fastrl.scale``): each agent logs into ``run_dir/agents/<tag>/`` (its config,
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
    with RunDirLock(run_dir):
        return _train(cfg, run_dir, resume, on_chunk, resume_step, record or {})


def _train(cfg, run_dir: Path, resume: bool, on_chunk, resume_step, record) -> dict[str, Any]:
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR, keep=cfg.checkpoint.keep)
    if not resume and ckpt.latest_step() is not None:
        ckpt.close()
        raise CheckpointError(
            f"{run_dir} already holds checkpoints of a run; continue it with resume={run_dir}, or "
            "choose a new run dir (nothing was changed)"
        )
    env = cfg.env.make()
    specs = scale.expand(cfg)
    n_agents = len(specs)
    # The learner is built twice: first to learn its env steps per update, then with the run's
    # total updates (which set learning-rate schedules). Building is cheap; nothing is traced.
    steps_per_update = agents.make_learner(cfg.algo_name, cfg.algo, env, cfg.network, 1).env_steps_per_update
    total_updates = max(1, math.ceil(cfg.train.total_env_steps / steps_per_update))
    k = cfg.train.updates_per_chunk
    n_chunks = math.ceil(total_updates / k)
    mesh = scale.mesh()
    if n_agents > 1:
        learner = scale.batch_learner(cfg, specs, env, n_chunks * k)
        init_key = scale.init_keys(specs)
    else:
        split = mesh if scale.learner_splits(cfg, mesh) else None
        learner = agents.make_learner(cfg.algo_name, cfg.algo, env, cfg.network, n_chunks * k, mesh=split)
        init_key = jax.random.PRNGKey(cfg.seed)
    config = cfg.to_dict()

    shardings = None
    if mesh is not None:
        abstract = jax.eval_shape(learner.init, init_key)
        shardings = scale.state_shardings(abstract, mesh, n_agents, getattr(cfg.algo, "num_envs", None))
    jit_init = jax.jit(learner.init) if shardings is None else jax.jit(learner.init, out_shardings=shardings)
    state = jit_init(init_key)
    chunk, wall = 0, 0.0
    watch = CollapseWatch(n_agents)
    # per agent: where its evaluation return first reached train.stop_at_return (None: not yet)
    reached: list[dict | None] = [None] * n_agents
    if resume:
        try:
            state, meta = ckpt.restore_newest(lambda step: ckpt.restore(state, config, step), resume_step)
        except CheckpointError:
            ckpt.close()
            raise
        chunk, wall = int(meta["chunk"]), float(meta["wall_s"])
        watch = CollapseWatch(n_agents, history=meta.get("eval_history"))
        reached = list(meta.get("reached") or reached)
        _set_aside_after(ckpt, run_dir, chunk)
        print(f"[fastrl] resumed {run_dir} at chunk {chunk} ({int(meta['env_steps']):,d} env steps)")
    # The run is valid and owns its folder: only now does anything get written into it.
    _write_text(run_dir / "config.json", json.dumps(config, indent=2))
    for name, text in record.items():
        _write_text(run_dir / name, text)
    state = _unalias(state)
    if shardings is not None:
        state = jax.device_put(state, shardings)

    def run_chunk(s):
        s, metrics = jax.lax.scan(lambda s, _: learner.update(s), s, None, length=k)
        if shardings is not None:  # keep the layout fixed from chunk to chunk
            s = jax.lax.with_sharding_constraint(s, shardings)
        return s, metrics

    t0, cache_before = time.perf_counter(), compile_cache.counts()
    lowered = jax.jit(run_chunk, donate_argnums=0).lower(state)
    trace_s = time.perf_counter() - t0
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    cache_note = compile_cache.describe(cache_before, compile_cache.is_enabled())
    cache_note = f"{trace_s:.1f}s tracing, {cache_note}"
    # A single run's evaluation steps its envs on every device (an Ant evaluation is 1000
    # sequential steps of a small batch: on one of 2 CPU devices it took ~12 s per chunk).
    eval_mesh = (
        mesh if n_agents == 1 and mesh is not None and cfg.train.eval_envs % mesh.devices.size == 0 else None
    )
    evaluate = agents.make_evaluator(env, learner.act, cfg.train.eval_envs, mesh=eval_mesh)
    evaluate = jax.jit(evaluate if n_agents == 1 else jax.vmap(evaluate))
    write_viewer = None
    if cfg.logger.viewer_every:  # a rollout's 3D page every N chunks (agent 0 of a batch)
        from fastrl import viewer

        title = f"{cfg.env.name} / {cfg.algo_name}"
        write_viewer = viewer.make_run_writer(env, learner.act, title, batched=n_agents > 1)
    batch_note = f" x {n_agents} agents in one program" if n_agents > 1 else ""
    print(
        f"[fastrl] {cfg.env.name} / {cfg.algo_name}: {n_chunks} chunks x {k} updates x "
        f"{steps_per_update:,d} env steps{batch_note}; chunk compiled in {compile_s:.1f}s ({cache_note}) on "
        f"{scale.describe(shardings, mesh)}; run dir {run_dir}"
    )
    if cfg.env.integrator is not None or cfg.env.solver_iterations is not None:
        physics_note = reference.physics_label(env)
        print(f"[fastrl] evaluation returns are at this run's physics ({physics_note}); the score in the "
              f"reference simulator: python -m fastrl.evaluate {run_dir} --reference")  # fmt: skip
    if n_agents > 1:
        outs = []
        for spec in specs:
            agent_dir = run_dir / "agents" / spec.tag
            agent_dir.mkdir(parents=True, exist_ok=True)
            (agent_dir / "config.json").write_text(json.dumps(spec.config.to_dict(), indent=2))
            outs.append(_Outputs(agent_dir, spec.config, chunk, _env_steps(state)))
    else:
        outs = [_Outputs(run_dir, cfg, chunk, _env_steps(state))]
    diverged = [False] * n_agents
    status, row, start_chunk = "done", {}, chunk
    save = lambda: ckpt.save(chunk, state, _meta(config, chunk, state, wall, watch, reached))  # noqa: E731
    try:
        with _StopFlag() as stop:
            while chunk < n_chunks:
                t = time.perf_counter()
                new_state, metrics = compiled(state)
                if n_agents == 1:
                    rows = [_reduce(metrics)]
                else:
                    rows = [_reduce(jax.tree.map(lambda x, i=i: x[:, i], metrics)) for i in range(n_agents)]
                for i, r in enumerate(rows):
                    losses = [v for key, v in r.items() if key.startswith("loss/")]
                    if not diverged[i] and not all(math.isfinite(v) for v in losses):
                        diverged[i] = True
                        who = f"agent {specs[i].tag} " if n_agents > 1 else ""
                        print(f"[fastrl] {who}training diverged (non-finite loss) in chunk {chunk + 1}",
                              file=sys.stderr)  # fmt: skip
                if all(diverged):
                    status, state = "diverged", new_state  # reported, never saved
                    msg = "[fastrl] the last good checkpoint is kept. Try a smaller learning rate or batch."
                    print(msg, file=sys.stderr)
                    break
                state, chunk = new_state, chunk + 1
                dt = time.perf_counter() - t
                wall += dt
                every = cfg.train.eval_every
                # Chunk 1 always evaluates: metrics.csv takes its columns from the first row.
                if chunk in (1, n_chunks) or (every and chunk % every == 0):
                    keys = [jax.random.fold_in(jax.random.PRNGKey(s.seed + 1), chunk) for s in specs]
                    key = keys[0] if n_agents == 1 else jnp.stack(keys)
                    ret, length, final = scale.to_host(evaluate(learner.policy_params(state), key))
                    ret, length = (np.asarray(x).reshape(n_agents, -1) for x in (ret, length))
                    final = {k: np.asarray(v).reshape(n_agents, -1) for k, v in final.items()}
                    for i, r in enumerate(rows):
                        r.update({"eval/episode_return": float(ret[i].mean()),
                                  "eval/episode_return_std": float(ret[i].std()),
                                  "eval/episode_length": float(length[i].mean())})  # fmt: skip
                        r.update({f"eval/{k}": float(v[i].mean()) for k, v in final.items()})
                        was = watch.collapsed[i]
                        if watch.update(i, r["eval/episode_return"]) and not was:
                            who = f"agent {specs[i].tag} " if n_agents > 1 else ""
                            print(f"[fastrl] {who}training collapsed in chunk {chunk}: eval return "
                                  f"{r['eval/episode_return']:.4g}, best {watch.best[i]:.4g}, first "
                                  f"{watch.first[i]:.4g}", file=sys.stderr)  # fmt: skip
                        r["train/collapsed"] = float(watch.collapsed[i])
                        target = cfg.train.stop_at_return
                        if target is not None and reached[i] is None and r["eval/episode_return"] >= target:
                            reached[i] = {"chunk": chunk, "env_steps": _env_steps(state, i), "wall_s": wall,
                                          "eval_return": r["eval/episode_return"]}  # fmt: skip
                if write_viewer and (chunk == n_chunks or chunk % cfg.logger.viewer_every == 0):
                    params = scale.to_host(learner.policy_params(state))  # every process gathers
                    if jax.process_index() == 0:
                        write_viewer(run_dir, chunk, params, jax.random.PRNGKey(cfg.seed + 1))
                for i, (r, out) in enumerate(zip(rows, outs, strict=True)):
                    r.update(chunk=chunk, env_steps=_env_steps(state, i), wall_s=wall, time_unix=time.time())
                    r["perf/env_steps_per_s"] = k * steps_per_update / dt
                    r["perf/compile_s"] = compile_s
                    if n_agents > 1:
                        r["train/diverged"] = float(diverged[i])
                    out.log(r)
                row = rows[0] if n_agents == 1 else _mean_row(rows, n_agents)
                if cfg.logger.progress and jax.process_index() == 0:
                    print(_progress(row, n_chunks * k * steps_per_update, wall), flush=True)
                if on_chunk is not None:
                    on_chunk(chunk, row)
                all_reached = cfg.train.stop_at_return is not None and all(x is not None for x in reached)
                stopping = stop.set or (
                    cfg.train.stop_after_chunks is not None
                    and chunk - start_chunk >= cfg.train.stop_after_chunks
                )
                if chunk == n_chunks or stopping or all_reached or chunk % cfg.checkpoint.every == 0:
                    save()
                if all_reached:
                    status = "reached"
                    who = "every agent's" if n_agents > 1 else "the"
                    print(f"[fastrl] {who} evaluation return reached train.stop_at_return="
                          f"{cfg.train.stop_at_return:g} by chunk {chunk} ({wall:.0f}s of training); "
                          "stopping", flush=True)  # fmt: skip
                    break
                if stopping:
                    status = "stopped"
                    why = "Ctrl-C" if stop.set else f"train.stop_after_chunks={cfg.train.stop_after_chunks}"
                    print(f"[fastrl] stopped by {why} after chunk {chunk} of {n_chunks}, checkpoint saved; "
                          f"continue with: python -m fastrl.train resume={run_dir}", flush=True)  # fmt: skip
                    break
    finally:
        for out in outs:
            out.plot()
            out.close()
        ckpt.close()
    summary = {"status": status, "chunks": chunk, "env_steps": _env_steps(state), "compile_s": compile_s,
               "wall_s": wall, "last": row, "run_dir": str(run_dir), "interrupted": stop.set}  # fmt: skip
    summary["collapsed"] = watch.collapsed if n_agents > 1 else watch.collapsed[0]
    summary["best_eval_return"] = watch.best if n_agents > 1 else watch.best[0]
    if cfg.train.stop_at_return is not None:
        summary["reached"] = reached if n_agents > 1 else reached[0]
    if n_agents > 1:
        summary["agents"] = [s.tag for s in specs]
        summary["diverged_agents"] = [s.tag for s, d in zip(specs, diverged, strict=True) if d]
        summary["collapsed_agents"] = [s.tag for s, c in zip(specs, watch.collapsed, strict=True) if c]
    return summary


class RunDirError(RuntimeError):
    """The run folder cannot be used (another process is running in it); the message says why."""


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
        try:
            import fcntl
        except ImportError:
            return self
        if jax.process_index() != 0:
            return self
        f = self.path.open("a+")
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


def _write_text(path: Path, text: str) -> None:
    """Writes ``text`` to ``path`` through a temporary file and a rename, so a crash mid-write
    never leaves a half-written file in place of a good one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


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


def _env_steps(state, agent: int | None = None) -> int:
    """Env steps so far: of one agent of a batch, or the most of any agent."""
    steps = np.asarray(scale.to_host(state.env_steps))
    return int(steps.reshape(-1)[agent] if agent is not None else steps.max())


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


def _meta(config: dict, chunk: int, state, wall: float, watch: CollapseWatch, reached: list) -> dict:
    return {"config": config, "chunk": chunk, "env_steps": _env_steps(state), "wall_s": wall,
            "eval_history": watch.history(), "reached": reached}  # fmt: skip
