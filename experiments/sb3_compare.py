"""fastrl against Stable-Baselines3 on a CPU: the same wall-clock budget, both scored in Gymnasium.

    python -m experiments.sb3_compare                                  # 4 envs x 3 learners x 300 s (~70 min)
    python -m experiments.sb3_compare --envs hopper --seconds 900
    python -m experiments.sb3_compare --envs humanoid --merge          # re-measure one env, keep the others
    python -m experiments.sb3_compare --quick --out DIR                # hopper, seconds per learner, for CI
    python -m experiments.sb3_compare --from-json experiments/results/sb3_compare.json  # the page again

What most users run on a CPU today is Stable-Baselines3 (PyTorch) on Gymnasium's own MuJoCo envs,
one process stepping one env. Here each learner trains for the same wall-clock budget
(``--seconds``), counted from launching its process, so start-up, imports and compiles are
inside it:

* **fastrl PPO**: ``python -m fastrl.train env=<env> algo=ppo`` with the shipped settings
  (``conf/experiment/<env>_ppo.yaml``) and ``train.max_seconds``; its checkpoints are the
  snapshots (``checkpoint.seconds`` spaces them over the budget).
* **SB3 PPO** and **SB3 SAC**: ``experiments/peers/sb3_train.py`` in ``.venv-peers`` (``bash
  experiments/peers/setup_peers.sh sb3``), with the RL Baselines3 Zoo's hyperparameters for the
  env, saving ``--snapshots`` snapshots evenly over the budget.

Both sides are then scored the same way, outside the clock: each snapshot's deterministic policy
runs ``--episodes`` episodes in Gymnasium's ``<Env>-v5`` (MuJoCo C, float64), the fastrl one
through ``fastrl.load_policy`` and ``fastrl.tools.reference.evaluate`` (Gymnasium built with the fastrl
env's settings, which for these four are Gymnasium's defaults: SB3 trains on the same env
keywords). Reported per env and learner: env steps in the budget, the return of the last
snapshot, the best snapshot's return, and the time to the same return: the target is the lower
of fastrl's last return and the better SB3 learner's, and a learner's time is its first
snapshot from which every later snapshot scores at least the target (``summarize``). One seed
per learner and env; the machine's 2 cores serve one learner at a time.

Writes ``experiments/results/sb3_compare.{json,md,png}`` (``_quick`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import json
import os
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
SB3_SCRIPT = ROOT / "experiments" / "peers" / "sb3_train.py"
ENVS = ("halfcheetah", "hopper", "ant", "humanoid")
LEARNERS = ("fastrl_ppo", "sb3_ppo", "sb3_sac")
LABELS = {"fastrl_ppo": "fastrl PPO", "sb3_ppo": "SB3 PPO", "sb3_sac": "SB3 SAC"}


def gymnasium_task(env_name: str) -> tuple[str, dict]:
    """The Gymnasium id and ``gymnasium.make`` keywords of fastrl's ``env_name`` as trained."""
    from fastrl.envs import registry
    from fastrl.tools import reference

    env = registry.make(env_name)
    return reference.GYMNASIUM[env.name].env_id, reference.gymnasium_kwargs(env)


def run_fastrl(
    env: str, seed: int, seconds: float, snapshots: int, quick: bool, out: pathlib.Path, algo: str = "ppo"
) -> list[dict]:
    """Trains fastrl's ``algo`` (its shipped settings for ``env``) for ``seconds`` with a cold
    compilation cache; its checkpoints as snapshots (seconds since launch, env steps, the
    checkpoint's step)."""
    from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer

    run_dir = out / f"fastrl_{algo}-{env}-{seed}"
    cmd = [sys.executable, "-m", "fastrl.train", f"env={env}", f"algo={algo}", f"seed={seed}",
           f"run_dir={run_dir}", f"train.max_seconds={seconds}", f"checkpoint.seconds={seconds / snapshots}",
           f"checkpoint.keep={4 * snapshots}", "logger=quiet"]  # fmt: skip
    if quick:
        # debug=quick's tiny networks and batches, trained on the time limit at full episode length
        cmd += ["debug=quick", "train.total_env_steps=100_000_000", "train.updates_per_chunk=null",
                "train.eval_every=0", "env.episode_length=null"]  # fmt: skip
    launched = time.time()
    cache = dict(os.environ, FASTRL_COMPILE_CACHE=str(out / f"compile_cache-{env}-{seed}"))
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=seconds + 600, capture_output=True, env=cache)
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR)
    try:
        snaps = []
        for step in sorted(ckpt.steps()):
            meta = ckpt.read_meta(step)[1]
            snaps.append({"seconds": meta["saved_at"] - launched, "env_steps": int(meta["env_steps"]),
                          "where": [str(run_dir), step]})  # fmt: skip
        return snaps
    finally:
        ckpt.close()


def score_fastrl(snaps: list[dict], episodes: int, seed: int) -> None:
    """Each snapshot's Gymnasium returns (``snap["returns"]``), via ``load_policy``."""
    import jax

    from fastrl.tools import reference
    from fastrl.training.config import RunConfig
    from fastrl.training.policy import load_policy

    for snap in snaps:
        policy = load_policy(*snap["where"])  # one restore: the env comes from its saved config
        env = reference.reference_env(RunConfig.from_dict(policy.run_config).env)
        scores = reference.evaluate(env, policy, episodes, jax.random.PRNGKey(1000 + seed), "gymnasium")
        snap["returns"], snap["lengths"] = scores.returns.tolist(), scores.lengths.tolist()


def run_sb3(algo: str, env: str, seed: int, seconds: float, snapshots: int, episodes: int,
            out: pathlib.Path) -> list[dict]:  # fmt: skip
    """Trains SB3's ``algo`` for ``seconds`` in ``.venv-peers`` and scores its snapshots."""
    if not PEERS.exists():
        raise SystemExit(f"{PEERS} is missing: run `bash experiments/peers/setup_peers.sh sb3` first")
    env_id, kwargs = gymnasium_task(env)
    folder = out / f"sb3_{algo}-{env}-{seed}"
    common = ["--env", env_id, "--algo", algo, "--out", str(folder), "--env-kwargs", json.dumps(kwargs)]
    launched = time.time()
    train = [str(PEERS), str(SB3_SCRIPT), "train", *common, "--seed", str(seed), "--seconds", str(seconds),
             "--snapshots", str(snapshots), "--t0", str(launched)]  # fmt: skip
    snaps = {r["index"]: r for r in _json_lines(train, seconds + 600) if r["event"] == "snapshot"}
    score = [str(PEERS), str(SB3_SCRIPT), "score", *common, "--episodes", str(episodes)]
    for rec in _json_lines(score, 3600):
        snaps[rec["index"]].update(returns=rec["returns"], lengths=rec["lengths"])
    return [
        {k: s[k] for k in ("seconds", "env_steps", "returns", "lengths")} for _, s in sorted(snaps.items())
    ]


def _json_lines(cmd: list[str], timeout: float) -> list[dict]:
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=peer_environ())
    if out.returncode:
        raise RuntimeError(f"{' '.join(cmd[:4])} failed ({out.returncode}):\n{out.stderr[-3000:]}")
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def summarize(env_runs: dict[str, list[dict]]) -> dict:
    """Per learner: env steps, last and best returns, and the time to the same return.

    The target is the lower of fastrl's last return and the better SB3 learner's last return
    (without fastrl: SB3's better last return), so both sides got there. A learner's time to it
    is the first snapshot from which every later snapshot scores at least the target: a lucky
    early snapshot that the learner then falls back from does not count. None: not reached."""
    means = {k: [float(np.mean(s["returns"])) for s in snaps] for k, snaps in env_runs.items()}
    sb3_last = max(rs[-1] for k, rs in means.items() if k.startswith("sb3"))
    target = min(sb3_last, means["fastrl_ppo"][-1]) if "fastrl_ppo" in means else sb3_last
    rows = {}
    for learner, snaps in env_runs.items():
        m, last = means[learner], snaps[-1]
        stays = [i for i in range(len(m)) if all(x >= target for x in m[i:])]
        rows[learner] = {"env_steps": last["env_steps"], "seconds": last["seconds"], "last_return": m[-1],
                         "last_std": float(np.std(last["returns"])), "best_return": max(m),
                         "seconds_to_target": snaps[stays[0]]["seconds"] if stays else None}  # fmt: skip
    return {"target": target, "learners": rows}


def time_ratio(summary: dict) -> float | None:
    """fastrl's time to the target over the faster SB3 learner's (None if either is missing)."""
    rows = summary["learners"]
    sb3 = [r["seconds_to_target"] for k, r in rows.items() if k.startswith("sb3")]
    sb3 = [t for t in sb3 if t is not None]
    mine = rows.get("fastrl_ppo", {}).get("seconds_to_target")
    return mine / min(sb3) if mine and sb3 else None


def render(result: dict) -> str:
    """The markdown page of ``result``."""
    lines = [f"# fastrl vs Stable-Baselines3 on a CPU, {result['seconds']:g} s of wall time per learner", "",
             f"Machine: {result['machine']}. Command: `{result['command']}`. fastrl {result['fastrl']}, "
             f"{result['sb3_versions']}.", "",
             "Each learner trains for the same wall-clock budget from launching its process (start-up "
             "and compile included), one at a time; every snapshot is then scored in Gymnasium's own "
             f"v5 env (MuJoCo C), {result['episodes']} episodes of the deterministic policy. One seed "
             f"({result['seeds']}). Target: the lower of fastrl's last return and the better SB3 "
             "learner's; a learner's time to it is its first snapshot from which every later one "
             "scores at least the target.", "",
             "| env | learner | env steps | last return | best return | s to the target | time ratio, "
             "fastrl / faster SB3 |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for env, summary in result["summary"].items():
        ratio = time_ratio(summary)
        for learner, r in summary["learners"].items():
            reach = "not reached" if r["seconds_to_target"] is None else f"{r['seconds_to_target']:.0f}"
            shown = "–" if learner != "fastrl_ppo" or ratio is None else f"{ratio:.2f}x"
            lines.append(f"| {env} | {LABELS[learner]} | {results.number(r['env_steps'])} | "
                         f"{r['last_return']:.0f} ± {r['last_std']:.0f} | {r['best_return']:.0f} | "
                         f"{reach} | {shown} |")  # fmt: skip
        lines.append(f"| {env} | target | | | {summary['target']:.0f} | | |")
    if result.get("note"):
        lines += ["", result["note"]]
    return "\n".join(lines)


def env_panels(envs: list[str]):
    """A figure of one panel per env in a row: (figure, the row of axes), the first axis labelled
    with Gymnasium's return."""
    plt = results.pyplot()
    fig, axes = plt.subplots(
        1, len(envs), figsize=(4 * len(envs), 3.4), constrained_layout=True, squeeze=False
    )
    axes[0][0].set_ylabel("return in Gymnasium v5")
    return fig, axes[0]


def plot(result: dict):
    """Gymnasium return against wall-clock seconds, one panel per env."""
    envs = list(result["runs"])
    fig, axes = env_panels(envs)
    colors = {"fastrl_ppo": "tab:blue", "sb3_ppo": "tab:orange", "sb3_sac": "tab:green"}
    for ax, env in zip(axes, envs, strict=True):
        for learner, snaps in result["runs"][env].items():
            t = [s["seconds"] for s in snaps]
            ax.plot(
                t,
                [np.mean(s["returns"]) for s in snaps],
                marker=".",
                color=colors[learner],
                label=LABELS[learner],
            )
        ax.set_title(env, fontsize=10)
        ax.set_xlabel("wall-clock s from launch")
    axes[0].legend(fontsize=7)
    return fig


def sb3_versions() -> str:
    code = (
        "import importlib.metadata as m; "
        "print(', '.join(f'{n} {m.version(n)}' for n in ('stable-baselines3', 'torch')))"
    )
    return subprocess.run([str(PEERS), "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="*", choices=ENVS, default=list(ENVS))
    parser.add_argument("--learners", nargs="*", choices=LEARNERS, default=list(LEARNERS))
    parser.add_argument("--seconds", type=float, default=300.0, help="wall-clock budget per learner and env")
    parser.add_argument("--snapshots", type=int, default=8, help="snapshots scored per run")
    parser.add_argument("--episodes", type=int, default=10, help="Gymnasium episodes per snapshot")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--quick", action="store_true", help="hopper, 15 s per learner, 2 snapshots, 2 episodes"
    )
    parser.add_argument("--out", default=str(results.RESULTS))
    parser.add_argument("--from-json", help="re-summarise a saved record instead of training")
    parser.add_argument(
        "--merge", action="store_true", help="replace these envs' rows in the saved record, keep the others"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.seconds, args.snapshots, args.episodes = ["hopper"], 15.0, 2, 2
    stem = "sb3_compare" + ("_quick" if args.quick else "")
    if args.from_json:  # the summary and page again from a saved record's snapshots
        result = results.load(pathlib.Path(args.from_json))
        stem = pathlib.Path(args.from_json).stem
    else:
        result = {"machine": results.machine(), "command": results.command(argv),
                  "fastrl": results.fastrl_version(), "sb3_versions": sb3_versions(),
                  "seconds": args.seconds, "episodes": args.episodes, "seeds": args.seed,
                  "runs": train_all(args)}  # fmt: skip
        if args.merge:
            result = merged(pathlib.Path(args.out) / f"{stem}.json", result)
    result["summary"] = {env: summarize(r) for env, r in result["runs"].items()}
    results.save(args.out, stem, result, render(result), plot(result))
    print(render(result))


def merged(path: pathlib.Path, new: dict) -> dict:
    """The saved record at ``path`` with ``new``'s envs measured anew (same budget and episodes),
    the page's header kept and a note saying which envs came from which run."""
    if not path.exists():
        return new
    old = results.load(path)
    for key in ("seconds", "episodes"):
        if old[key] != new[key]:
            raise SystemExit(f"--merge: {path} has {key}={old[key]}, this run {new[key]}; they must match")
    envs = list(new["runs"])
    runs = {env: new["runs"].get(env) or old["runs"][env] for env in ENVS if env in {*old["runs"], *envs}}
    note = (f"{', '.join(envs)}: measured again on {results.today()}, fastrl {new['fastrl']}, "
            f"{new['sb3_versions']}, by `{new['command']}`; the other envs are from the command "
            "above.")  # fmt: skip
    return {**old, "runs": runs, "note": note}


def train_all(args) -> dict[str, dict[str, list[dict]]]:
    """Every learner on every env, one at a time: their scored snapshots."""
    runs: dict[str, dict[str, list[dict]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        for env in args.envs:
            runs[env] = {}
            for learner in args.learners:
                print(f"sb3_compare: {env} {LABELS[learner]} for {args.seconds:g} s", flush=True)
                if learner == "fastrl_ppo":
                    snaps = run_fastrl(env, args.seed, args.seconds, args.snapshots, args.quick, work)
                    score_fastrl(snaps, args.episodes, args.seed)
                    for s in snaps:
                        s.pop("where")
                else:
                    snaps = run_sb3(
                        learner[4:], env, args.seed, args.seconds, args.snapshots, args.episodes, work
                    )
                runs[env][learner] = snaps
    return runs


if __name__ == "__main__":
    main()
