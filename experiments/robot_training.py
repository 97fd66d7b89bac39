"""Robot-task training runs against env steps and wall time, beside MuJoCo Playground's result.

    python -m experiments.robot_training RUN_DIR [RUN_DIR ...]
    python -m experiments.robot_training RUN_DIR --merge    # add or replace these runs' rows

For each run (``python -m fastrl.train env=<robot task> algo=ppo ...``), from its
``metrics.csv``: every evaluation (deterministic policy: mean return, episode length and the
env's ``eval_metrics``) and the last chunk's training return, each with its env steps and
training wall time; compile time separately. Beside each evaluation, the mean evaluation return
of Playground's own training (Brax PPO on MJX, Playground's settings) at the same env steps,
linearly interpolated between its published points (0 at 0 steps), where such points exist.

Playground's points (``PLAYGROUND``) are read off the learning-curve plot that
github.com/alexanderdittrich/okapi publishes (``docs/benchmark_performance.png``, commit fbdd5ef:
"Brax MJX", the mean of 8 seeds of ``mujoco_playground``'s ``brax_ppo_config``, 8192 envs, an
evaluation every 10.8M (Berkeley Humanoid) or 22.3M (Go1) steps), to within about 0.2. Their
wall times are on one RTX 4080 Super GPU. No published curve was found for PandaPickCube or
LeapCubeReorient. Writes ``experiments/results/robot_training.{json,md}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import pathlib

import numpy as np

from experiments import results

# env -> (Playground task, [(env steps, mean eval return)], wall minutes for the whole run)
PLAYGROUND = {
    "humanoid_joystick": (
        "BerkeleyHumanoidJoystickFlatTerrain",
        [(10.8e6, 4.7), (21.6e6, 11.2), (32.4e6, 16.3), (43.3e6, 19.2), (54.1e6, 21.7), (64.9e6, 22.9),
         (75.7e6, 25.4), (86.5e6, 27.2), (97.3e6, 27.7), (108.1e6, 29.2), (118.9e6, 29.9),
         (129.8e6, 30.9), (140.6e6, 30.6), (151.4e6, 31.5)],
        22.0,
    ),
    "go1_joystick": (
        "Go1JoystickFlatTerrain",
        [(22.3e6, 18.2), (44.6e6, 22.1), (66.8e6, 27.0), (89.1e6, 28.0), (111.4e6, 28.2), (133.7e6, 28.4),
         (156.0e6, 28.9), (178.3e6, 28.9), (200.5e6, 29.1)],
        8.9,
    ),
}  # fmt: skip


def playground_at(env: str, steps: float) -> float | None:
    """Playground's mean evaluation return at ``steps`` (linear between its points; None past
    its last point or for a task without published points)."""
    if env not in PLAYGROUND:
        return None
    points = [(0.0, 0.0), *PLAYGROUND[env][1]]
    xs, ys = zip(*points, strict=True)
    return float(np.interp(steps, xs, ys)) if steps <= xs[-1] else None


def read_run(run_dir: pathlib.Path) -> dict:
    config = json.loads((run_dir / "config.json").read_text())
    with open(run_dir / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    env = config["env"]["name"]
    num = lambda r, k: float(r[k]) if r.get(k) not in (None, "") else None  # noqa: E731
    extra = sorted(k for k in rows[0] if k.startswith("eval/") and k[5:] not in
                   ("episode_return", "episode_return_std", "episode_length"))  # fmt: skip
    evals = [
        {"env_steps": int(float(r["env_steps"])), "wall_s": num(r, "wall_s"),
         "eval_return": num(r, "eval/episode_return"), "eval_length": num(r, "eval/episode_length"),
         **{k[5:]: num(r, k) for k in extra},
         "playground_return": playground_at(env, float(r["env_steps"]))}
        for r in rows if r.get("eval/episode_return") not in (None, "")
    ]  # fmt: skip
    last = rows[-1]
    return {
        "run_dir": str(run_dir), "env": env, "seed": config.get("seed"), "from": _source(config),
        "num_envs": config["algo"].get("num_envs"), "compile_s": num(rows[0], "perf/compile_s"),
        "env_steps": int(float(last["env_steps"])), "wall_s": num(last, "wall_s"),
        "train_return": num(last, "train/episode_return"),
        "env_steps_per_s": num(last, "perf/env_steps_per_s"),
        "evals": evals,
    }  # fmt: skip


def _source(config: dict) -> str | None:
    """What a fine-tuned run (``init_from``) started from: the source's env and its env steps
    (from the source's own metrics, when they can be read), or None for a run from scratch."""
    source = config.get("init_from")
    if source is None:
        return None
    path = pathlib.Path(source)
    try:
        env = json.loads((path / "config.json").read_text())["env"]["name"]
        with open(path / "metrics.csv") as f:
            steps = int(float(list(csv.DictReader(f))[-1]["env_steps"]))
        return f"{env} at {steps / 1e6:.0f}M steps"
    except (OSError, KeyError, IndexError, ValueError):
        return str(path)


def _task(run: dict) -> str:
    source = run.get("from")
    return run["env"] if source is None else f"{run['env']} (from {source})"


def markdown(runs: list[dict]) -> str:
    lines = [
        "# Robot-task training on this CPU, beside MuJoCo Playground's", "",
        f"Command: `{results.command()}`. Each run: `python -m fastrl.train env=<task> algo=ppo` with the "
        "shipped `experiment/<task>_ppo` settings, seed 0, on this 2-core machine; evaluations are the "
        "deterministic policy's mean over the run's evaluation episodes, domain randomisation on. "
        "Playground: the mean evaluation return of its Brax PPO on MJX (8192 envs, 8 seeds), read off a "
        "published plot and interpolated at the same env steps (see `experiments/robot_training.py`); "
        "`-` where no published point covers those steps. A task marked `(from ...)` was fine-tuned: started "
        "from another run's weights (`init_from`), its env steps counted from that start.", "",
        "| task | env steps | training s | eval return | eval episode length | other eval metrics "
        "| Playground return at these steps |",
        "| --- | ---: | ---: | ---: | ---: | --- | ---: |",
    ]  # fmt: skip
    for run in runs:
        for e in run["evals"]:
            other = ", ".join(f"{k} {v:.2f}" for k, v in e.items()
                              if k not in ("env_steps", "wall_s", "eval_return", "eval_length",
                                           "playground_return") and v is not None) or "-"  # fmt: skip
            ref = "-" if e["playground_return"] is None else f"{e['playground_return']:.1f}"
            lines.append(f"| {_task(run)} | {e['env_steps']:,} | {e['wall_s']:,.0f} | {e['eval_return']:.1f} "
                         f"| {e['eval_length']:.0f} | {other} | {ref} |")  # fmt: skip
    lines += ["", "| task | envs | env steps | training s (+ compile s) | env steps/s | last training return "
              "| Playground's whole run |", "| --- | ---: | ---: | ---: | ---: | ---: | --- |"]  # fmt: skip
    for run in runs:
        pg = PLAYGROUND.get(run["env"])
        whole = (
            "-"
            if pg is None
            else f"{pg[1][-1][1]:.1f} at {pg[1][-1][0] / 1e6:.0f}M steps, {pg[2]:.0f} min (GPU)"
        )
        lines.append(f"| {_task(run)} | {run['num_envs']} | {run['env_steps']:,} | {run['wall_s']:,.0f} "
                     f"(+ {run['compile_s']:.0f}) | {run['env_steps_per_s']:,.0f} "
                     f"| {run['train_return']:.1f} | {whole} |")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dirs", nargs="+", type=pathlib.Path)
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS, help="results folder")
    parser.add_argument("--note", default="", help="a sentence on the runs, shown under the tables")
    parser.add_argument(
        "--merge", action="store_true",
        help="keep the saved results' other runs (rows of an earlier command), with their note",
    )  # fmt: skip
    args = parser.parse_args()
    runs = [read_run(d) for d in args.run_dirs]
    note = args.note
    if args.merge:
        saved = json.loads((args.out / "robot_training.json").read_text())
        new = {r["run_dir"] for r in runs}
        runs = [r for r in saved["runs"] if r["run_dir"] not in new] + runs
        note = " ".join(n for n in (saved["meta"].get("note", ""), args.note) if n)
        merged = "Rows merged (`--merge`) from earlier runs of this script."
        note += "" if merged in note else f" {merged}"
    meta = {"machine": results.machine(), "date": results.today(), "note": note}
    page = markdown(runs) + (f"\n\n{note}" if note else "")
    results.save(args.out, "robot_training", {"meta": meta, "runs": runs}, page)
    print(page)


if __name__ == "__main__":
    main()
