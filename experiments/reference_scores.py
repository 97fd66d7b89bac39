"""fastrl's evaluation beside the reference simulator's, for trained runs (issue 33).

    python -m experiments.reference_scores RUN_DIR [RUN_DIR ...]          # 32 episodes each
    python -m experiments.reference_scores RUN_DIR --merge                 # add rows to the table
    python -m experiments.reference_scores --quick --out DIR               # tiny, for CI

For each run: fastrl's own evaluation at the run's physics settings (what training logs and
``python -m fastrl.evaluate`` print), fastrl at the asset's own settings when the run overrides
them (the Ant PPO run trains with Euler and 5 solver iterations; the asset is RK4), and the
reference: Gymnasium's own v5 env in MuJoCo C for the standard suite, the env's MJCF in MuJoCo C
with fastrl's observation and reward for fastrl's own scenes (``fastrl.tools.reference``). Every
score runs the same deterministic policy over the same episodes, each from the same initial
state (evaluation seed 0). Writes ``results/reference_scores.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

import fastrl
from experiments import results
from fastrl.tools import reference
from fastrl.training.policy import load_run


def score_run(run_dir: str, episodes: int, seed: int = 0) -> dict:
    """One row of the table: every score of the run's latest checkpoint."""
    rc, _, learner, state = load_run(run_dir)
    params = learner.policy_params(state)
    start = time.perf_counter()
    rows = reference.compare(rc.env, lambda obs: learner.act(params, obs), episodes, seed)
    out = {
        "run": f"{rc.env.name} / {rc.algo_name}, seed {rc.seed}",
        "run_dir": str(run_dir),
        "env_steps": int(state.env_steps),
        "episodes": episodes,
        "seconds": round(time.perf_counter() - start, 1),
    }
    for key, (label, scores) in rows.items():
        out[key] = {
            "label": label,
            "mean": float(scores.returns.mean()),
            "std": float(scores.returns.std()),
            "mean_length": float(scores.lengths.mean()),
            "ended_early": int((scores.lengths < rc.env.make().episode_length).sum()),
            "returns": [round(float(r), 2) for r in scores.returns],
        }
    return out


def _cell(score: dict | None) -> str:
    if score is None:
        return "-"
    early = f", {score['ended_early']} ended early" if score["ended_early"] else ""
    return f"{score['mean']:.0f} ± {score['std']:.0f} (length {score['mean_length']:.0f}{early})"


def _ratio(row: dict, a: str, b: str) -> str:
    if a not in row or b not in row or not row[b]["mean"]:
        return "-"
    return f"{row[a]['mean'] / row[b]['mean']:.3f}"


def render(rows: list[dict], command: str) -> str:
    """The markdown tables of ``rows``: the scores, then what each column ran."""
    lines = [
        "# fastrl's evaluation and the reference simulator's: same policy, same episodes",
        "",
        f"Date: {results.today()}. Machine: {results.machine()}. Command: `{command}`.",
        "Each score is the mean ± std of the return over the episodes; every column runs the same "
        "deterministic policy from the same initial states (evaluation seed 0). A run trained at "
        "physics settings other than its asset's (the Ant's Euler with 5 solver iterations) gets "
        "two more columns, which pair the simulators at equal physics.",
        "",
        "| run | env steps | episodes | fastrl, the run's physics | MuJoCo C, the run's integrator "
        "| fastrl, the asset's physics | reference | fastrl / reference | same physics: fastrl / MuJoCo C "
        "(run's; asset's) |",
        "| --- | ---: | ---: | --- | --- | --- | --- | ---: | ---: |",
    ]
    for r in rows:
        same = f"{_ratio(r, 'fastrl', 'mujoco_run')}; {_ratio(r, 'fastrl_asset', 'reference')}"
        cells = " | ".join(_cell(r.get(k)) for k in ("fastrl", "mujoco_run", "fastrl_asset", "reference"))
        lines.append(
            f"| {r['run']} | {r['env_steps']:,d} | {r['episodes']} | {cells} | "
            f"{_ratio(r, 'fastrl', 'reference')} | {same} |"
        )
    lines += ["", "| run | column | simulator and physics |", "| --- | --- | --- |"]
    for r in rows:
        for key in ("fastrl", "mujoco_run", "fastrl_asset", "reference"):
            if key in r:
                lines.append(f"| {r['run']} | {key} | {r[key]['label']} |")
    return "\n".join(lines) + "\n"


def quick_run(tmp: pathlib.Path, env: str = "hopper") -> str:
    """A tiny PPO run (``debug=quick``) of ``env`` trained with Euler, in ``tmp``."""
    from hydra import compose, initialize_config_dir

    from fastrl.cli.conf import CONF_DIR
    from fastrl.cli.train import run

    overrides = [f"env={env}", "algo=ppo", "debug=quick", "logger=quiet", "env.integrator=euler"]
    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        run(compose("train", overrides=[*overrides, f"run_dir={tmp}"]))
    return str(tmp)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dirs", nargs="*", help="run folders written by python -m fastrl.train")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--out", default=str(results.RESULTS))
    parser.add_argument("--merge", action="store_true", help="add to (or replace rows of) the existing table")
    parser.add_argument("--quick", action="store_true", help="a tiny Hopper run, 2 episodes (CI)")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    name = "reference_scores_quick" if args.quick else "reference_scores"
    command = results.command(None if argv is None else [__file__, *argv])
    with tempfile.TemporaryDirectory() as tmp:
        run_dirs = [quick_run(pathlib.Path(tmp))] if args.quick else args.run_dirs
        episodes = 2 if args.quick else args.episodes
        rows = []
        for run_dir in run_dirs:
            rows.append(score_run(run_dir, episodes))
            print(render(rows[-1:], command).splitlines()[7], flush=True)
    path = out / f"{name}.json"
    if args.merge and path.exists():
        old = results.load(path)
        new_runs = {r["run"] for r in rows}
        rows = [r for r in old["rows"] if r["run"] not in new_runs] + rows
        command = old["command"] + "; " + command
    results.save(out, name, {"command": command, "rows": rows}, render(rows, command))
    print(f"wrote {out / name}.{{md,json}}")
    return 0


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    sys.exit(main())
