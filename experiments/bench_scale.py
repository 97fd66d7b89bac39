"""Sweeps and scale on this machine: N agents in one program, and 2 host devices vs 1.

    python -m experiments.bench_scale            # Ant PPO (the shipped settings), 8 agents
    python -m experiments.bench_scale --env inverted_pendulum   # a small env's tuned PPO
    python -m experiments.bench_scale --quick    # tiny, for CI

Every configuration trains through ``fastrl.training.runner.train`` in a fresh process (the device
count is fixed when JAX starts), a few chunks of the Ant's tuned PPO with evaluation kept
small. Throughput is the median of the chunks after the first (compilation excluded).

- One program with ``train.num_seeds=N`` vs one run: 8 sequential runs take 8 times one
  run's time, so the ratio of env steps/s is the speed-up of the batch over running them
  one after the other.
- Each of the first two agents is compared with a separate single run of its seed: the
  largest relative difference of its per-chunk losses and returns.
- ``XLA_FLAGS=--xla_force_host_platform_device_count=2``: the same runs split over 2 CPU
  devices (env batch for one agent, agent batch for N).

Writes experiments/results/scale_throughput_<env>.{json,md} (``_quick`` in CI mode).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

from experiments import results

ROOT = results.ROOT
KEYS = ("loss/policy_loss", "loss/value_loss", "train/episode_return", "eval/episode_return")


def worker(overrides: list[str], run_dir: str) -> None:
    """Runs one training in this process and prints its per-chunk rows as one JSON line."""
    import jax
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    import fastrl
    from fastrl.cli.conf import CONF_DIR
    from fastrl.training import Callback, Evaluation, runner
    from fastrl.training.config import RunConfig

    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with

    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        cfg = compose("train", overrides=[*overrides, f"run_dir={run_dir}"])
    container = OmegaConf.to_container(cfg, resolve=True)
    for key in ("resume", "run_dir", "distributed"):
        container.pop(key, None)
    rows = []

    class Keep(Callback):
        def on_chunk(self, run, chunk):
            rows.append([{k: v for k, v in r.items() if isinstance(v, int | float)} for r in chunk.rows])

    out = runner.train(RunConfig.from_dict(container), run_dir, callbacks=[Evaluation(), Keep()])
    result = {"devices": jax.device_count(), "compile_s": out["compile_s"], "rows": rows}
    print("RESULT " + json.dumps(result))


def _steps_per_update(overrides: list[str]) -> int:
    from hydra import compose, initialize_config_dir

    from fastrl.cli.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        algo = compose("train", overrides=[*overrides, "run_dir=/unused"]).algo
    return int(algo.num_envs) * int(algo.unroll_length)


def _total_env_steps(overrides: list[str]) -> int:
    from hydra import compose, initialize_config_dir

    from fastrl.cli.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        return int(compose("train", overrides=[*overrides, "run_dir=/unused"]).train.total_env_steps)


def measure(overrides: list[str], devices: int) -> dict:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable,
            "-m",
            "experiments.bench_scale",
            "--worker",
            json.dumps(overrides),
            tmp + "/run",
        ]
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT)
    if out.returncode:
        raise RuntimeError(f"{overrides} on {devices} devices failed:\n{out.stderr[-3000:]}")
    result = json.loads(out.stdout.split("RESULT ", 1)[1])
    rows = result["rows"]
    n_agents = len(rows[0])
    rates = sorted(r[0]["perf/env_steps_per_s"] * n_agents for r in rows[1:]) or [0.0]
    result.update(overrides=overrides, n_agents=n_agents, env_steps_per_s=rates[len(rates) // 2])
    return result


def max_rel_diff(a: list[dict], b: list[dict], keys: tuple[str, ...]) -> float:
    worst = 0.0
    for ra, rb in zip(a, b, strict=True):
        for k in keys:
            if k in ra and k in rb:
                worst = max(worst, abs(ra[k] - rb[k]) / max(abs(rb[k]), 1e-6))
    return worst


def configure(args) -> tuple[list[str], int]:
    """The overrides every run shares, and the number of agents in the batched runs."""
    if args.quick:
        return ["env=inverted_pendulum", "debug=quick", "logger=quiet", "train.total_env_steps=512"], 2
    base = [
        f"env={args.env}",
        "algo=ppo",
        "logger=quiet",
        f"train.updates_per_chunk={args.updates_per_chunk}",
        "train.eval_envs=4",
    ]
    per_update = _steps_per_update(base)
    base.append(f"train.total_env_steps={args.chunks * args.updates_per_chunk * per_update}")
    return base, args.agents


def measure_all(base: list[str], n_agents: int) -> dict[str, dict]:
    """The five configurations, each in a fresh process."""
    seeds = [f"train.num_seeds={n_agents}"]
    return {
        "one run, 1 device": measure(base, 1),
        f"{n_agents} agents in one program, 1 device": measure(base + seeds, 1),
        "one run of seed 1, 1 device": measure(base + ["seed=1"], 1),
        "one run, 2 devices (env batch split)": measure(base, 2),
        f"{n_agents} agents in one program, 2 devices (agents split)": measure(base + seeds, 2),
    }


def agreement(runs: dict[str, dict], n_agents: int) -> dict:
    """How closely the batched agents follow their single runs, and 2 devices follow 1."""
    batch_rows = runs[f"{n_agents} agents in one program, 1 device"]["rows"]
    # Float rounding differs between a vmapped and a single program; the first chunk shows how
    # closely they agree, the last whether chaotic dynamics have since amplified the difference.
    agree, last_eval = {}, {}
    for s, name in ((0, "one run, 1 device"), (1, "one run of seed 1, 1 device")):
        single = runs[name]["rows"]
        for which, c in (("first", 0), ("last", -1)):
            agree[f"agent seed {s} vs its single run, {which} chunk"] = max_rel_diff(
                [batch_rows[c][s]], [single[c][0]], KEYS
            )
        last_eval[s] = (
            batch_rows[-1][s].get("eval/episode_return"),
            single[-1][0].get("eval/episode_return"),
        )
    finals = [batch_rows[-1][i].get("eval/episode_return", float("nan")) for i in range(n_agents)]
    sharded = max_rel_diff(runs["one run, 2 devices (env batch split)"]["rows"][0],
                           runs["one run, 1 device"]["rows"][0], KEYS)  # fmt: skip
    return {"agreement": agree, "final_eval_agent_vs_single": last_eval,
            "sharded_first_chunk_rel_diff": sharded, "agent_final_eval_returns": finals}  # fmt: skip


def sweep_estimate(runs: dict[str, dict], n_agents: int, budget: int) -> dict | None:
    """Wall seconds of ``n_agents`` runs of ``budget`` env steps, one after the other and in one
    program (1 device, compiles included); None when a rate is missing."""
    one, batch = runs["one run, 1 device"], runs[f"{n_agents} agents in one program, 1 device"]
    if not (one["env_steps_per_s"] and batch["env_steps_per_s"]):
        return None
    sequential = n_agents * (one["compile_s"] + budget / one["env_steps_per_s"])
    together = batch["compile_s"] + n_agents * budget / batch["env_steps_per_s"]
    return {"sequential": sequential, "one_program": together}


def markdown(result: dict, env: str, label: str, n_agents: int, budget: int) -> str:
    """The configurations' throughput, the sweep estimate and the agreement list."""
    runs, one = result["runs"], result["runs"]["one run, 1 device"]["env_steps_per_s"]
    lines = [f"# Sweeps and scale: {label} PPO on a {result['cpu_count']}-core CPU", "",
             f"Command: `python -m experiments.bench_scale --env {env}`. Env steps/s summed over "
             "agents, median of chunks after the first.", "",
             "| configuration | env steps/s | vs one run on 1 device | compile s |",
             "| --- | ---: | ---: | ---: |"]  # fmt: skip
    for name, r in runs.items():
        ratio = r["env_steps_per_s"] / one if one else float("nan")
        lines.append(f"| {name} | {r['env_steps_per_s']:,.0f} | {ratio:.2f}x | {r['compile_s']:.1f} |")
    if estimate := result.get("sweep_estimate_s"):
        sequential, together = estimate["sequential"], estimate["one_program"]
        lines += ["", f"Estimated wall time of {n_agents} runs of the shipped budget ({budget:,d} env steps "
                  f"each), compiles included, 1 device: one after the other {sequential:,.0f} s, in one "
                  f"program "
                  f"{together:,.0f} s ({sequential / together:.2f}x)."]  # fmt: skip
    lines += ["", "Largest relative difference of the chunk's losses and returns:", ""]
    lines += [f"- {k}: {v:.2e}" for k, v in result["agreement"].items()]
    lines += [f"- agent seed {s}: final eval return {a:.1f} in the batch, {b:.1f} as a single run"
              for s, (a, b) in result["final_eval_agent_vs_single"].items()]  # fmt: skip
    sharded, finals = result["sharded_first_chunk_rel_diff"], result["agent_final_eval_returns"]
    lines += [f"- one run on 2 devices vs 1 device, first chunk: {sharded:.2e}", "",
              "Final evaluation returns of the agents (independent RNG streams): "
              + ", ".join(f"{x:.1f}" for x in finals)]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    parser.add_argument("--env", default="ant", help="env trained with its tuned PPO settings")
    parser.add_argument("--agents", type=int, default=8)
    parser.add_argument(
        "--updates-per-chunk", type=int, default=2, help="longer chunks time small envs better"
    )
    parser.add_argument("--chunks", type=int, default=4)
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--render", type=pathlib.Path, help="re-tabulate this result JSON's runs")
    parser.add_argument("--worker", nargs=2, metavar=("OVERRIDES_JSON", "RUN_DIR"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(json.loads(args.worker[0]), args.worker[1])
        return
    base, n_agents = configure(args)
    # --render: re-tabulate the runs of an earlier measurement
    runs = results.load(args.render)["runs"] if args.render else measure_all(base, n_agents)
    result = {"runs": runs, **agreement(runs, n_agents), "cpu_count": os.cpu_count()}
    budget = _total_env_steps([f"env={args.env}", "algo=ppo"]) if not args.quick else 512
    if estimate := sweep_estimate(runs, n_agents, budget):
        result["sweep_estimate_s"] = estimate
    text = markdown(result, args.env, base[0].split("=")[1], n_agents, budget)
    results.save(
        args.out, "scale_throughput_quick" if args.quick else f"scale_throughput_{args.env}", result, text
    )
    print(text)


if __name__ == "__main__":
    main()
