"""Where learning fails: PPO and SAC over learning rate x batch size, judged by the runner.

    python -m experiments.learner_stability                  # PPO and SAC on inverted_pendulum
    python -m experiments.learner_stability --algos ppo      # one learner
    python -m experiments.learner_stability --algos ppo --merge  # redo one, keep the other's cells
    python -m experiments.learner_stability --quick          # tiny, for CI (~1 min)

For each learner and each batch size, ONE training program holds every learning rate x seed as
independent agents (``train.vmap_sweep`` and ``train.num_seeds``, ``fastrl/training/scale.py``); batch
sizes change shapes, so each is its own program. The runner itself classifies every agent
(``fastrl/training/progress.py``):

* **diverged**: a loss became non-finite (the runner flags the agent, ``train/diverged``, and
  never checkpoints a batch whose agents all diverged);
* **collapsed**: at the end its evaluation return had fallen back more than halfway from its best
  to its first evaluation and by more than a quarter of its best, after a real gain
  (``CollapseWatch``, logged as ``train/collapsed``);
* otherwise **learned** when the final deterministic evaluation return reaches ``TARGET`` of the
  task's best return, else **stalled** (trained without failing, but not far enough in the
  budget).

Task: ``inverted_pendulum`` (return 1000 = balanced for the whole episode), cheap enough that a
grid of 4-5 batch sizes x 9 learning rates (1e-4 to 1, half decades) x 2 seeds runs in minutes
per learner on 2 cores.

* PPO uses the shipped ``experiment/inverted_pendulum_ppo`` settings (64 envs x 16 steps per
  rollout, 4 epochs) over 150k env steps; "batch size" is the minibatch size (SB3's
  ``batch_size``): the rollout of 1024 steps split into 32, 8, 4, 2 or 1 minibatches of 32, 128,
  256 (shipped), 512 or 1024.
* SAC: 16 envs, 4 gradient updates per 16 env steps, 1,000 random steps before learning,
  ``[64, 64]`` networks, 40k env steps; "batch size" is the replay sample per gradient update
  (32 to 1024).

Writes ``experiments/results/learner_stability.{json,md,png}`` (``_quick`` in quick mode).
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import tempfile
import time

import jax
import numpy as np
from hydra import compose, initialize_config_dir

import fastrl
from experiments import results
from fastrl.cli.conf import CONF_DIR
from fastrl.cli.train import run

TARGET = 0.9  # of the best return, 1000 on inverted_pendulum
BEST_RETURN = 1000.0
LRS = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0]

SETUPS = {
    "ppo": {
        "overrides": ["env=inverted_pendulum", "algo=ppo", "train.total_env_steps=150000"],
        "batch_key": "algo.num_minibatches",
        # minibatch size -> number of minibatches of the 64 x 16 = 1024-step rollout
        "batches": {32: 32, 128: 8, 256: 4, 512: 2, 1024: 1},
        "shipped": (1e-3, 256),
        "quick": {"batches": {256: 4}, "steps": 4096},
    },
    "sac": {
        "overrides": [
            "env=inverted_pendulum",
            "algo=sac",
            "algo.num_envs=16",
            "algo.grad_updates_per_update=4",
            "algo.learning_starts=1000",
            "algo.buffer_size=100000",
            "network.policy_hidden=[64,64]",
            "network.value_hidden=[64,64]",
            "train.total_env_steps=40000",
            "train.updates_per_chunk=100",
        ],
        "batch_key": "algo.batch_size",
        "batches": {32: 32, 128: 128, 256: 256, 1024: 1024},
        "shipped": (3e-4, 256),
        "quick": {"batches": {256: 256}, "steps": 1500},
    },
}


def classify(final: float, collapsed: bool, diverged: bool) -> str:
    if diverged:
        return "diverged"
    if collapsed:
        return "collapsed"
    return "learned" if final >= TARGET * BEST_RETURN else "stalled"


def run_cell(algo: str, batch: int, lrs: list[float], seeds: int, quick: bool) -> dict:
    """One program: every learning rate x seed at one batch size."""
    setup = SETUPS[algo]
    value = (setup["quick"] if quick else setup)["batches"][batch]
    overrides = [
        *setup["overrides"],
        f"{setup['batch_key']}={value}",
        "logger=quiet",
        f"train.num_seeds={seeds}",
        "train.vmap_sweep={learning_rate: [" + ", ".join(f"{lr:g}" for lr in lrs) + "]}",
    ]
    if quick:
        overrides += [
            f"train.total_env_steps={setup['quick']['steps']}",
            "train.eval_envs=2",
            "env.episode_length=100",
        ]
        overrides += ["train.eval_every=1"]
        if algo == "sac":
            overrides += ["algo.learning_starts=500", "train.updates_per_chunk=20"]
    else:
        overrides += ["train.eval_every=2", "train.eval_envs=8"]  # evaluation would cost more than training
    with tempfile.TemporaryDirectory() as tmp, initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        cfg = compose("train", overrides=[*overrides, f"run_dir={tmp}/run"])
        t0 = time.perf_counter()
        summary = run(cfg)
        wall = time.perf_counter() - t0
        agents_dir = pathlib.Path(tmp) / "run" / "agents"
        finals = []
        for tag in summary["agents"]:
            rows = (agents_dir / tag / "metrics.csv").read_text().strip().splitlines()
            header, last = rows[0].split(","), rows[-1].split(",")
            cell = dict(zip(header, last, strict=False)).get("eval/episode_return", "")
            finals.append(float(cell) if cell not in ("", "nan") else float("nan"))
    agents = []
    for i, tag in enumerate(summary["agents"]):
        lr, seed = lrs[i // seeds], i % seeds
        diverged = tag in summary["diverged_agents"]
        collapsed = bool(summary["collapsed"][i])
        best = summary["best_eval_return"][i]
        agents.append(
            {
                "learning_rate": lr,
                "seed": seed,
                "final_return": finals[i],
                "best_return": best,
                "diverged": diverged,
                "collapsed": collapsed,
                "outcome": classify(finals[i], collapsed, diverged),
            }
        )
    return {
        "algo": algo,
        "batch_size": batch,
        "agents": agents,
        "wall_s": wall,
        "compile_s": summary["compile_s"],
        "status": summary["status"],
    }


def cells_table(cells: list[dict]) -> dict:
    """(algo, batch, lr) -> {outcomes, median final return}."""
    out = {}
    for c in cells:
        for lr in sorted({a["learning_rate"] for a in c["agents"]}):
            ag = [a for a in c["agents"] if a["learning_rate"] == lr]
            # a diverged agent's return means nothing (its parameters are not finite)
            finite = [a["final_return"] for a in ag if np.isfinite(a["final_return"]) and not a["diverged"]]
            out[(c["algo"], c["batch_size"], lr)] = {
                "outcomes": [a["outcome"] for a in ag],
                "median_final": statistics.median(finite) if finite else float("nan"),
            }
    return out


def markdown(result: dict) -> str:
    """Per learner, the batch x learning rate grid of outcomes and median final returns."""
    table = cells_table(result["cells"])
    lines = [
        "# Learner stability: PPO and SAC over learning rate x batch size (inverted_pendulum)",
        "",
        f"Command: `{result['command']}`. Machine: {result['machine']}. JAX {result['jax']}.",
        f"Each cell: {result['seeds']} seeds; outcome judged by the runner (D diverged: non-finite loss; "
        f"C collapsed: final eval return fell back more than halfway from its best to its first; "
        f"L learned: final eval return >= {TARGET * BEST_RETURN:g}; S stalled: none of those). "
        "The number is the median final deterministic eval return. `*` marks the shipped setting.",
        "",
    ]
    for algo in result["algos"]:
        cells = [c for c in result["cells"] if c["algo"] == algo]
        lrs = sorted({a["learning_rate"] for c in cells for a in c["agents"]})
        shipped = tuple(SETUPS[algo]["shipped"])
        lines += [
            f"## {algo.upper()}",
            "",
            "| batch \\ learning rate | " + " | ".join(f"{lr:g}" for lr in lrs) + " |",
            "| --- |" + " ---: |" * len(lrs),
        ]
        for c in sorted(cells, key=lambda c: c["batch_size"]):
            row = []
            for lr in lrs:
                t = table[(algo, c["batch_size"], lr)]
                tags = "".join(o[0].upper() for o in t["outcomes"])
                mark = "*" if (lr, c["batch_size"]) == shipped else ""
                row.append(f"{mark}{tags} {t['median_final']:.0f}".replace(" nan", ""))
            lines.append(f"| {c['batch_size']} | " + " | ".join(row) + " |")
        walls = ", ".join(
            f"batch {c['batch_size']}: {c['wall_s']:.0f} s ({c['compile_s']:.0f} s compile)"
            for c in sorted(cells, key=lambda c: c["batch_size"])
        )
        lines += [
            "",
            f"Wall time per program ({len(lrs)} learning rates x {result['seeds']} seeds): {walls}.",
            "",
        ]
        counts = {}
        for c in cells:
            for a in c["agents"]:
                counts[a["outcome"]] = counts.get(a["outcome"], 0) + 1
        lines += [
            "Outcomes over all agents: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + ".",
            "",
        ]
    return "\n".join(lines)


def plot(result: dict):
    """Per learner, the grid coloured by the share of agents that diverged or collapsed."""
    plt = results.pyplot()
    table = cells_table(result["cells"])
    algos = result["algos"]
    fig, axes = plt.subplots(1, len(algos), figsize=(5.5 * len(algos), 4), squeeze=False)
    for ax, algo in zip(axes[0], algos, strict=True):
        cells = [c for c in result["cells"] if c["algo"] == algo]
        lrs = sorted({a["learning_rate"] for c in cells for a in c["agents"]})
        batches = sorted(c["batch_size"] for c in cells)
        grid = np.zeros((len(batches), len(lrs)))
        for i, b in enumerate(batches):
            for j, lr in enumerate(lrs):
                out = table[(algo, b, lr)]["outcomes"]
                grid[i, j] = sum(o in ("diverged", "collapsed") for o in out) / len(out)
        ax.imshow(grid, cmap="Reds", vmin=0, vmax=1, origin="lower", aspect="auto")
        for i, b in enumerate(batches):
            for j, lr in enumerate(lrs):
                t = table[(algo, b, lr)]
                tags = "".join(o[0].upper() for o in t["outcomes"])
                label = f"{tags}\n{t['median_final']:.0f}".replace("\nnan", "")
                colour = "white" if grid[i, j] > 0.7 else "black"
                ax.text(j, i, label, ha="center", va="center", fontsize=7, color=colour)
                if (lr, b) == tuple(SETUPS[algo]["shipped"]):
                    ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2, ec="blue"))
        ax.set_xticks(range(len(lrs)), [f"{lr:g}" for lr in lrs], rotation=45)
        ax.set_yticks(range(len(batches)), [str(b) for b in batches])
        ax.set_xlabel("learning rate")
        ax.set_ylabel("batch size" + (" (minibatch)" if algo == "ppo" else " (replay sample)"))
        ax.set_title(f"{algo.upper()} on inverted_pendulum: red = diverged or collapsed")
    fig.tight_layout()
    return fig


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="1 batch size x 2 learning rates, tiny budgets")
    parser.add_argument("--algos", nargs="+", choices=sorted(SETUPS), default=sorted(SETUPS))
    parser.add_argument("--seeds", type=int, default=None, help="per cell (default 2; quick 1)")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument(
        "--merge", action="store_true", help="keep the other learners already in the output JSON"
    )
    args = parser.parse_args()
    seeds = args.seeds or (1 if args.quick else 2)
    # Quick: a sane rate and an absurd one (1e4), which must be caught as diverged, not left NaN.
    lrs = [1e-3, 1e4] if args.quick else LRS
    cells, algos = [], list(args.algos)
    stem = "learner_stability" + ("_quick" if args.quick else "")
    previous = args.out / f"{stem}.json"
    if args.merge and previous.exists():
        old = results.load(previous)
        cells = [c for c in old["cells"] if c["algo"] not in args.algos]
        algos = sorted({c["algo"] for c in cells} | set(args.algos))
    for algo in args.algos:
        setup = SETUPS[algo]
        for batch in (setup["quick"] if args.quick else setup)["batches"]:
            print(
                f"[learner_stability] {algo} batch {batch}: {len(lrs)} learning rates x {seeds} seeds",
                flush=True,
            )
            cells.append(run_cell(algo, batch, lrs, seeds, args.quick))
            c = cells[-1]
            print(
                f"  {c['wall_s']:.0f} s: "
                + ", ".join(
                    f"{a['learning_rate']:g}/{a['seed']} {a['outcome']} {a['final_return']:.0f}"
                    for a in c["agents"]
                ),
                flush=True,
            )
    result = {
        "command": "python -m experiments.learner_stability" + (" --quick" if args.quick else ""),
        "machine": results.machine(),
        "jax": jax.__version__,
        "algos": algos,
        "seeds": seeds,
        "cells": cells,
    }
    text = markdown(result)
    results.save(args.out, stem, result, text, plot(result))
    print(text)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
