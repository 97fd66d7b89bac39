"""Does a trained joystick policy (go1_joystick, humanoid_joystick) follow commands, in fastrl
and in MuJoCo C?

    python -m experiments.joystick_commands RUN_DIR          # 7 commands, 32 envs, 2 MuJoCo C episodes
    python -m experiments.joystick_commands RUN_DIR --quick    # 2 commands, 1.5 s, for CI

Each command (forward m/s, sideways m/s, yaw rad/s) is held for ``--seconds`` from the env's
reset states (the env's ``command`` option: no redraws), with nominal physics (no domain
randomisation), no observation noise and no pushes. The achieved velocity is the one the task's
tracking terms score (its ``forward_velocity``, ``sideways_velocity`` and ``yaw_rate``
metrics), averaged over the steps after the first second. The *tracking score* is the task's two
tracking terms per step, ``exp(-|command xy - v xy|^2 / sigma) + 0.5 exp(-(command yaw - yaw
rate)^2 / sigma)`` with the task's ``tracking_sigma``, averaged likewise: 1.5 at perfect
tracking. Beside it, what a robot standing still would score under the same command.

Sim-to-sim: the same policy drives MuJoCo C (the ``mujoco`` bindings) from the first
``--runs`` of the same reset states, its observation computed from ``mjData``
(``experiments/sim_to_sim.py``). Falls end an episode in both; their count is reported.

``--env NAME`` holds the commands in another env with the same observations instead of the
run's own (``--env go1_joystick_rough`` for a go1_joystick policy: the flat-ground walker on
rough ground), written as ``commands_<env>_from_<run's env>``.

Writes ``experiments/results/commands_<env>.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib

import jax
import numpy as np

import fastrl
from experiments import results, sim_to_sim
from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer
from fastrl.training.config import RunConfig

COMMANDS = ((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (1.0, 0.0, 0.0), (-0.5, 0.0, 0.0), (0.0, 0.5, 0.0),
            (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))  # fmt: skip
VELOCITY = ("forward_velocity", "sideways_velocity", "yaw_rate")
SETTLE_S = 1.0


def standing_still(command, sigma: float) -> float:
    """The tracking score of a robot that does not move, under ``command``."""
    c = np.asarray(command)
    return float(np.exp(-np.sum(c[:2] ** 2) / sigma) + 0.5 * np.exp(-(c[2] ** 2) / sigma))


def _side(env, episodes) -> dict:
    """One simulator's velocity, tracking score and falls from its ``sim_to_sim.Episodes``."""
    w, m = env.reward_weights, episodes.means
    per_step = (
        m["reward_tracking_lin_vel"] / w["tracking_lin_vel"]
        + 0.5 * m["reward_tracking_ang_vel"] / w["tracking_ang_vel"]
    ) / env.dt
    return {
        "velocity": [float(m[k].mean()) for k in VELOCITY],
        "velocity_std": [float(m[k].std()) for k in VELOCITY],
        "score": float(per_step.mean()),
        "falls": int(np.sum(m["fell"] > 0)),
    }


def measure(run_dir: str, commands, n: int, runs: int, seconds: float, env_name: str | None = None):
    """The env's name and a row per command (in ``env_name``, None: the run's env)."""
    policy = fastrl.load_policy(run_dir)
    base = sim_to_sim.nominal_env(policy, env_name=env_name)
    kicks = {"pushes": False} if "pushes" in RunConfig.from_dict(policy.run_config).env.options else {}
    steps, settle = int(round(seconds / base.dt)), int(round(SETTLE_S / base.dt))
    length = max(steps, base.episode_length)  # one episode holds the command for the whole time
    rows = []
    for command in commands:
        env = sim_to_sim.nominal_env(policy, length, env_name, command=list(command), **kicks)
        ours, start = sim_to_sim.in_fastrl(env, policy, n, steps, seed=0, skip=settle)
        first = jax.tree.map(lambda x: x[:runs], start)
        theirs = sim_to_sim.in_mujoco(env, policy, first, steps, seed=0, skip=settle)
        row = {"command": list(command), "standing_still": standing_still(command, env.tracking_sigma),
               "fastrl": _side(env, ours), "mujoco": _side(env, theirs)}  # fmt: skip
        rows.append(row)
        print(row, flush=True)
    return base.name, rows


def trained(run_dir: str) -> dict:
    """What the measured policy is: its checkpoint's env steps and the run's PPO settings."""
    ckpt = Checkpointer(pathlib.Path(run_dir) / CHECKPOINT_DIR)
    try:
        _, meta = ckpt.read_meta(ckpt.latest_step())
    finally:
        ckpt.close()
    algo = meta["config"]["algo"]
    keep = ("num_envs", "unroll_length", "num_minibatches", "init_std", "entropy_cost", "entropy_estimate")
    env = meta["config"]["env"]["name"]
    start = meta["config"].get("init_from")
    out = {"env": env, "env_steps": int(meta["env_steps"]), "algo": {k: algo.get(k) for k in keep}}
    return out | ({"init_from": start} if start else {})


def markdown(name: str, rows: list[dict], meta: dict) -> str:
    vec = lambda v: " / ".join(f"{x:+.2f}" for x in v)  # noqa: E731
    ours = np.mean([r["fastrl"]["score"] for r in rows])
    theirs = np.mean([r["mujoco"]["score"] for r in rows])
    still = np.mean([r["standing_still"] for r in rows])
    return "\n".join(
        [
            f"# {name}: does the trained policy follow commands, in fastrl and in MuJoCo C?",
            "",
            f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}; run `{meta['run_dir']}`. "
            f"Command: `{meta['command']}`.",
            "",
            f"Policy: the run's newest checkpoint, {meta['trained']['env_steps']:,} env steps of PPO"
            + (f" on {meta['trained']['env']}" if meta["trained"].get("env", name) != name else "")
            + " ("
            + ", ".join(f"{k} {v}" for k, v in meta["trained"]["algo"].items())
            + ")."
            + (
                f" The run started from the weights of `{meta['trained']['init_from']}` (`init_from`); "
                "its env steps count from there."
                if meta["trained"].get("init_from")
                else ""
            ),
            "",
            f"- **Tracking score (of 1.5) averaged over the commands: fastrl {ours:.2f}, MuJoCo C "
            f"{theirs:.2f} ({theirs / ours:.0%} of fastrl's); a robot standing still would score "
            f"{still:.2f}.** Each command held {meta['seconds']:g} s from reset (no pushes, no "
            f"noise, nominal physics), velocities averaged after the first {SETTLE_S:g} s; fastrl "
            f"over {meta['envs']} envs, MuJoCo C over {meta['runs']} of the same starts.",
            "- Velocities: forward m/s / sideways m/s / yaw rad/s, the ones the task's tracking "
            "terms score (the IMU's, in its own frame).",
            "",
            "| command | standing still | fastrl velocity | fastrl score | falls | MuJoCo C velocity "
            "| MuJoCo C score | falls |",
            "| --- | ---: | --- | ---: | ---: | --- | ---: | ---: |",
            *(
                f"| {vec(r['command'])} | {r['standing_still']:.2f} | {vec(r['fastrl']['velocity'])} "
                f"| {r['fastrl']['score']:.2f} | {r['fastrl']['falls']} | {vec(r['mujoco']['velocity'])} "
                f"| {r['mujoco']['score']:.2f} | {r['mujoco']['falls']} |"
                for r in rows
            ),
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--runs", type=int, default=2, help="MuJoCo C episodes per command")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--env", help="hold the commands in this env instead of the run's own")
    args = parser.parse_args()
    commands = COMMANDS[:3:2] if args.quick else COMMANDS
    if args.quick:
        args.envs, args.runs, args.seconds = 4, 1, 1.5
    name, rows = measure(args.run_dir, commands, args.envs, args.runs, args.seconds, args.env)
    meta = {"date": results.today(), "machine": results.machine(), "command": results.command(),
            "fastrl": results.fastrl_version(), "run_dir": args.run_dir, "envs": args.envs,
            "runs": args.runs, "seconds": args.seconds, "trained": trained(args.run_dir)}  # fmt: skip
    own = meta["trained"]["env"]
    stem = f"commands_{name}" + (f"_from_{own}" if own != name else "") + ("_quick" if args.quick else "")
    results.save(args.out, stem, {"meta": meta, "rows": rows}, markdown(name, rows, meta))
    print(markdown(name, rows, meta))


if __name__ == "__main__":
    main()
