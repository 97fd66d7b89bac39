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
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.training.config import RunConfig

NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0, "damping": 0.0}


def nominal_env(policy, episode_length: int | None = None, env_name: str | None = None, **options):
    """The run's env (or ``env_name``, another env with the same observations: a flat-ground
    policy on rough ground) with domain randomisation and observation noise off, and ``options``
    (e.g. a held ``command``) over its own; ``episode_length`` (None: the run's)."""
    config = RunConfig.from_dict(policy.run_config).env
    quiet = {"observation_noise": 0.0} if "observation_noise" in config.options else {}
    return dataclasses.replace(
        config, name=env_name or config.name, randomization=NOMINAL,
        options={**config.options, **quiet, **options},
        episode_length=episode_length or config.episode_length,
    ).make().for_evaluation()  # fmt: skip


class Episodes(NamedTuple):
    """What episodes in one simulator gave: each episode's return (E,), each of the env's
    ``eval_metrics`` at its last step, and each of its step metrics (``State.metrics``: reward
    terms, motion) averaged over its steps from ``skip`` on while the episode lasted."""

    returns: np.ndarray
    last: dict
    means: dict


def _mean(total, count):
    return {k: np.asarray(v) / np.maximum(np.asarray(count), 1) for k, v in total.items()}


def in_fastrl(env, policy, episodes: int, steps: int, seed: int, skip: int = 0):
    """Episodes of ``steps`` control steps (or to their end) from the resets of ``seed``:
    ``Episodes``, and the starts (reset states) for MuJoCo C."""
    start = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(seed), episodes))

    def body(carry, t):
        state, alive, ret, last, total, count = carry
        state = jax.vmap(env.step)(state, policy(state.obs))
        ret = ret + jnp.where(alive, state.reward, 0.0)
        last = {k: jnp.where(alive, state.metrics[k], v) for k, v in last.items()}
        on = alive & (t >= skip)
        total = {k: v + jnp.where(on, state.metrics[k], 0.0) for k, v in total.items()}
        return (state, alive & ~state.done, ret, last, total, count + on), None

    names = tuple(getattr(env, "eval_metrics", ()))
    zero = jnp.zeros(episodes, start.obs.dtype)
    init = (start, jnp.ones(episodes, bool), zero, {k: zero for k in names},
            {k: zero for k in start.metrics}, zero)  # fmt: skip
    scan = jax.jit(lambda c: jax.lax.scan(body, c, jnp.arange(steps)))
    (_, _, ret, last, total, count), _ = scan(init)
    out = Episodes(np.asarray(ret), {k: np.asarray(v) for k, v in last.items()}, _mean(total, count))
    return out, start


def in_mujoco(env, policy, start, steps: int, seed: int, skip: int = 0) -> Episodes:
    """The same episodes in MuJoCo C from ``start``'s states and tasks."""
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    names = tuple(getattr(env, "eval_metrics", ()))
    with jax.enable_x64(True):
        model = physics.load_mjcf(env.asset_path, linesearch=env.linesearch)

        @jax.jit
        def score(before, qpos, qvel, ctrl, action, task, key):
            after = physics.forward(model, physics.make_data(model, qpos=qpos, qvel=qvel, ctrl=ctrl))
            terms, terminated, extra, task = env._reward_task(model, before, after, action, task, key)
            metrics = {**{f"reward_{k}": v for k, v in terms.items()}, **extra}
            return after, sum(terms.values()), terminated, metrics, task

        first = jax.jit(
            lambda qpos, qvel: physics.forward(model, physics.make_data(model, qpos=qpos, qvel=qvel))
        )

        @jax.jit
        def prepare(qpos, qvel, task):  # the env's change before a step's physics (a push, a goal)
            data = env._before_physics(physics.make_data(model, qpos=qpos, qvel=qvel), task)
            return data.qvel, data.mocap_pos, data.mocap_quat

        act = jax.jit(policy)
        returns, lasts, totals, counts = [], [], [], []
        for i in range(start.obs.shape[0]):
            task = jax.tree.map(lambda x, i=i: jnp.asarray(np.asarray(x[i])), start.task)
            md = mujoco.MjData(mj)
            md.qpos[:], md.qvel[:] = np.asarray(start.data.qpos[i]), np.asarray(start.data.qvel[i])
            mujoco.mj_forward(mj, md)
            before = first(md.qpos.copy(), md.qvel.copy())
            ret, metrics, total, count = 0.0, {}, {}, 0
            for t in range(min(steps, env.episode_length)):
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
                before, reward, terminated, metrics, task = score(
                    before, md.qpos.copy(), md.qvel.copy(), ctrl, action, task, key
                )
                ret += float(reward)
                total = {k: total.get(k, 0.0) + float(v) * (t >= skip) for k, v in metrics.items()}
                count += t >= skip
                if bool(terminated):
                    break
            returns.append(ret)
            lasts.append({k: float(metrics[k]) for k in names})
            totals.append(total)
            counts.append(count)
    stack = lambda rows, keys: {k: np.asarray([r.get(k, 0.0) for r in rows]) for k in keys}  # noqa: E731
    keys = sorted({k for t in totals for k in t})
    return Episodes(np.asarray(returns), stack(lasts, names), _mean(stack(totals, keys), counts))


def measure(run_dir: str, episodes: int, steps: int | None, seed: int = 0) -> dict:
    policy = fastrl.load_policy(run_dir)
    env = nominal_env(policy)
    steps = steps or env.episode_length
    ours, start = in_fastrl(env, policy, episodes, steps, seed)
    theirs = in_mujoco(env, policy, start, steps, seed)
    side = lambda e: {"return": float(e.returns.mean()), "return_std": float(e.returns.std()),  # noqa: E731
                      **{k: float(v.mean()) for k, v in e.last.items()}}  # fmt: skip
    row = {"env": env.name, "run_dir": str(run_dir), "episodes": episodes, "steps": steps,
           "fastrl": side(ours), "mujoco": side(theirs)}  # fmt: skip
    row["kept"] = {k: (row["mujoco"][k] / row["fastrl"][k] if row["fastrl"][k] else None)
                   for k in ("return", *ours.last)}  # fmt: skip
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
        "| " + " | ".join(["simulator", "return", *names]) + " |",
        "| --- | ---: |" + " ---: |" * len(names),
        *("| " + " | ".join([label, f"{s['return']:.1f} ± {s['return_std']:.1f}",
                             *(f"{s[k]:.2f}" for k in names)]) + " |"
          for label, s in (("fastrl", f), ("MuJoCo C", m))),
        "| " + " | ".join(["MuJoCo C / fastrl", *(pct(kept[k]) for k in ("return", *names))]) + " |",
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
