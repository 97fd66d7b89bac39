"""Time to return: a fastrl learner against the same algorithm in Brax, same task, same machine.

    python -m experiments.time_to_return --task inverted_pendulum --seeds 0 1 2   # ~10 min
    python -m experiments.time_to_return --task ant --seeds 0 1 2                 # ~1 h on 2 cores
    python -m experiments.time_to_return --task hopper_sac --seeds 0 --stop-at-target
    python -m experiments.time_to_return --quick                                  # tiny, for CI
    python -m experiments.time_to_return --task ant --brax-from OLD.json  # re-run fastrl, reuse Brax's

For each seed it runs Brax's learner (``experiments/peers/brax_ppo.py`` for PPO,
``experiments/peers/brax_train.py`` for SAC, ES and APG, in ``.venv-peers``), then ``python -m
fastrl.train`` with the task's shipped settings, and records each evaluation's return against
the wall-clock seconds from launching that process to the evaluation (both sides the same way:
interpreter start-up, imports, compiles and earlier evaluations included). It reports per
learner the median over seeds of the seconds to first reach the task's target, and the ratio.
``--stop-at-target`` ends each run at its first evaluation at or above the target (fastrl's
``train.stop_at_return``; for Brax the peer script stops its ``progress_fn``). Writes
``experiments/results/time_to_return_<task>.{json,md,png}``.

Tasks (PPO):

* ``ant``: fastrl's Ant (Gymnasium v5's, MuJoCo-faithful physics, ``experiment/ant_ppo``) vs
  Brax's ``ant`` on its fastest ``spring`` backend with Brax's published Ant hyperparameters at
  1024 envs and batch 512 (issue 5's comparison). Brax's spring Ant is not the same physics:
  only its feet collide, and the spring model is not MuJoCo's. Target 3000.
* ``inverted_pendulum``: both sides the same MuJoCo model and task (Brax's ``generalized``
  backend, its default) with the *same* PPO settings, fastrl's ``experiment/
  inverted_pendulum_ppo`` written in Brax's terms (64 envs x 16-step unrolls, 4 minibatches,
  4 epochs, learning rate 1e-3, discount 0.99, entropy 1e-3, 2x32 policy and 2x64 value
  networks). Target 950 of 1000.

Tasks (SAC, ES, APG), each with fastrl's shipped ``experiment/<env>_<algo>`` settings written
in Brax's terms, on Brax's env of the same name with its default backend (``generalized``,
MuJoCo's models converted by Brax), evaluating 16 episodes with the mean action on both sides:

* ``hopper_sac`` (target 1000) and ``halfcheetah_sac`` (target 2000): 64 envs, 16 gradient
  steps of batch 256 per 64 env steps, 10,000 random-action steps first, learning rate 6e-4,
  discount 0.99, 2x256 networks, an evaluation every ~51k env steps. Differs: Brax's target
  entropy is -0.5 x action size, fastrl's -action size (both their defaults).
* ``halfcheetah_es`` (target 1000): 128 episodes of 1000 steps per update (Brax's
  ``population_size=64`` antithetic pairs), perturbation std 0.05, learning rate 0.02,
  centred-rank fitness, 2x32 policy, an evaluation every 640k env steps.
* ``swimmer_es`` (target 100): as ``halfcheetah_es`` but with a linear policy (fastrl's
  ``experiment/swimmer_es``; Brax: ``hidden_layer_sizes=()``).
* ``inverted_pendulum_apg`` (target 950): 64 envs, gradients over 32-step horizons, learning
  rate 3e-3, 2x32 policy. fastrl's ``experiment/inverted_pendulum_apg`` adds smooth shaping terms
  (upright, centred) to the reward it differentiates, since the 0/1 survival reward has no
  gradient; Brax's inverted_pendulum rewards survival only (1 per step), so its APG gets a zero
  gradient: this measures what each framework gives a user who asks for APG on the task.
* ``reacher_apg`` (target -5): 128 envs, gradients over 50-step horizons, learning rate 3e-3,
  2x64 policy, on Gymnasium's 50-step reacher episodes (Brax's ``episode_length=50``).

Both evaluate 1000-step episodes (reacher: 50); fastrl's evaluation uses the mean action. For
PPO Brax 0.14 evaluates its stochastic policy (its default), which on these tasks makes Brax's
numbers no higher; for SAC, ES and APG both sides evaluate the mean action.
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

from experiments import results
from fastrl.runtime.xla_flags import peer_environ

ROOT = results.ROOT
PEERS = ROOT / ".venv-peers" / "bin" / "python"


def _every(updates: int) -> list[str]:
    """fastrl's overrides for an evaluation every ``updates`` learner updates (fixed chunks)."""
    return [f"train.updates_per_chunk={updates}", "train.eval_every=1"]


TASKS = {
    "ant": {
        "label": "the Ant (fastrl: Gymnasium v5's; Brax: its spring Ant)",
        "target": 3000.0,
        # an evaluation every 5 updates (409,600 env steps)
        "fastrl": ["env=ant", "algo=ppo", *_every(5)],
        "fastrl_steps": 4_096_000,
        "brax": "--env ant --backend spring --num-envs 1024 --batch-size 512 --num-evals 20".split(),
        "brax_steps": 4_000_000,
    },
    "inverted_pendulum": {
        "label": "inverted_pendulum (same task and settings)",
        "target": 950.0,
        "fastrl": ["env=inverted_pendulum", "algo=ppo", *_every(10)],
        "fastrl_steps": 153_600,
        "brax": (
            "--env inverted_pendulum --backend generalized --num-envs 64 --batch-size 16 --num-minibatches 4"
            " --unroll-length 16 --num-updates-per-batch 4 --learning-rate 1e-3 --discounting 0.99"
            " --entropy-cost 1e-3 --reward-scaling 1 --policy-hidden 32 32 --value-hidden 64 64"
            " --num-eval-envs 16 --num-evals 16"
        ).split(),
        "brax_steps": 153_600,
    },
}
_SAC_BRAX = (
    "--algo sac --hidden 256 256 --set num_envs=64 grad_updates_per_step=16 batch_size=256 learning_rate=6e-4"
    " discounting=0.99 min_replay_size=10000 max_replay_size=1000000 reward_scaling=1 tau=0.005"
    " num_eval_envs=16 deterministic_eval=True num_evals=21"
)
TASKS.update(
    {
        f"{env}_sac": {
            "label": f"{env} (Brax: its generalized {env})",
            "algo": "sac",
            "target": target,
            "fastrl": [f"env={env}", "algo=sac", *_every(800)],  # eval every 51,200 steps
            "fastrl_steps": 1_024_000,
            "brax": f"{_SAC_BRAX} --env {env}".split(),
            "brax_steps": 1_024_000,
        }
        for env, target in (("hopper", 1000.0), ("halfcheetah", 2000.0))
    }
)
_ES_BRAX = (
    "--algo es --set population_size=64 perturbation_std=0.05 learning_rate=0.02"
    " fitness_shaping=CENTERED_RANK num_eval_envs=16 deterministic_eval=True num_evals=33"
)
TASKS.update(
    {
        f"{env}_es": {
            "label": f"{env} (Brax: its generalized {env})",
            "algo": "es",
            "target": target,
            "fastrl": [f"env={env}", "algo=es", *_every(5)],  # 5 updates (640k env steps) per evaluation
            "fastrl_steps": 20_480_000,
            "brax": [*f"{_ES_BRAX} --env {env} --hidden".split(), *hidden],  # swimmer: linear
            "brax_steps": 20_480_000,
        }
        for env, target, hidden in (("halfcheetah", 1000.0, ["32", "32"]), ("swimmer", 100.0, []))
    }
)
TASKS["inverted_pendulum_apg"] = {
    "label": "inverted_pendulum (Brax: its generalized inverted_pendulum, survival reward only)",
    "algo": "apg",
    "target": 950.0,
    "fastrl": [
        "env=inverted_pendulum",
        "algo=apg",
        *_every(20),
    ],  # 20 updates (40,960 env steps) per evaluation
    "fastrl_steps": 491_520,
    "brax": (
        "--algo apg --env inverted_pendulum --hidden 32 32 --set num_envs=64 horizon_length=32"
        " learning_rate=3e-3 num_eval_envs=16 deterministic_eval=True num_evals=13 policy_updates=240"
    ).split(),
    "brax_steps": None,
}
TASKS["reacher_apg"] = {
    "label": "reacher (Brax: its generalized reacher, 50-step episodes)",
    "algo": "apg",
    # -5, not -10: a motionless arm scores -11.8, so both learners pass -10 at their first
    # evaluation (then the ratio measures compile time); at -5 the arm must reach the target.
    "target": -5.0,
    "fastrl": ["env=reacher", "algo=apg", *_every(10)],  # 10 updates (64k env steps) per evaluation
    "fastrl_steps": 2_048_000,
    "brax": (
        "--algo apg --env reacher --hidden 64 64 --set num_envs=128 horizon_length=50 learning_rate=3e-3"
        " episode_length=50 num_eval_envs=32 deterministic_eval=True num_evals=33 policy_updates=320"
    ).split(),
    # Brax's APG is budgeted in policy updates (policy_updates x num_envs x horizon env steps).
    "brax_steps": None,
}


def run_brax(
    task: dict, seed: int, steps: int | None, stop_at: float | None, time_limit: float | None = None
) -> tuple[list[tuple[float, int, float]], bool]:
    """Brax's learning curve as (seconds since launch, env steps, eval return), and whether the
    run was cut at ``time_limit`` seconds (its curve up to then is kept)."""
    algo = task.get("algo", "ppo")
    if algo == "ppo":
        script = str(ROOT / "experiments/peers/brax_ppo.py")
        cmd = [str(PEERS), script, *task["brax"], "--num-timesteps", str(steps)]
    else:
        cmd = [str(PEERS), str(ROOT / "experiments/peers/brax_train.py"), *task["brax"]]
        if steps is not None:
            cmd += ["--set", f"num_timesteps={steps}"]
    cmd += ["--seed", str(seed)]
    if stop_at is not None:
        cmd += ["--stop-at-return", str(stop_at)]
    launched = time.time()
    try:
        out = subprocess.run(
            cmd, capture_output=True, text=True, timeout=time_limit or 7200, env=peer_environ()
        )
    except subprocess.TimeoutExpired as e:  # its output so far arrives as bytes
        stdout, cut = (e.stdout or b"").decode(), True
    else:
        if out.returncode:
            raise RuntimeError(f"Brax's {algo.upper()} failed ({out.returncode}):\n{out.stderr[-3000:]}")
        stdout, cut = out.stdout, False
    curve = []
    for line in stdout.splitlines():
        rec = json.loads(line)
        if rec.get("event") == "eval":
            curve.append((rec["time_unix"] - launched, rec["env_steps"], rec["eval_return"]))
    return curve, cut


def run_fastrl(
    task: dict, seed: int, steps: int, quick: bool, stop_at: float | None
) -> list[tuple[float, int, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        overrides = task["fastrl"]
        if quick:  # debug=quick's own chunks (an evaluation every 2 updates)
            overrides = [o for o in overrides if not o.startswith("train.updates_per_chunk=")]
        cmd = [sys.executable, "-m", "fastrl.train", *overrides, f"seed={seed}", f"run_dir={tmp}/run",
               f"train.total_env_steps={steps}", "logger=quiet"]  # fmt: skip
        if stop_at is not None:
            cmd.append(f"train.stop_at_return={stop_at}")
        if quick:
            cmd += ["debug=quick"]
        launched = time.time()
        subprocess.run(cmd, check=True, cwd=ROOT, timeout=7200, capture_output=True)
        rows = (pathlib.Path(tmp) / "run" / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    curve = []
    for row in rows[1:]:
        rec = dict(zip(header, row.split(","), strict=True))
        if rec.get("eval/episode_return"):
            seconds = float(rec["time_unix"]) - launched
            curve.append((seconds, int(rec["env_steps"]), float(rec["eval/episode_return"])))
    return curve


def reused_brax_runs(path: pathlib.Path, task: str, seeds: list[int]) -> tuple[list[dict], str]:
    """Brax's runs for ``seeds`` from a saved result, and a note for the table saying so."""
    saved = results.load(path)
    if saved.get("task") != task:
        raise SystemExit(f"--brax-from {path} holds task {saved.get('task')!r}, not {task!r}")
    runs = [r for r in saved["runs"] if r["learner"] == "brax" and r["seed"] in seeds]
    missing = sorted(set(seeds) - {r["seed"] for r in runs})
    if missing:
        raise SystemExit(f"--brax-from {path} has no Brax run for seeds {missing}")
    note = (
        f"Brax's runs are reused from an earlier run of this script (`{saved['command']}`, "
        f"{saved.get('machine', '?')}), not measured again alongside fastrl's."
    )
    if saved.get("note"):
        note += f" That run's note (its fastrl runs are replaced here): {saved['note']}"
    return runs, note


def time_to(curve, target: float) -> float | None:
    return next((t for t, _, r in curve if r >= target), None)


def summarize(runs: list[dict]) -> dict:
    summary = {}
    for name in ("brax", "fastrl"):
        mine = [r for r in runs if r["learner"] == name]
        reached = [r["time_to_target"] for r in mine if r["time_to_target"] is not None]
        lasts = [r["curve"][-1] for r in mine if r["curve"]]  # (seconds, steps, return) of each run's end
        summary[name] = {
            "runs": len(mine),
            "reached": len(reached),
            "median_s": float(np.median(reached)) if mine and len(reached) == len(mine) else None,
            "median_final_return": float(np.median([last[2] for last in lasts])) if lasts else None,
            "median_wall_s": float(np.median([last[0] for last in lasts])) if lasts else None,
        }
    return summary


def write(result: dict, out: pathlib.Path, stem: str) -> None:
    """The JSON, a markdown table and the chart, all from ``result``."""
    result["summary"] = summarize(result["runs"])
    target = result["target"]
    algo = TASKS.get(result["task"], {}).get("algo", "ppo").upper()
    lines = [f"# Time to eval return {target:g}: {result['task']}, fastrl {algo} vs Brax {algo}", "",
             f"Machine: {result.get('machine', '?')}. Command: `{result['command']}`.", "",
             "| learner | seeds | reached target | median s to target | median final return | median run s |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for name, s in result["summary"].items():
        if not s["runs"]:
            continue
        med = f"{s['median_s']:.0f}" if s["median_s"] is not None else "not reached by all"
        final = f"{s['median_final_return']:.0f}" if s["median_final_return"] is not None else "-"
        wall = f"{s['median_wall_s']:.0f}" if s["median_wall_s"] is not None else "-"
        lines.append(f"| {name} | {s['runs']} | {s['reached']} | {med} | {final} | {wall} |")
    b, f = result["summary"]["brax"]["median_s"], result["summary"]["fastrl"]["median_s"]
    if b and f:
        lines += ["", f"fastrl takes {f / b:.2f}x Brax's wall time to reach {target:g} (median of seeds)."]
    cut = [f"{r['learner']} seed {r['seed']}" for r in result["runs"] if r.get("cut_at_time_limit")]
    if cut:
        lines += [
            "",
            f"Cut at the time limit (`--brax-time-limit`), curve kept up to then: {', '.join(cut)}.",
        ]
    if result.get("note"):
        lines += ["", result["note"]]
    results.save(out, stem, result, "\n".join(lines), _plot(result["runs"], target, result["task"]))


def _plot(runs: list[dict], target: float, task: str):
    """Every run's evaluation return against its wall-clock seconds, the target dashed."""
    plt = results.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    colors = {"brax": "tab:orange", "fastrl": "tab:blue"}
    for r in runs:
        if r["curve"]:
            t, _, ret = zip(*r["curve"], strict=True)
            label = f"{r['learner']} seed {r['seed']}"
            ax.plot(t, ret, color=colors[r["learner"]], alpha=0.8, marker=".", label=label)
    ax.axhline(target, color="gray", ls="--", lw=1)
    algo = TASKS.get(task, {}).get("algo", "ppo").upper()
    ax.set_title(f"{algo} on {TASKS.get(task, {}).get('label', task)}", fontsize=10)
    ax.set_xlabel("wall-clock seconds (start-up and compile included)")
    ax.set_ylabel("eval episode return")
    ax.legend(fontsize=7)
    return fig


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", choices=sorted(TASKS), default="inverted_pendulum")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--brax-steps", type=int, default=None, help="default: the task's")
    parser.add_argument("--fastrl-steps", type=int, default=None, help="default: the task's")
    parser.add_argument("--quick", action="store_true", help="one seed, fastrl only, tiny budget")
    parser.add_argument("--skip-brax", action="store_true")
    parser.add_argument("--brax-time-limit", type=float, help="end each Brax run after this many seconds")
    parser.add_argument(
        "--stop-at-target", action="store_true", help="end each run at its first evaluation >= the target"
    )  # fmt: skip
    parser.add_argument(
        "--brax-from", type=pathlib.Path,
        help="reuse the Brax runs of a saved result JSON instead of running Brax again (the table says so)",
    )  # fmt: skip
    parser.add_argument("--from-json", type=pathlib.Path, help="re-render the table and chart of a saved run")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args(argv)
    if args.from_json:
        result = results.load(args.from_json)
        write(result, args.out, f"time_to_return_{result['task']}")
        return
    task = TASKS[args.task]
    seeds = args.seeds[:1] if args.quick else args.seeds
    skip_brax = args.skip_brax or args.quick or args.brax_from is not None or not PEERS.exists()
    if skip_brax and not (args.skip_brax or args.quick or args.brax_from):
        print(
            f"[time_to_return] no {PEERS}: Brax skipped (see experiments/peers/setup_peers.sh)",
            file=sys.stderr,
        )
    runs, note = reused_brax_runs(args.brax_from, args.task, seeds) if args.brax_from else ([], None)
    stop_at = task["target"] if args.stop_at_target else None
    for seed in seeds:
        if not skip_brax:
            steps = args.brax_steps or task["brax_steps"]
            curve, cut = run_brax(task, seed, steps, stop_at, args.brax_time_limit)
            runs.append({"learner": "brax", "seed": seed, "curve": curve, "cut_at_time_limit": cut})
        steps = 1024 if args.quick else (args.fastrl_steps or task["fastrl_steps"])
        curve = run_fastrl(task, seed, steps, args.quick, stop_at)
        runs.append({"learner": "fastrl", "seed": seed, "curve": curve})
    for r in runs:
        r["time_to_target"] = time_to(r["curve"], task["target"])
    command = results.command(None if argv is None else [__file__, *argv])
    result = {"task": args.task, "target": task["target"], "command": command,
              "machine": results.machine(), "runs": runs}  # fmt: skip
    if note:
        result["note"] = note
    write(result, args.out, f"time_to_return_{args.task}" + ("_quick" if args.quick else ""))


if __name__ == "__main__":
    main()
