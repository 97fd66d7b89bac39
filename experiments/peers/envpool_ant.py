"""EnvPool throughput (control steps/s) of ``Ant-v4`` or any ``--env-id``, as one JSON line.

Run inside the peer venv (see experiments/peers/setup_peers.sh):

    .venv-peers/bin/python experiments/peers/envpool_ant.py --num-envs 64 --seconds 5

Uses the synchronous API: every call steps all ``num_envs`` environments (``env.step(actions,
env_ids)`` with all ids) with fresh uniform random actions in [-1, 1]; EnvPool auto-resets
finished episodes on their next step, and those reset steps are counted like any other. Throughput
is ``num_envs * calls / wall seconds`` over ``--seconds`` after ``--warmup`` seconds of stepping;
``peak_rss_bytes`` is the process's peak resident memory.
The model's integrator and timestep are read from the MJCF file that EnvPool loads
(``<base_path>/mujoco/assets_gym/<xml_file>`` from the env config): Gymnasium's ant.xml, RK4 at
0.01 s, and frame_skip 5, i.e. 0.05 s per control step.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
import xml.etree.ElementTree as ET

import envpool
import numpy as np

ENV_ID = "Ant-v4"
NUM_THREADS = 2
# MuJoCo's defaults when <option> omits them.
MJ_DEFAULT_INTEGRATOR = "Euler"
MJ_DEFAULT_TIMESTEP = 0.002


def model_options(config: dict) -> dict:
    """Integrator and timestep from the MJCF file EnvPool loads; empty if it cannot be found."""
    base, xml_file = config.get("base_path"), config.get("xml_file")
    if not base or not xml_file:
        return {}
    path = os.path.join(base, "mujoco", "assets_gym", xml_file)
    if not os.path.isfile(path):
        return {}
    option = ET.parse(path).getroot().find("option")
    attrs = option.attrib if option is not None else {}
    integrator = attrs.get("integrator", MJ_DEFAULT_INTEGRATOR)
    return {
        "timestep": float(attrs.get("timestep", MJ_DEFAULT_TIMESTEP)),
        "integrator": integrator,
        "rk4": integrator.upper() == "RK4",
        "model_xml": path,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env-id", default=ENV_ID, help=f"EnvPool task id (default {ENV_ID})")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--seconds", type=float, default=5.0, help="measured stepping time")
    parser.add_argument("--warmup", type=float, default=1.0, help="un-timed stepping before measuring")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    n = args.num_envs
    env = envpool.make_gymnasium(
        args.env_id, num_envs=n, batch_size=n, num_threads=NUM_THREADS, seed=args.seed
    )
    config = dict(env.spec.config._asdict())
    space = env.action_space
    rng = np.random.default_rng(args.seed)
    env_ids = np.arange(n, dtype=np.int32)

    def actions() -> np.ndarray:
        return rng.uniform(space.low, space.high, size=(n, *space.shape)).astype(space.dtype)

    env.reset()
    t_end = time.perf_counter() + args.warmup
    while time.perf_counter() < t_end:
        env.step(actions(), env_ids)

    calls = 0
    t0 = time.perf_counter()
    t_end = t0 + args.seconds
    while True:
        env.step(actions(), env_ids)
        calls += 1
        now = time.perf_counter()
        if now >= t_end:
            break
    wall = now - t0
    env.close()

    out = {
        "peer": "envpool",
        "env": args.env_id,
        "num_envs": n,
        "num_threads": NUM_THREADS,
        "control_steps_per_s": n * calls / wall,
    }
    if "frame_skip" in config:
        out["frame_skip"] = int(config["frame_skip"])
    opts = model_options(config)
    out.update({k: opts[k] for k in ("timestep", "integrator", "rk4") if k in opts})
    if "frame_skip" in out:
        out["physics_steps_per_s"] = out["control_steps_per_s"] * out["frame_skip"]
    out.update({"calls": calls, "wall_s": wall, "envpool_version": envpool.__version__})
    out["peak_rss_bytes"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps(out))


if __name__ == "__main__":
    main()
