"""Sim-to-sim: does a trained robot-task policy keep its return and success in MuJoCo C?

    python -m experiments.sim_to_sim RUN_DIR                # 16 episodes in each simulator
    python -m experiments.sim_to_sim RUN_DIR --episodes 2 --steps 10 --out /tmp/s2s   # quick

The run's policy (``fastrl.load_policy``, its deterministic action) drives the run's env for
``--episodes`` episodes in fastrl (float32, as trained), with domain randomisation off, and
from the same starts (each episode's first ``qpos``, ``qvel`` and task) in MuJoCo C through
the ``mujoco`` bindings, float64, the scene as written, with the env's own change before each
step's physics (a push, a goal cube's pose). On MuJoCo C's side the policy sees the
task's ``observation_from_mujoco`` of ``mjData``; each step's reward, termination and the
task's next state (e.g. redrawn commands, the servo targets an action moved) come from the
env's own reward function applied to MuJoCo C's state (its kinematics and contacts computed
by fastrl from MuJoCo C's ``qpos`` and ``qvel``), so both sides are scored alike.

Reports each side's mean return and each of the env's ``eval_metrics`` (e.g. ``success``) at
an episode's last step, and MuJoCo C's as a fraction of fastrl's. Writes
``experiments/results/sim_to_sim_<env>.{json,md}`` (``--out`` another folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.training.config import RunConfig

NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0, "damping": 0.0}


def nominal_env(policy):
    """The run's env with domain randomisation off (and no observation noise where it has some)."""
    config = RunConfig.from_dict(policy.run_config).env
    options = dict(config.options)
    if "observation_noise" in options:
        options["observation_noise"] = 0.0
    return dataclasses.replace(config, randomization=NOMINAL, options=options).make()


def in_fastrl(env, policy, episodes: int, steps: int, seed: int):
    """Episodes of ``steps`` control steps (or to termination): returns, the eval metrics at each
    episode's last step, and the starts (reset states) for MuJoCo C."""
    start = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(seed), episodes))

    def body(carry, _):
        state, alive, ret, last = carry
        state = jax.vmap(env.step)(state, policy(state.obs))
        ret = ret + jnp.where(alive, state.reward, 0.0)
        last = {k: jnp.where(alive, state.metrics[k], v) for k, v in last.items()}
        return (state, alive & ~state.terminated, ret, last), None

    names = tuple(getattr(env, "eval_metrics", ()))
    zero = jnp.zeros(episodes, start.obs.dtype)
    init = (start, jnp.ones(episodes, bool), zero, {k: zero for k in names})
    (_, _, ret, last), _ = jax.jit(lambda c: jax.lax.scan(body, c, None, length=steps))(init)
    return np.asarray(ret), {k: np.asarray(v) for k, v in last.items()}, start


def in_mujoco(env, policy, start, steps: int, seed: int):
    """The same episodes in MuJoCo C from ``start``'s states and tasks."""
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    names = tuple(getattr(env, "eval_metrics", ()))
    with jax.enable_x64(True):
        model = physics.load_mjcf(env.asset_path, linesearch=env.linesearch)

        @jax.jit
        def score(before, qpos, qvel, ctrl, action, task, key):
            after = physics.forward(model, physics.make_data(model, qpos=qpos, qvel=qvel, ctrl=ctrl))
            terms, terminated, extra, task = env._reward_task(model, before, after, action, task, key)
            return after, sum(terms.values()), terminated, {k: extra[k] for k in names}, task

        first = jax.jit(
            lambda qpos, qvel: physics.forward(model, physics.make_data(model, qpos=qpos, qvel=qvel))
        )

        @jax.jit
        def prepare(qpos, qvel, task):  # the env's change before a step's physics (a push, a goal)
            data = env._before_physics(physics.make_data(model, qpos=qpos, qvel=qvel), task)
            return data.qvel, data.mocap_pos, data.mocap_quat

        act = jax.jit(policy)
        returns, metrics = [], {k: [] for k in names}
        for i in range(start.obs.shape[0]):
            task = jax.tree.map(lambda x, i=i: jnp.asarray(np.asarray(x[i])), start.task)
            md = mujoco.MjData(mj)
            md.qpos[:], md.qvel[:] = np.asarray(start.data.qpos[i]), np.asarray(start.data.qvel[i])
            mujoco.mj_forward(mj, md)
            before = first(md.qpos.copy(), md.qvel.copy())
            ret, last = 0.0, {}
            for t in range(steps):
                obs = env.observation_from_mujoco(md, task)
                action = jnp.asarray(act(jnp.asarray(obs, jnp.float32)), jnp.float64)
                ctrl = np.asarray(env._control(action, task))
                md.ctrl[:] = ctrl
                qvel, mocap_pos, mocap_quat = prepare(md.qpos.copy(), md.qvel.copy(), task)
                md.qvel[:] = np.asarray(qvel)
                if mj.nmocap:
                    md.mocap_pos[:], md.mocap_quat[:] = np.asarray(mocap_pos), np.asarray(mocap_quat)
                for _ in range(env.frame_skip):
                    mujoco.mj_step(mj, md)
                key = jax.random.fold_in(jax.random.PRNGKey(seed), i * 100_003 + t)
                before, reward, terminated, last, task = score(
                    before, md.qpos.copy(), md.qvel.copy(), ctrl, action, task, key
                )
                ret += float(reward)
                if bool(terminated):
                    break
            returns.append(ret)
            for k in names:
                metrics[k].append(float(last[k]))
    return np.asarray(returns), {k: np.asarray(v) for k, v in metrics.items()}


def measure(run_dir: str, episodes: int, steps: int | None, seed: int = 0) -> dict:
    policy = fastrl.load_policy(run_dir)
    env = nominal_env(policy)
    steps = steps or env.episode_length
    ret, last, start = in_fastrl(env, policy, episodes, steps, seed)
    mj_ret, mj_last = in_mujoco(env, policy, start, steps, seed)
    side = lambda r, m: {"return": float(r.mean()), "return_std": float(r.std()),  # noqa: E731
                         **{k: float(v.mean()) for k, v in m.items()}}  # fmt: skip
    row = {"env": env.name, "run_dir": str(run_dir), "episodes": episodes, "steps": steps,
           "fastrl": side(ret, last), "mujoco": side(mj_ret, mj_last)}  # fmt: skip
    row["kept"] = {k: (row["mujoco"][k] / row["fastrl"][k] if row["fastrl"][k] else None)
                   for k in ("return", *last)}  # fmt: skip
    return row


def markdown(row: dict) -> str:
    names = [k for k in row["fastrl"] if k not in ("return", "return_std")]
    f, m, kept = row["fastrl"], row["mujoco"], row["kept"]
    pct = lambda x: "-" if x is None else f"{100 * x:.0f}%"  # noqa: E731
    lines = [
        f"# Sim-to-sim: {row['env']} in fastrl and in MuJoCo C", "",
        f"Command: `{results.command()}`. Run: `{row['run_dir']}`. {row['episodes']} episodes of up to "
        f"{row['steps']} control steps from the same starts, domain randomisation off; the policy's "
        "deterministic action. MuJoCo C: the scene as written, float64, the policy reading "
        "`observation_from_mujoco`; both sides scored by the env's reward function.", "",
        "| simulator | return | " + " | ".join(names) + " |",
        "| --- | ---: |" + " ---: |" * len(names),
        *(f"| {label} | {s['return']:.1f} ± {s['return_std']:.1f} | "
          + " | ".join(f"{s[k]:.2f}" for k in names) + " |" for label, s in (("fastrl", f), ("MuJoCo C", m))),
        "| MuJoCo C / fastrl | " + " | ".join(pct(kept[k]) for k in ("return", *names)) + " |",
    ]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument(
        "--steps", type=int, default=None, help="control steps per episode (default: the env's)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS, help="results folder")
    args = parser.parse_args()
    row = measure(args.run_dir, args.episodes, args.steps, args.seed)
    print(row)
    row["meta"] = {"machine": results.machine()}
    results.save(args.out, f"sim_to_sim_{row['env']}", row, markdown(row))


if __name__ == "__main__":
    main()
