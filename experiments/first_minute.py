"""The first minute of a training run, as a new user sees it: when the first progress line comes,
how long the compile takes cold and from the persistent cache.

    python -m experiments.first_minute                       # the Ant and the Humanoid (~8 min)
    python -m experiments.first_minute --envs ant --updates 20
    python -m experiments.first_minute --quick --out DIR     # inverted_pendulum, debug=quick, for CI

For each env, ``python -m fastrl.train env=<env> algo=ppo`` is launched twice with the same
fresh compilation cache folder (``FASTRL_COMPILE_CACHE``): the first launch compiles cold, the
second finds the chunk in the cache. Each launch trains ``--updates`` learner updates and
evaluates 4 episodes (the Humanoid's default 128 would take minutes, and come after the
progress lines this measures). Recorded
per launch, from its output lines as they arrive:

    first line      seconds from launch to the first progress line
    compile         the chunk's compile time as the run reports it (tracing included), and
                    whether the cache held it
    train steps/s   env steps over the seconds of the training chunks (metrics.csv: no compile,
                    evaluation or checkpoint time)
    wall            seconds from launch to exit

Writes ``experiments/results/first_minute.{md,json}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

from experiments import results

ROOT = results.ROOT
ENVS = ("ant", "humanoid", "inverted_pendulum")  # inverted_pendulum under debug=quick (--quick)


def steps_per_update(env: str, extra: list[str]) -> int:
    """Env steps per PPO update of ``env`` as ``python -m fastrl.train`` composes it."""
    from hydra import compose, initialize_config_dir

    from fastrl.cli.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        cfg = compose("train", overrides=[f"env={env}", "algo=ppo", *extra])
    return cfg.algo.num_envs * cfg.algo.unroll_length


def launch(env: str, updates: int, cache: str, run_dir: pathlib.Path, extra: list[str]) -> dict:
    """One launch; its timings."""
    per_update = steps_per_update(env, extra)
    cmd = [sys.executable, "-m", "fastrl.train", f"env={env}", "algo=ppo", f"run_dir={run_dir}",
           f"train.total_env_steps={updates * per_update}", "train.eval_envs=4",
           *extra]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ, FASTRL_COMPILE_CACHE=cache),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    out: dict = {"command": " ".join(cmd[1:]), "first_line_s": None}
    lines = []
    for line in proc.stdout:
        lines.append(line.rstrip())
        if out["first_line_s"] is None and re.match(r"\[[#-]+\]", line):
            out["first_line_s"] = time.perf_counter() - t0
        if m := re.search(r"chunk compiled in ([\d.]+)s \(([\d.]+s tracing|traced program read from the "
                          r"cache), compilation cache (\w+)", line):  # fmt: skip
            traced = m[2].removesuffix("s tracing")
            out["compile_s"], out["cache"] = float(m[1]), m[3]
            out["tracing_s"] = 0.0 if traced.startswith("traced") else float(traced)
        if m := re.search(r"([\d,]+) updates x ([\d,]+) env steps", line):
            assert int(m[2].replace(",", "")) == per_update, line
    proc.wait()
    out["wall_s"] = time.perf_counter() - t0
    if proc.returncode:
        raise RuntimeError(f"{out['command']} failed:\n" + "\n".join(lines[-20:]))
    with (run_dir / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    steps = int(rows[-1]["env_steps"])
    out["train_steps_per_s"] = steps / float(rows[-1]["wall_s"])
    out["chunks"] = len(rows)
    return out


def markdown(launches: dict, meta: dict) -> str:
    out = [
        "# The first minute: first progress line and compile, cold and from the cache",
        "",
        f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}. Command: `{meta['command']}`.",
        "",
        "Each env launched twice with one fresh compilation cache: cold, then from the cache. "
        "Compile: the chunk's, as the run reports it (tracing included). Train steps/s: env steps "
        "over the training chunks' seconds.",
        "",
        "| env | launch | first progress line (s) | chunk compile (s) | of it tracing (s) | cache | train steps/s | chunks | wall (s) |",  # noqa: E501
        "| --- | --- | ---: | ---: | ---: | --- | ---: | ---: | ---: |",
    ]
    for env, runs in launches.items():
        for which, r in runs.items():
            out.append(
                f"| {env} | {which} | {r['first_line_s']:.1f} | {r['compile_s']:.1f} | "
                f"{r['tracing_s']:.1f} | {r['cache']} | {r['train_steps_per_s']:,.0f} | {r['chunks']} | "
                f"{r['wall_s']:.0f} |"
            )
    return "\n".join(out) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="*", default=["ant", "humanoid"], choices=ENVS)
    parser.add_argument("--updates", type=int, default=3, help="learner updates per launch")
    parser.add_argument("--quick", action="store_true", help="inverted_pendulum with debug=quick (CI)")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    extra = ["debug=quick"] if args.quick else []
    if args.quick:
        args.envs, args.updates = ["inverted_pendulum"], 4
    launches = {}
    for env in args.envs:
        with tempfile.TemporaryDirectory() as tmp:
            cache = str(pathlib.Path(tmp) / "cache")
            launches[env] = {
                which: launch(env, args.updates, cache, pathlib.Path(tmp) / which, extra)
                for which in ("cold", "cached")
            }
        print(env, json.dumps(launches[env], indent=1), flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    meta = {
        "date": results.today(),
        "machine": results.machine(),
        "fastrl": commit.stdout.strip(),
        "command": results.command(),
    }
    stem = "first_minute_quick" if args.quick else "first_minute"
    results.save(args.out, stem, {"meta": meta, "results": launches}, markdown(launches, meta))


if __name__ == "__main__":
    main()
