"""Does a trained go1_joystick policy follow commands, in fastrl and in MuJoCo C?

    python -m experiments.go1_commands RUN_DIR            # 7 commands, 32 envs each + 2 MuJoCo C runs
    python -m experiments.go1_commands RUN_DIR --quick    # 2 commands, 1 s, for CI

Each command (forward m/s, sideways m/s, yaw rad/s) is held for ``--seconds`` (no redraws) from
the env's reset states, with nominal physics (no domain randomisation) and no observation noise.
The achieved velocity is the trunk's in its own frame (planar velocity and yaw rate), averaged
over the time after the first second. The *tracking score* is the task's two tracking terms per
step, ``exp(-|command xy - v xy|^2 / 0.25) + 0.5 exp(-(command yaw - yaw rate)^2 / 0.25)``, averaged
(1.5 at perfect tracking; a robot standing still under a 1 m/s command scores ~0.52).

Sim-to-sim: the same policy drives MuJoCo C (the ``mujoco`` bindings) from the same reset
states, its observation computed from ``mjData`` (``Go1Joystick.observation_from_mujoco``).
Falls end an episode in both; their count is reported.

Writes ``experiments/results/go1_commands.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from fastrl import envs

COMMANDS = ((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (1.0, 0.0, 0.0), (-0.5, 0.0, 0.0), (0.0, 0.5, 0.0),
            (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))  # fmt: skip
NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0}
SIGMA = 0.25  # the task's tracking_sigma
SETTLE_S = 1.0


def _body_velocity(qpos, qvel) -> np.ndarray:
    """(..., 3): the trunk's forward and sideways velocity in its own frame, and its yaw rate."""
    rot = np.stack([np.asarray(_quat_mat(q)) for q in np.reshape(qpos[..., 3:7], (-1, 4))])
    rot = rot.reshape(*qpos.shape[:-1], 3, 3)
    local = np.einsum("...ji,...j->...i", rot, qvel[..., :3])
    return np.concatenate([local[..., :2], qvel[..., 5:6]], -1)


def _quat_mat(q) -> np.ndarray:
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, np.asarray(q, np.float64))
    return mat.reshape(3, 3)


def _score(command, vel) -> np.ndarray:
    lin = np.exp(-np.sum((command[:2] - vel[..., :2]) ** 2, -1) / SIGMA)
    return lin + 0.5 * np.exp(-((command[2] - vel[..., 2]) ** 2) / SIGMA)


def _fastrl(env, policy, command, n: int, steps: int):
    """Velocities (steps, n, 3) and whether each env fell, the command held."""
    state = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), n))
    cmd = jnp.broadcast_to(jnp.asarray(command, state.obs.dtype), (n, 3))
    task = dict(state.task, command=cmd, resample_in=jnp.full(n, 10**9, jnp.int32))
    state = state.replace(task=task, obs=state.obs.at[:, -3:].set(cmd))  # the command ends the obs
    start = (np.asarray(state.data.qpos), np.asarray(state.data.qvel))

    def body(s, _):
        s = jax.vmap(env.step)(s, policy(s.obs))
        return s, (s.data.qpos, s.data.qvel, s.done)

    _, (qpos, qvel, done) = jax.jit(lambda s: jax.lax.scan(body, s, None, length=steps))(state)
    return _body_velocity(np.asarray(qpos), np.asarray(qvel)), np.asarray(done).any(0), start


def _mujoco(env, policy, command, start, runs: int, steps: int):
    """The same in MuJoCo C, from the first ``runs`` of fastrl's reset states."""
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    act = jax.jit(policy)
    vels, fell = [], []
    for i in range(runs):
        md = mujoco.MjData(mj)
        md.qpos[:], md.qvel[:] = start[0][i], start[1][i]
        mujoco.mj_forward(mj, md)
        task = {
            "noise": np.zeros(33),
            "last_action": np.zeros(env.action_size),
            "command": np.asarray(command),
        }
        out, down = [], False
        for _ in range(steps):
            action = np.asarray(act(jnp.asarray(env.observation_from_mujoco(md, task), jnp.float32)))
            md.ctrl[:] = np.asarray(env._control(jnp.asarray(action), task))
            for _ in range(env.frame_skip):
                mujoco.mj_step(mj, md)
            task["last_action"] = action
            out.append(_body_velocity(md.qpos[None], md.qvel[None])[0])
            down |= _quat_mat(md.qpos[3:7])[2, 2] < 0
        vels.append(out)
        fell.append(down)
    return np.transpose(np.asarray(vels), (1, 0, 2)), np.asarray(fell)


def measure(run_dir: str, commands, n: int, runs: int, seconds: float) -> list[dict]:
    policy = fastrl.load_policy(run_dir)
    env = envs.make("go1_joystick", randomization=NOMINAL, observation_noise=0.0)
    steps, settle = int(round(seconds / env.dt)), int(round(SETTLE_S / env.dt))
    rows = []
    for command in commands:
        vel, fell, start = _fastrl(env, policy, command, n, steps)
        mj_vel, mj_fell = _mujoco(env, policy, command, start, runs, steps)
        c = np.asarray(command)
        rows.append(
            {
                "command": list(command),
                "fastrl_velocity": vel[settle:].mean((0, 1)).tolist(),
                "fastrl_velocity_std": vel[settle:].mean(0).std(0).tolist(),
                "fastrl_score": float(_score(c, vel[settle:]).mean()),
                "fastrl_falls": int(fell.sum()),
                "mujoco_velocity": mj_vel[settle:].mean((0, 1)).tolist(),
                "mujoco_score": float(_score(c, mj_vel[settle:]).mean()),
                "mujoco_falls": int(mj_fell.sum()),
            }
        )
        print(rows[-1], flush=True)
    return rows


def trained(run_dir: str) -> dict:
    """What the measured policy is: its checkpoint's env steps and the run's PPO settings."""
    from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer

    ckpt = Checkpointer(pathlib.Path(run_dir) / CHECKPOINT_DIR)
    try:
        _, meta = ckpt.read_meta(ckpt.latest_step())
    finally:
        ckpt.close()
    algo = meta["config"]["algo"]
    keep = ("num_envs", "unroll_length", "num_minibatches", "init_std", "entropy_cost", "entropy_estimate")
    return {"env_steps": int(meta["env_steps"]), "algo": {k: algo.get(k) for k in keep}}


def markdown(rows: list[dict], meta: dict) -> str:
    vec = lambda v: " / ".join(f"{x:+.2f}" for x in v)  # noqa: E731
    ours = np.mean([r["fastrl_score"] for r in rows])
    theirs = np.mean([r["mujoco_score"] for r in rows])
    return "\n".join(
        [
            "# go1_joystick: does the trained policy follow commands, in fastrl and in MuJoCo C?",
            "",
            f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}; run `{meta['run_dir']}`. "
            f"Command: `{meta['command']}`.",
            "",
            f"Policy: the run's newest checkpoint, {meta['trained']['env_steps']:,} env steps of PPO ("
            + ", ".join(f"{k} {v}" for k, v in meta["trained"]["algo"].items())
            + ").",
            "",
            f"- **Tracking score (of 1.5) averaged over the commands: fastrl {ours:.2f}, MuJoCo C "
            f"{theirs:.2f} ({theirs / ours:.0%} of fastrl's).** Each command held {meta['seconds']:g} s "
            f"from reset, velocities averaged after the first {SETTLE_S:g} s; fastrl over "
            f"{meta['envs']} envs, MuJoCo C over {meta['runs']} of the same starts.",
            "- Velocities: forward m/s / sideways m/s / yaw rad/s, in the trunk's frame. A robot "
            "that stands still scores 1.5 under the zero command and about 0.52 under a 1 m/s "
            "forward one.",
            "",
            "| command | fastrl velocity | fastrl score | falls | MuJoCo C velocity | MuJoCo C score "
            "| falls |",
            "| --- | --- | ---: | ---: | --- | ---: | ---: |",
            *(
                f"| {vec(r['command'])} | {vec(r['fastrl_velocity'])} | {r['fastrl_score']:.2f} "
                f"| {r['fastrl_falls']} | {vec(r['mujoco_velocity'])} | {r['mujoco_score']:.2f} "
                f"| {r['mujoco_falls']} |"
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
    args = parser.parse_args()
    commands = COMMANDS[:3:2] if args.quick else COMMANDS
    if args.quick:
        args.envs, args.runs, args.seconds = 4, 1, 1.5
    rows = measure(args.run_dir, commands, args.envs, args.runs, args.seconds)
    meta = {"date": results.today(), "machine": results.machine(), "command": results.command(),
            "fastrl": results.fastrl_version(), "run_dir": args.run_dir, "envs": args.envs,
            "runs": args.runs, "seconds": args.seconds, "trained": trained(args.run_dir)}  # fmt: skip
    stem = "go1_commands_quick" if args.quick else "go1_commands"
    results.save(args.out, stem, {"meta": meta, "rows": rows}, markdown(rows, meta))
    print(markdown(rows, meta))


if __name__ == "__main__":
    main()
