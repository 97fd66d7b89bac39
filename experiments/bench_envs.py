"""Every env's throughput, and the Gymnasium vector API against Gymnasium's own, in one run.

    python experiments/bench_envs.py            # ~20-30 min on 2 cores (compiles every env twice)
    python experiments/bench_envs.py --quick    # tiny, for CI (peers skipped if absent)

1. For every fastrl env at batch 1024 and 4096: control steps/s of ``vmap(env.step)`` (with
   auto-reset, rewards and observations: the full env step) under a jitted scan with uniform
   random actions, beside MuJoCo C through EnvPool's ``<Task>-v4`` with 2 threads (from
   ``.venv-peers``), which uses Gymnasium's models with the same integrators and frame skips.
2. A CleanRL-style random-policy loop (numpy actions in, numpy observations out) over
   ``fastrl.envs.make_vec("ant", N)`` vs ``gymnasium.vector.SyncVectorEnv`` of Gymnasium's own
   ``Ant-v5``, same N: steps/s of each and their ratio.

Writes ``experiments/results/env_throughput.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import time

import gymnasium
import jax
import jax.numpy as jnp

from fastrl import envs

ROOT = pathlib.Path(__file__).resolve().parents[1]
PEERS = ROOT / ".venv-peers" / "bin" / "python"
RESULTS = ROOT / "experiments" / "results"
ENVPOOL_IDS = {
    "ant": "Ant-v4", "halfcheetah": "HalfCheetah-v4", "hopper": "Hopper-v4", "walker2d": "Walker2d-v4",
    "humanoid": "Humanoid-v4", "humanoidstandup": "HumanoidStandup-v4", "reacher": "Reacher-v4",
    "swimmer": "Swimmer-v4", "pusher": "Pusher-v4", "inverted_pendulum": "InvertedPendulum-v4",
    "inverted_double_pendulum": "InvertedDoublePendulum-v4",
}  # fmt: skip


def bench_fastrl(name: str, batch: int, steps: int) -> dict:
    env = envs.make(name)
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))

    def run(state, key):
        def one(s, k):
            a = jax.random.uniform(k, (batch, env.action_size), minval=low, maxval=high)
            return jax.vmap(env.step)(s, a), None

        return jax.lax.scan(one, state, jax.random.split(key, steps))[0]

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state, jax.random.PRNGKey(1)).compile()
    compile_s = time.perf_counter() - t0
    state = jax.block_until_ready(compiled(state, jax.random.PRNGKey(1)))
    t0 = time.perf_counter()
    state = jax.block_until_ready(compiled(state, jax.random.PRNGKey(2)))
    wall = time.perf_counter() - t0
    return {"engine": "fastrl", "env": name, "batch": batch, "control_steps_per_s": batch * steps / wall,
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


def bench_vector(num_envs: int, steps: int) -> dict:
    fast = envs.make_vec("ant", num_envs=num_envs, seed=0)
    gym = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make("Ant-v5") for _ in range(num_envs)])
    f, g = cleanrl_loop(fast, steps), cleanrl_loop(gym, max(2, steps // 4))
    return {
        "num_envs": num_envs,
        "fastrl_make_vec_steps_per_s": f,
        "gymnasium_sync_steps_per_s": g,
        "ratio": f / g,
    }


def main() -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=RESULTS, help="results folder")
    parser.add_argument("--envs", nargs="*", default=None, help="subset of env names")
    parser.add_argument("--batches", type=int, nargs="*", default=[1024, 4096], help="batch sizes")
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    args = parser.parse_args()
    names = args.envs or (["inverted_pendulum"] if args.quick else envs.names())
    batches = [8] if args.quick else args.batches
    steps = 2 if args.quick else args.steps
    rows = []
    for name in names:
        for batch in batches:
            r = bench_fastrl(name, batch, steps)
            peer = None if args.quick else bench_envpool(name, batch, 5.0)
            r["envpool_control_steps_per_s"] = peer["control_steps_per_s"] if peer else None
            rows.append(r)
            print(json.dumps(r), flush=True)
    vector = bench_vector(4 if args.quick else 64, 3 if args.quick else 50)
    print(json.dumps(vector))
    suffix = "_quick" if args.quick else ""
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"machine": "2-core x86_64 CPU, no accelerator", "jax": jax.__version__}
    result = {"meta": meta, "envs": rows, "vector": vector}
    (args.out / f"env_throughput{suffix}.json").write_text(json.dumps(result, indent=1))
    lines = ["# Env throughput (control steps/s, this machine, one run)", "",
             "| env | batch | fastrl | EnvPool (MuJoCo C, 2 threads) | fastrl / EnvPool | compile s |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for r in rows:
        peer = r["envpool_control_steps_per_s"]
        ratio = f"{r['control_steps_per_s'] / peer:.2f}" if peer else "-"
        peer_s = f"{peer:,.0f}" if peer else "-"
        lines.append(f"| {r['env']} | {r['batch']} | {r['control_steps_per_s']:,.0f} | {peer_s} | {ratio} | "
                     f"{r['compile_s']:.1f} |")  # fmt: skip
    lines += [
        "",
        f"CleanRL-style random loop, {vector['num_envs']} envs: fastrl make_vec('ant') "
        f"{vector['fastrl_make_vec_steps_per_s']:,.0f} steps/s vs Gymnasium SyncVectorEnv(Ant-v5) "
        f"{vector['gymnasium_sync_steps_per_s']:,.0f} steps/s: **{vector['ratio']:.1f}x**.",
    ]
    (args.out / f"env_throughput{suffix}.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
