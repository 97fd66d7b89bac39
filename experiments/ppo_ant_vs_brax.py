"""Learning speed on the Ant: fastrl's PPO vs Brax's own PPO, same machine, one session.

    python experiments/ppo_ant_vs_brax.py --seeds 0 1 2          # ~1.5-2 h on 2 cores
    python experiments/ppo_ant_vs_brax.py --quick                 # tiny, for CI (Brax skipped if absent)

For each seed, runs Brax's PPO on its ``ant`` (spring backend, Brax's published Ant
hyperparameters with 1024 envs and batch 512, as in issue 5) through
``experiments/peers/brax_ppo_ant.py`` in ``.venv-peers``, then fastrl's
``python -m fastrl.train env=ant algo=ppo`` (the shipped ``experiment/ant_ppo`` settings), and
records eval return against wall-clock seconds since the process started (compiles included).
Reports, per learner, the median over seeds of the seconds to first reach ``--target`` (3000),
and the ratio. Writes ``experiments/results/ppo_ant_vs_brax.{json,md,png}``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
PEERS = ROOT / ".venv-peers" / "bin" / "python"
RESULTS = ROOT / "experiments" / "results"


def run_brax(seed: int, steps: int, quick: bool) -> list[tuple[float, int, float]]:
    if not PEERS.exists():
        return []
    cmd = [str(PEERS), str(ROOT / "experiments/peers/brax_ppo_ant.py"), "--seed", str(seed),
           "--num-timesteps", str(steps), "--num-envs", "1024", "--batch-size", "512"]  # fmt: skip
    if quick:
        cmd += ["--num-envs", "16", "--batch-size", "16", "--num-minibatches", "4", "--episode-length", "20",
                "--num-eval-envs", "4", "--num-evals", "2"]  # fmt: skip
    else:
        cmd += ["--num-evals", "20"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=7200)
    curve = []
    for line in out.stdout.splitlines():
        rec = json.loads(line)
        if rec.get("event") == "eval":
            curve.append((rec["elapsed_s"], rec["env_steps"], rec["eval_return"]))
    return curve


def run_fastrl(seed: int, steps: int, quick: bool) -> list[tuple[float, int, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "fastrl.train", "env=ant", "algo=ppo", f"seed={seed}",
               f"run_dir={tmp}/run", f"train.total_env_steps={steps}", "logger=quiet"]  # fmt: skip
        if quick:
            cmd += ["debug=quick"]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT, timeout=7200, capture_output=True)
        total = time.perf_counter() - t0
        rows = (pathlib.Path(tmp) / "run" / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    curve = []
    for row in rows[1:]:
        rec = dict(zip(header, row.split(","), strict=True))
        if rec.get("eval/episode_return"):
            curve.append((float(rec["wall_s"]), int(rec["env_steps"]), float(rec["eval/episode_return"])))
    # wall_s counts training chunks only; add the process's start-up and compile time up front.
    overhead = total - (curve[-1][0] if curve else 0.0)
    return [(t + overhead, s, r) for t, s, r in curve]


def time_to(curve, target: float) -> float | None:
    return next((t for t, _, r in curve if r >= target), None)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--target", type=float, default=3000.0)
    parser.add_argument("--brax-steps", type=int, default=5_000_000)
    parser.add_argument("--fastrl-steps", type=int, default=5_000_000)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--skip-brax", action="store_true")
    parser.add_argument("--out", type=pathlib.Path, default=RESULTS)
    args = parser.parse_args()
    seeds = args.seeds[:1] if args.quick else args.seeds
    runs = []
    for seed in seeds:
        for name, fn, steps in (
            ("brax", run_brax, args.brax_steps),
            ("fastrl", run_fastrl, args.fastrl_steps),
        ):
            if name == "brax" and (args.skip_brax or args.quick):
                continue
            curve = fn(seed, 1024 if args.quick else steps, args.quick)
            runs.append(
                {"learner": name, "seed": seed, "curve": curve, "time_to_target": time_to(curve, args.target)}
            )
            print(json.dumps(runs[-1]), flush=True)
    summary = {}
    for name in ("brax", "fastrl"):
        times = [r["time_to_target"] for r in runs if r["learner"] == name]
        reached = [t for t in times if t is not None]
        median = float(np.median(reached)) if times and len(reached) == len(times) else None
        summary[name] = {"runs": len(times), "reached": len(reached), "median_s": median}
    suffix = "_quick" if args.quick else ""
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"ppo_ant_vs_brax{suffix}.json").write_text(
        json.dumps({"target": args.target, "runs": runs, "summary": summary}, indent=1)
    )
    lines = [f"# PPO on the Ant: seconds to eval return {args.target:g} (this machine, one session)", "",
             "| learner | seeds | reached | median s |", "| --- | ---: | ---: | ---: |"]  # fmt: skip
    for name, s in summary.items():
        med = f"{s['median_s']:.0f}" if s["median_s"] is not None else "not reached by all"
        lines.append(f"| {name} | {s['runs']} | {s['reached']} | {med} |")
    (args.out / f"ppo_ant_vs_brax{suffix}.md").write_text("\n".join(lines) + "\n")
    _plot(runs, args.out / f"ppo_ant_vs_brax{suffix}.png", args.target)


def _plot(runs, path, target):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    colors = {"brax": "tab:orange", "fastrl": "tab:blue"}
    for r in runs:
        if r["curve"]:
            t, _, ret = zip(*r["curve"], strict=True)
            ax.plot(t, ret, color=colors[r["learner"]], alpha=0.8, label=f"{r['learner']} seed {r['seed']}")
    ax.axhline(target, color="gray", ls="--", lw=1)
    ax.set_xlabel("wall-clock seconds (compile included)")
    ax.set_ylabel("eval episode return")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
