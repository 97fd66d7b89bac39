"""A robot task's full env step on one CPU device and split over several, in one child per count.

    python -m experiments.device_split leap_cube_reorient panda_pick_cube --devices 1 2

Each child sets ``--xla_force_host_platform_device_count``, lays the batch out over its devices
(``over_devices``, as ``VectorEnv`` and the learners do) and times a jitted scan of 10 env steps
under uniform random actions: the best of 3 runs after a warm-up, as control steps per second.
Writes ``device_split.{json,md}`` to ``--out`` (``experiments/results/``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import jax

import fastrl
from experiments import bench_envs, results


def measure(name: str, batch: int) -> dict:
    fastrl.use_recommended_xla_flags()
    r = bench_envs.bench_fastrl(name, batch, steps=10, repeats=3)
    rate, compile_s = round(r["control_steps_per_s"]), round(r["compile_s"], 1)
    return {"env": name, "devices": jax.device_count(), "batch": batch, "control_steps_per_s": rate,
            "compile_s": compile_s}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("envs", nargs="+")
    p.add_argument("--devices", type=int, nargs="+", default=[1, 2])
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--out", default=str(results.RESULTS))
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        print(json.dumps(measure(args.envs[0], args.batch)), flush=True)
        return
    rows = []
    for name in args.envs:
        for count in args.devices:
            flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={count}"
            cmd = [sys.executable, "-m", "experiments.device_split", name, "--batch", str(args.batch)]
            cmd.append("--child")
            out = subprocess.run(cmd, env=dict(os.environ, XLA_FLAGS=flags.strip()), capture_output=True,
                                 text=True, check=True)  # fmt: skip
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]), flush=True)
    meta = {"date": results.today(), "machine": results.machine(), "fastrl": results.fastrl_version(),
            "command": results.command()}  # fmt: skip
    keys = ["env", "batch", "devices", "control_steps_per_s", "compile_s"]
    table = results.table(["env", "batch", "devices", "control steps/s", "compile s"],
                          [[r[k] for k in keys] for r in rows])  # fmt: skip
    text = "# A robot task's env step on 1 and on several CPU devices\n\n"
    text += f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}.\n\n"
    text += f"Command: `{meta['command']}`.\n\n{table}"
    results.save(args.out, "device_split", {"meta": meta, "rows": rows}, text)


if __name__ == "__main__":
    main()
