"""The real-robot tasks' throughput beside MuJoCo C's ``rollout`` on the same scenes, in one run.

    python -m experiments.robot_throughput                  # every robot task, batch 1024 (~5 min)
    python -m experiments.robot_throughput --envs panda_pick_cube

For each task of ``fastrl/envs/robots/`` at batch 1024: control steps/s of fastrl's full env
step (physics, observation, reward, auto-reset; float32, a jitted scan of ``vmap(env.step)``
under uniform random actions), on one CPU device and split over 2 (one per core, in a child
process), as ``experiments.bench_envs`` measures them. Beside it, MuJoCo C stepping the same
scene through ``mujoco.rollout`` with 2 threads (float64, physics only: no observation or
reward), ``frame_skip`` physics steps per control step, with the servo targets that the same
kind of random actions sets from a new episode's start. And EnvPool's C++ port of the same task
(``ENVPOOL_PORTS``: physics, observation, reward, auto-reset) with 2 threads, from the peer venv
(``experiments/peers/setup_peers.sh``), at each power of two of envs from 32 up to the batch that
fits half the machine's memory (the ports hold tens of MB per env); the fastest is kept.

Writes ``experiments/results/robot_throughput.{json,md}``; a run's rows replace the earlier rows of its
envs there.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

import fastrl
from experiments import bench_envs, results
from fastrl import envs
from fastrl.envs import robots

# each robot task's scene (``assets.scene_path`` names)
SCENES = {
    cls.name: cls.scene
    for cls in vars(robots).values()
    if isinstance(cls, type) and issubclass(cls, robots.RobotTask) and cls.scene  # not the base classes
}
TASKS = sorted(SCENES)
# EnvPool's C++ ports of the same Playground tasks (observation, reward and auto-reset included)
ENVPOOL_PORTS = {
    "go1_joystick": "Go1JoystickFlatTerrain-v1",
    "go1_joystick_rough": "Go1JoystickRoughTerrain-v1",
    "humanoid_joystick": "BerkeleyHumanoidJoystickFlatTerrain-v1",
    "leap_cube_reorient": "LeapCubeReorient-v1",
    "panda_pick_cube": "PandaPickCube-v1",
}
PORT_MEMORY_SHARE = 0.5  # of physical memory: the most an EnvPool run may be expected to hold


def bench_rollout(name: str, batch: int, steps: int, seed: int = 0) -> dict:
    """MuJoCo C's control steps/s on the task's scene: ``rollout`` with 2 threads, the servo targets
    of uniform random actions from each env's start (each held for ``frame_skip`` physics steps)."""
    env = envs.make(name)
    starts = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(seed), batch))
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    actions = jax.random.uniform(
        jax.random.PRNGKey(seed + 1), (steps, batch, env.action_size), minval=low, maxval=high
    )
    ctrl = jax.vmap(jax.vmap(env._control), in_axes=(0, None))(actions, starts.task)  # (steps, batch, nu)
    control = np.repeat(np.asarray(ctrl, np.float64).transpose(1, 0, 2), env.frame_skip, axis=1)
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    md = mujoco.MjData(mj)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty((batch, mujoco.mj_stateSize(mj, spec)))
    for i in range(batch):
        md.qpos[:], md.qvel[:] = np.asarray(starts.data.qpos[i]), np.asarray(starts.data.qvel[i])
        mujoco.mj_getState(mj, md, state[i], spec)
    datas = [mujoco.MjData(mj) for _ in range(2)]
    with rollout.Rollout(nthread=2) as r:
        r.rollout(mj, datas, state, control)  # warm-up
        t0 = time.perf_counter()
        r.rollout(mj, datas, state, control)
        wall = time.perf_counter() - t0
    return {"control_steps_per_s": batch * steps / wall, "physics_steps_per_control_step": env.frame_skip}


def _envpool(env_id: str, num_envs: int, seconds: float) -> dict:
    cmd = [str(bench_envs.PEERS), str(results.ROOT / "experiments/peers/envpool_ant.py"),
           "--env-id", env_id, "--num-envs", str(num_envs), "--seconds", str(seconds)]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if out.returncode:
        raise RuntimeError(f"EnvPool {env_id} at {num_envs} envs failed: {out.stderr[-800:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_envpool_port(name: str, batch: int, seconds: float) -> dict | None:
    """EnvPool's C++ port of the task with 2 threads, at the number of envs that runs fastest among
    the powers of two from 32 up to ``batch`` whose memory (extrapolated from 32 envs' peak) fits
    ``PORT_MEMORY_SHARE`` of this machine's: the best rate, its envs, and every size tried."""
    if not bench_envs.PEERS.exists():
        return None
    first = _envpool(ENVPOOL_PORTS[name], 32, seconds)
    per_env = first["peak_rss_bytes"] / 32  # the process's base memory counted in: an overestimate
    budget = PORT_MEMORY_SHARE * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    tried = {32: first}
    n = 64
    while n <= batch and n * per_env <= budget:
        tried[n] = _envpool(ENVPOOL_PORTS[name], n, seconds)
        n *= 2
    best = max(tried, key=lambda k: tried[k]["control_steps_per_s"])
    return {
        "env_id": ENVPOOL_PORTS[name],
        "num_envs": best,
        "control_steps_per_s": tried[best]["control_steps_per_s"],
        "frame_skip": tried[best].get("frame_skip"),
        "tried": {
            k: {"control_steps_per_s": v["control_steps_per_s"], "peak_rss_bytes": v["peak_rss_bytes"]}
            for k, v in tried.items()
        },
        "envpool_version": first["envpool_version"],
    }


def markdown(rows: list[dict], commands: list[str]) -> str:
    lines = [
        "# Real-robot task throughput (control steps/s, this machine, one run)", "",
        "Runs, each later one's rows replacing the earlier rows of its envs: "
        + "; ".join(f"`{c}`" for c in commands)
        + ". fastrl: the full env step (physics, observation, reward, auto-reset; float32) on one "
        "CPU device and split over 2 (one per core), each scene stepped as "
        "its env steps it (leap_cube_reorient with MJX's broad-phase caps, its default). EnvPool: "
        "its C++ port of the same Playground task (observation, reward and auto-reset included) with "
        "2 threads, at the number of envs (a power of two up to the batch, within half the machine's "
        "memory) that ran fastest. MuJoCo C: `mujoco.rollout` with 2 threads on the same scene "
        "(float64, physics only), the servo targets of random actions. `best / EnvPool`: the better "
        "of fastrl's two columns over EnvPool's rate.", "",
        "| env | scene | batch | physics steps per control step | fastrl | fastrl, 2 devices "
        "| EnvPool port, 2 threads (envs) | best / EnvPool | MuJoCo C rollout, 2 threads "
        "| fastrl / MuJoCo C | 2 devices / MuJoCo C | compile s |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]  # fmt: skip
    for r in rows:
        one, two, peer = (r["control_steps_per_s"], r["split_2_devices"]["control_steps_per_s"],
                          r["mujoco_rollout"]["control_steps_per_s"])  # fmt: skip
        skip = r["mujoco_rollout"]["physics_steps_per_control_step"]
        port = r.get("envpool_port")
        port_cells = (
            [f"{port['control_steps_per_s']:,.0f} ({port['num_envs']})",
             f"{max(one, two) / port['control_steps_per_s']:.2f}"]
            if port else ["not run", ""]
        )  # fmt: skip
        ratios = [f"{one / peer:.2f}", f"{two / peer:.2f}", f"{r['compile_s']:.1f}"]
        cells = [r["env"], f"`{r['scene']}`", r["batch"], skip, f"{one:,.0f}", f"{two:,.0f}", *port_cells,
                 f"{peer:,.0f}", *ratios]  # fmt: skip
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="*", default=TASKS, help=f"robot tasks (default: {' '.join(TASKS)})")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--envpool-seconds", type=float, default=5.0, help="timed seconds per EnvPool size")
    parser.add_argument("--out", default=results.RESULTS, help="results folder")
    args = parser.parse_args()
    unknown = sorted(set(args.envs) - set(TASKS))
    if unknown:
        parser.error(f"not robot tasks: {', '.join(unknown)}; choose from {', '.join(TASKS)}")
    rows = []
    for name in args.envs:
        row = bench_envs.bench_fastrl(name, args.batch, args.steps)
        row["scene"] = SCENES[name]
        row["mujoco_rollout"] = bench_rollout(name, args.batch, args.steps)
        row["envpool_port"] = bench_envpool_port(name, args.batch, args.envpool_seconds)
        rows.append(row)
        print(row, flush=True)
    job = {
        "envs": [[r["env"], r["batch"]] for r in rows],
        "steps": args.steps,
        "vector": [],
        "vector_steps": 0,
    }
    split = {r["env"]: r for r in bench_envs.in_child(job, 2)}
    for r in rows:
        r["split_2_devices"] = split[r["env"]]
    save(args.out, rows)


def save(out: str, rows: list[dict]) -> None:
    """Writes the record: these rows replace the earlier rows of their envs, the others stay."""
    path = pathlib.Path(out) / "robot_throughput.json"
    before = json.loads(path.read_text()) if path.exists() else {"rows": [], "meta": {}}
    names = {r["env"] for r in rows}
    rows = sorted(
        [r for r in before["rows"] if r["env"] not in names] + rows, key=lambda r: TASKS.index(r["env"])
    )
    commands = [*before["meta"].get("commands", []), results.command()]
    meta = {
        "machine": results.machine(),
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "commands": commands,
    }
    results.save(out, "robot_throughput", {"meta": meta, "rows": rows}, markdown(rows, commands))


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
