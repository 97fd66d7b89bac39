"""Ant with contacts: fastrl's control steps/s vs EnvPool (MuJoCo C) and Brax, in one run.

    python -m experiments.bench_contacts             # a few minutes on 2 cores
    python -m experiments.bench_contacts --quick     # tiny, for CI (peers skipped if absent)

Control step 0.05 s. fastrl runs its Ant asset (a) as Gymnasium/EnvPool do, RK4 at 0.01 s x 5,
(b) with semi-implicit Euler at 0.01 s x 5, both with the asset's solver iterations (7), and (c)
with the settings ``env=ant algo=ppo`` trains with (``conf/experiment/ant_ppo.yaml``: Euler, 5
iterations), under a jitted scan of vmapped steps with fresh random actions each control step;
then (a) and (c) again with the batch split over 2 CPU devices (``shard_map``, one program copy
per core, as ``python -m fastrl.train`` runs PPO), in a child process started with
``XLA_FLAGS=--xla_force_host_platform_device_count=2``. Peers run from
``.venv-peers`` (``bash experiments/peers/setup_peers.sh``): EnvPool ``Ant-v4`` with 2 threads and
Brax's ``ant`` with its mjx, generalized, spring and positional backends at their own defaults.
fastrl runs with the XLA:CPU flags of ``fastrl.use_recommended_xla_flags()``
(``fastrl/runtime/xla_flags.py``); Brax with the user's ``XLA_FLAGS`` (its own defaults). Writes
``experiments/results/contacts_throughput.{md,json,png}``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import fastrl
from experiments import results
from fastrl import envs, physics
from fastrl.runtime.xla_flags import peer_environ

ROOT = results.ROOT
ANT = ROOT / "fastrl" / "assets" / "ant.xml"
PEERS = ROOT / ".venv-peers" / "bin" / "python"
# Gymnasium's Ant start pose: standing, legs bent.
QPOS0 = np.array([0, 0, 0.75, 1, 0, 0, 0, 0, 1, 0, -1, 0, -1, 0, 1.0])


def bench_fastrl(
    integrator: str, batch: int, control_steps: int, iterations: int | None = None, substeps: int = 5
) -> dict:
    m = physics.load_mjcf(ANT, integrator=integrator, solver_iterations=iterations)
    key = jax.random.PRNGKey(0)
    qvel = 0.1 * jax.random.normal(key, (batch, m.nv))
    data = jax.vmap(lambda v: physics.make_data(m, qpos=QPOS0, qvel=v))(qvel)
    ctrl = jax.random.uniform(key, (control_steps, batch, m.nu), minval=-1, maxval=1)

    def control_step(d, u):
        return jax.lax.fori_loop(0, substeps, lambda _, d: physics.step(m, d, u), d)

    one = envs.over_devices(jax.vmap(control_step), envs.batch_mesh(batch))  # with 2+ devices, a slice each

    def run(d, ctrl):
        return jax.lax.scan(lambda d, u: (one(d, u), None), d, ctrl)[0]

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(data, ctrl).compile()
    compile_s = time.perf_counter() - t0
    out = jax.block_until_ready(compiled(data, ctrl))
    t0 = time.perf_counter()
    out = jax.block_until_ready(compiled(out, ctrl))
    wall = time.perf_counter() - t0
    return {
        "engine": f"fastrl {integrator} 0.01x{substeps}, {m.solver_iterations} iters"
        + (f", {jax.device_count()} devices" if jax.device_count() > 1 else ""),
        "batch": batch,
        "control_steps_per_s": batch * control_steps / wall,
        "compile_s": compile_s,
        "diverged_fraction": float(jnp.mean(out.diverged)),
        "solver_iterations": m.solver_iterations,
    }


def bench_fastrl_devices(settings, batches: list[int], control_steps: int, devices: int) -> list[dict]:
    """``bench_fastrl`` rows measured in a child process with ``devices`` CPU devices."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    spec = json.dumps({"settings": settings, "batches": batches, "control_steps": control_steps})
    cmd = [sys.executable, "-m", "experiments.bench_contacts", "--worker", spec]
    out = subprocess.run(cmd, env=env, cwd=ROOT, check=True, capture_output=True, text=True, timeout=3600)
    return [json.loads(line[4:]) for line in out.stdout.splitlines() if line.startswith("ROW ")]


def _peer(args: list[str]) -> dict | None:
    if not PEERS.exists():
        print(f"peers not installed ({PEERS}); run experiments/peers/setup_peers.sh", flush=True)
        return None
    env = peer_environ(PYTHONPATH="")  # Brax at its own XLA defaults, not fastrl's
    proc = subprocess.run([str(PEERS), *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=900)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode or not lines:
        print(f"peer failed: {' '.join(args)}\n{proc.stderr[-2000:]}", flush=True)
        return None
    return json.loads(lines[-1])


def bench_envpool(num_envs: int, seconds: float) -> dict | None:
    r = _peer(["experiments/peers/envpool_ant.py", "--num-envs", str(num_envs), "--seconds", str(seconds)])
    if r:
        r = {"engine": "EnvPool Ant-v4 (MuJoCo C, RK4 0.01x5, 2 threads)", "batch": num_envs,
             "control_steps_per_s": r["control_steps_per_s"], "compile_s": 0.0}  # fmt: skip
    return r


def bench_brax(backend: str, batch: int, steps: int) -> dict | None:
    r = _peer(
        ["experiments/peers/brax_ant.py", "--backend", backend, "--batch", str(batch), "--steps", str(steps)]
    )
    if r:
        r = {"engine": f"Brax {backend} (dt {r['dt']:.3f}, {r['n_frames']} frames)", "batch": batch,
             "control_steps_per_s": r["control_steps_per_s"], "compile_s": r["compile_s"],
             "nonfinite": r["nonfinite"]}  # fmt: skip
    return r


def chart(rows: list[dict]):
    """Control steps/s against batch, one line per engine (log-log)."""
    plt = results.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for engine in dict.fromkeys(r["engine"] for r in rows):
        pts = sorted((r["batch"], r["control_steps_per_s"]) for r in rows if r["engine"] == engine)
        ax.plot(*zip(*pts, strict=True), marker="o", label=engine)
    ax.set(xscale="log", yscale="log", xlabel="batch (parallel environments)",
           ylabel="control steps / s (0.05 s each)", title="Ant with contacts, 2-core CPU")  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def markdown(rows: list[dict]) -> str:
    """The table of every row against EnvPool's best, then each engine's best."""
    best = {}
    for r in rows:
        best[r["engine"]] = max(best.get(r["engine"], 0.0), r["control_steps_per_s"])
    envpool = next((v for k, v in best.items() if k.startswith("EnvPool")), None)
    lines = ["# Ant with contacts: control steps per second (0.05 s each)", "",
             f"Machine: {results.machine()}. Command: `python -m experiments.bench_contacts`.", "",
             "| engine | batch | control steps/s | compile s | vs EnvPool best |",
             "| --- | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for r in rows:
        ratio = f"{r['control_steps_per_s'] / envpool:.2f}x" if envpool else "n/a"
        sps = f"{r['control_steps_per_s']:,.0f}"
        lines.append(f"| {r['engine']} | {r['batch']} | {sps} | {r['compile_s']:.1f} | {ratio} |")
    lines += ["", "Best per engine:", ""] + [f"- {k}: {v:,.0f}" for k, v in best.items()]
    return "\n".join(lines)


def worker(spec: dict) -> None:
    """The child process of ``bench_fastrl_devices``: prints a ``ROW <json>`` line per measurement."""
    for integrator, iterations in spec["settings"]:
        for b in spec["batches"]:
            print(
                "ROW " + json.dumps(bench_fastrl(integrator, b, spec["control_steps"], iterations)),
                flush=True,
            )


def measure(quick: bool) -> list[dict]:
    """fastrl's settings on 1 device, then 2; the peers (full mode only). Prints each row."""
    fastrl_batches = [16] if quick else [64, 256, 1024, 4096, 8192]
    control_steps = 2 if quick else 10
    from omegaconf import OmegaConf

    shipped = OmegaConf.load(ROOT / "conf" / "experiment" / "ant_ppo.yaml").env
    rows = []
    settings = [("rk4", None), ("euler", None), (shipped.integrator, shipped.solver_iterations)]
    if quick:  # one compile in CI: the setting the Ant trains with
        settings = settings[-1:]
    for integrator, iterations in settings:
        for b in fastrl_batches:
            rows.append(bench_fastrl(integrator, b, control_steps, iterations))
            print(rows[-1], flush=True)
    split_settings = settings[-1:] if quick else [settings[0], settings[-1]]
    for r in bench_fastrl_devices(split_settings, [2 * b for b in fastrl_batches[:1]] if quick
                                  else fastrl_batches[1:], control_steps, 2):  # fmt: skip
        rows.append(r)
        print(rows[-1], flush=True)
    if not quick:
        for n in (16, 64, 256):
            rows.append(bench_envpool(n, 5.0))
            print(rows[-1], flush=True)
        for backend in ("mjx", "generalized", "spring", "positional"):
            for b in (256, 1024):
                rows.append(bench_brax(backend, b, 50))
                print(rows[-1], flush=True)
    return [r for r in rows if r]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--worker", help=argparse.SUPPRESS)  # child process of bench_fastrl_devices
    args = parser.parse_args()
    if args.worker:
        return worker(json.loads(args.worker))
    rows = measure(args.quick)
    name = "contacts_throughput_quick" if args.quick else "contacts_throughput"
    text = markdown(rows)
    record = {"machine": results.machine(), "command": results.command(), "rows": rows}
    results.save(args.out, name, record, text, chart(rows), dpi=120)
    print(text)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
