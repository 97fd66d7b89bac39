"""Every env's throughput, and the Gymnasium vector API against Gymnasium's own, in one run.

    python -m experiments.bench_envs            # ~20-30 min on 2 cores (compiles every env twice)
    python -m experiments.bench_envs --quick    # tiny, for CI (peers skipped if absent)

1. For every fastrl env at batch 1024 and 4096: control steps/s of ``vmap(env.step)`` (with
   auto-reset, rewards and observations: the full env step) under a jitted scan with uniform
   random actions, beside MuJoCo C through EnvPool's ``<Task>-v4`` with 2 threads (from
   ``.venv-peers``), which uses Gymnasium's models with the same integrators and frame skips.
   The same fastrl rows again with the batch split over 2 CPU devices (one program copy per
   core, ``shard_map``), in a child process started with
   ``XLA_FLAGS=--xla_force_host_platform_device_count=2``.
2. A CleanRL-style random-policy loop (numpy actions in, numpy observations out) over
   ``fastrl.envs.make_vec("ant", N)`` vs ``gymnasium.vector.SyncVectorEnv`` of Gymnasium's own
   ``Ant-v5``, same N (64 and 1024): steps/s of each and their ratio, with make_vec on one
   device and on 2 CPU devices (child process). make_vec runs twice: with the env's defaults
   (Gymnasium's RK4 at 0.01 s x 5, 7 Newton iterations) and with the settings fastrl trains the
   Ant with (``integrator="euler", solver_iterations=5``, ``conf/experiment/ant_ppo.yaml``; they
   meet the same MuJoCo-agreement bars, ``tests/physics/test_contact.py``).

The 2-device child reports each row on stderr as it finishes (the whole run takes 45+ min).

fastrl runs with the XLA:CPU flags of ``fastrl.use_recommended_xla_flags()``
(``fastrl/runtime/xla_flags.py``).
Writes ``experiments/results/env_throughput.{json,md}`` (``--name`` another stem, e.g. for a run
of one env).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

import gymnasium
import jax
import jax.numpy as jnp

import fastrl
from experiments import results
from fastrl import envs

ROOT = results.ROOT
PEERS = ROOT / ".venv-peers" / "bin" / "python"
ENVPOOL_IDS = {
    "ant": "Ant-v4", "halfcheetah": "HalfCheetah-v4", "hopper": "Hopper-v4", "walker2d": "Walker2d-v4",
    "humanoid": "Humanoid-v4", "humanoidstandup": "HumanoidStandup-v4", "reacher": "Reacher-v4",
    "swimmer": "Swimmer-v4", "pusher": "Pusher-v4", "inverted_pendulum": "InvertedPendulum-v4",
    "inverted_double_pendulum": "InvertedDoublePendulum-v4",
}  # fmt: skip


def bench_fastrl(name: str, batch: int, steps: int, repeats: int = 1) -> dict:
    """The full env step of ``name`` at ``batch`` under uniform random actions, split over the
    devices when there are several: control steps per second of a jitted ``steps``-step scan, the
    best of ``repeats`` runs after one warm-up run."""
    env = envs.make(name)
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))

    step = envs.over_devices(jax.vmap(env.step), envs.batch_mesh(batch))

    def run(state, key):
        def one(s, k):
            a = jax.random.uniform(k, (batch, env.action_size), minval=low, maxval=high)
            return step(s, a), None

        return jax.lax.scan(one, state, jax.random.split(key, steps))[0]

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state, jax.random.PRNGKey(1)).compile()
    compile_s = time.perf_counter() - t0
    state = jax.block_until_ready(compiled(state, jax.random.PRNGKey(1)))
    wall = float("inf")
    for i in range(repeats):
        t0 = time.perf_counter()
        state = jax.block_until_ready(compiled(state, jax.random.PRNGKey(2 + i)))
        wall = min(wall, time.perf_counter() - t0)
    engine = "fastrl" if jax.device_count() == 1 else f"fastrl, {jax.device_count()} devices"
    return {"engine": engine, "env": name, "batch": batch, "control_steps_per_s": batch * steps / wall,
            "compile_s": compile_s, "diverged": float(state.metrics["diverged"].mean())}  # fmt: skip


def bench_envpool(name: str, batch: int, seconds: float) -> dict | None:
    if not PEERS.exists() or name not in ENVPOOL_IDS:
        return None
    cmd = [str(PEERS), str(ROOT / "experiments/peers/envpool_ant.py"), "--env-id", ENVPOOL_IDS[name],
           "--num-envs", str(batch), "--seconds", str(seconds)]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if out.returncode:
        print(f"envpool {name} failed: {out.stderr[-500:]}")
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def cleanrl_loop(venv, steps: int, seed: int = 0) -> float:
    """Random-policy loop as CleanRL writes it; returns env steps per second."""
    venv.reset(seed=seed)
    venv.action_space.seed(seed)
    venv.step(venv.action_space.sample())  # warm up (compiles fastrl's step)
    t0 = time.perf_counter()
    for _ in range(steps):
        obs, reward, term, trunc, info = venv.step(venv.action_space.sample())
    return venv.num_envs * steps / (time.perf_counter() - t0)


# make_vec's Ant at the settings fastrl trains it with (conf/experiment/ant_ppo.yaml).
TRAINING_SETTINGS = {"integrator": "euler", "solver_iterations": 5}


def bench_vector(num_envs: int, steps: int, gym: bool = True) -> dict:
    fast = envs.make_vec("ant", num_envs=num_envs, seed=0)
    f = cleanrl_loop(fast, steps)
    ft = cleanrl_loop(envs.make_vec("ant", num_envs=num_envs, seed=0, **TRAINING_SETTINGS), steps)
    row = {"num_envs": num_envs, "devices": jax.device_count(), "fastrl_make_vec_steps_per_s": f,
           "fastrl_make_vec_training_settings_steps_per_s": ft}  # fmt: skip
    if gym:
        sync = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make("Ant-v5") for _ in range(num_envs)])
        g = cleanrl_loop(sync, max(2, steps // 4))
        row.update(gymnasium_sync_steps_per_s=g, ratio=f / g, ratio_training_settings=ft / g)
    return row


def in_child(job: dict, devices: int) -> list[dict]:
    """Runs ``job`` (fastrl env rows and make_vec loops) in a child process with ``devices`` CPU devices."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    cmd = [sys.executable, "-m", "experiments.bench_envs", "--worker", json.dumps(job)]
    # stdout carries the rows; stderr (progress) goes straight to ours.
    out = subprocess.run(cmd, env=env, cwd=ROOT, check=True, stdout=subprocess.PIPE, text=True, timeout=7200)
    return [json.loads(line[4:]) for line in out.stdout.splitlines() if line.startswith("ROW ")]


def worker(job: dict) -> None:
    """The child process of ``in_child``: a ``ROW <json>`` line on stdout per row, progress on stderr."""
    for name, batch in job["envs"]:
        row = bench_fastrl(name, batch, job["steps"])
        print("ROW " + json.dumps(row), flush=True)
        print(f"  {jax.device_count()} devices: {name} x{batch}: {row['control_steps_per_s']:,.0f} "
              f"control steps/s", file=sys.stderr, flush=True)  # fmt: skip
    for n in job["vector"]:
        row = bench_vector(n, job["vector_steps"], gym=False)
        print("ROW " + json.dumps(row), flush=True)
        print(f"  {jax.device_count()} devices: make_vec x{n}: {row['fastrl_make_vec_steps_per_s']:,.0f} "
              "steps/s", file=sys.stderr, flush=True)  # fmt: skip


def measure(names: list[str], batches: list[int], steps: int, quick: bool) -> tuple[list[dict], list[dict]]:
    """Every env's rows (with EnvPool beside them) and the make_vec loops, on one device, then the
    same on 2 devices in a child process, merged into them."""
    rows = []
    for name in names:
        for batch in batches:
            r = bench_fastrl(name, batch, steps)
            peer = None if quick else bench_envpool(name, batch, 5.0)
            r["envpool_control_steps_per_s"] = peer["control_steps_per_s"] if peer else None
            rows.append(r)
            print(json.dumps(r), flush=True)
    vector_sizes, vector_steps = ([4], 3) if quick else ([64, 1024], 20)
    vector = [bench_vector(n, vector_steps) for n in vector_sizes]
    print(json.dumps(vector))
    job = {"envs": [[r["env"], r["batch"]] for r in rows], "steps": steps, "vector": vector_sizes,
           "vector_steps": vector_steps}  # fmt: skip
    split = in_child(job, 2)
    split_envs = {(r["env"], r["batch"]): r for r in split if "env" in r}
    for r in rows:
        r["split_2_devices"] = split_envs[r["env"], r["batch"]]
    for v, r in zip(vector, [r for r in split if "num_envs" in r], strict=True):
        g = v["gymnasium_sync_steps_per_s"]
        v["fastrl_make_vec_2_devices_steps_per_s"] = r["fastrl_make_vec_steps_per_s"]
        v["ratio_2_devices"] = r["fastrl_make_vec_steps_per_s"] / g
        v["fastrl_make_vec_training_settings_2_devices_steps_per_s"] = t = r[
            "fastrl_make_vec_training_settings_steps_per_s"
        ]
        v["ratio_training_settings_2_devices"] = t / g
    return rows, vector


def markdown(rows: list[dict], vector: list[dict]) -> str:
    """The env table (one device, two, EnvPool), then the make_vec vs SyncVectorEnv table."""
    lines = ["# Env throughput (control steps/s, this machine, one run)", "",
             f"Command: `{results.command()}`. "
             "fastrl: the full env step (physics, observation,",
             "reward, auto-reset) on one CPU device, and split over 2 CPU devices (one per core).", "",
             "| env | batch | fastrl | fastrl, 2 devices | EnvPool (MuJoCo C, 2 threads) | fastrl / EnvPool "
             "| 2 devices / EnvPool | compile s |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for r in rows:
        peer, two = r["envpool_control_steps_per_s"], r["split_2_devices"]["control_steps_per_s"]
        ratio = f"{r['control_steps_per_s'] / peer:.2f}" if peer else "-"
        ratio2 = f"{two / peer:.2f}" if peer else "-"
        peer_s = f"{peer:,.0f}" if peer else "-"
        lines.append(f"| {r['env']} | {r['batch']} | {r['control_steps_per_s']:,.0f} | {two:,.0f} | "
                     f"{peer_s} | {ratio} | {ratio2} | {r['compile_s']:.1f} |")  # fmt: skip
    lines += ["", "CleanRL-style random loop (numpy actions in, numpy observations out) over fastrl "
              "`make_vec('ant')` and Gymnasium's `SyncVectorEnv` of `Ant-v5`. make_vec with the env's "
              "defaults (Gymnasium's RK4, 0.01 s x 5) and with the Ant's training settings "
              "(`integrator='euler', solver_iterations=5`):", "",
              "| envs | Gymnasium SyncVectorEnv | make_vec | 2 devices | ratio | ratio, 2 devices "
              "| make_vec, training settings | 2 devices | ratio | ratio, 2 devices |",
              "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for v in vector:
        rates = [
            v[f"fastrl_make_vec{k}_steps_per_s"]
            for k in ("", "_2_devices", "_training_settings", "_training_settings_2_devices")
        ]
        ratios = [v[k] for k in ("ratio", "ratio_2_devices", "ratio_training_settings",
                                 "ratio_training_settings_2_devices")]  # fmt: skip
        cells = [f"{v['gymnasium_sync_steps_per_s']:,.0f}", *(f"{x:,.0f}" for x in rates[:2]),
                 *(f"{x:.2f}x" for x in ratios[:2]), *(f"{x:,.0f}" for x in rates[2:]),
                 *(f"{x:.2f}x" for x in ratios[2:])]  # fmt: skip
        lines.append(f"| {v['num_envs']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS, help="results folder")
    parser.add_argument("--envs", nargs="*", default=None, help="subset of env names")
    parser.add_argument("--batches", type=int, nargs="*", default=[1024, 4096], help="batch sizes")
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--name", default="env_throughput",
                        help="output file stem (a partial run need not replace the full table)")  # fmt: skip
    parser.add_argument("--worker", help=argparse.SUPPRESS)  # child process of in_child
    args = parser.parse_args()
    if args.worker:
        return worker(json.loads(args.worker))
    names = args.envs or (["inverted_pendulum"] if args.quick else envs.names())
    batches = [8] if args.quick else args.batches
    rows, vector = measure(names, batches, 2 if args.quick else args.steps, args.quick)
    meta = {"machine": results.machine(), "jax": jax.__version__}
    stem = args.name + ("_quick" if args.quick else "")
    results.save(args.out, stem, {"meta": meta, "envs": rows, "vector": vector}, markdown(rows, vector))


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
