"""Where a trained Ant's trajectories part: fastrl against MuJoCo C, and MuJoCo C against itself.

    python -m experiments.trajectory_parting RUN_DIR                  # 8 episodes per integrator
    python -m experiments.trajectory_parting --quick --out DIR        # tiny, for CI

Closed loop, the run's deterministic policy, each episode from the same initial state (fastrl's
evaluation draws, seed 0), at Euler and at RK4 (fastrl at the run's solver iterations for Euler,
the asset's for RK4; MuJoCo C at the same integrator, converged solver, float64):

* the first step at which the two simulators' ``qpos`` differ by more than 1e-4, 1e-3, 1e-2
  and 1e-1 (max over coordinates), and fastrl's one-step error: one fastrl env step from
  MuJoCo's state with MuJoCo's action, against MuJoCo's next state (median and max over the
  episode's first 400 steps);
* the same parting steps for MuJoCo C against MuJoCo C with the initial velocities moved by
  1e-7 (about float32's rounding of them): how fast any two nearly equal simulations part.

Writes ``results/trajectory_parting.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from experiments.reference_scores import quick_run
from fastrl import envs, physics
from fastrl.tools import reference
from fastrl.training.policy import load_run

THRESHOLDS = (1e-4, 1e-3, 1e-2, 1e-1)


def _parting(a: np.ndarray, b: np.ndarray) -> list[int | None]:
    """First step at which the (T, nq) trajectories differ by more than each threshold."""
    n = min(len(a), len(b))
    diff = np.abs(a[:n] - b[:n]).max(axis=1)
    return [int(np.argmax(diff > th)) if (diff > th).any() else None for th in THRESHOLDS]


def _fastrl_rollouts(env, act, start_key, episodes: int) -> list[np.ndarray]:
    """(T_i, nq) qpos of each closed-loop fastrl episode, until it ends."""

    def one(key):
        def body(carry, _):
            s, alive = carry
            nxt = env.step(s, act(s.obs))
            return (nxt, alive & ~nxt.done), (nxt.data.qpos, alive)

        _, (qpos, alive) = jax.lax.scan(
            body, (env.reset(key), jnp.ones((), bool)), None, length=env.episode_length
        )
        return qpos, alive

    qpos, alive = jax.device_get(jax.jit(jax.vmap(one))(jax.random.split(start_key, episodes)))
    return [q[a] for q, a in zip(np.asarray(qpos), np.asarray(alive), strict=True)]


def _mujoco_rollout(env, m, policy, start, i: int, eps: float, one_step=None):
    """(T, nq) qpos of MuJoCo C's closed-loop episode i, and fastrl's one-step errors along it."""
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(start.data.qpos[i], np.float64)
    d.qvel[:] = np.asarray(start.data.qvel[i], np.float64) + eps
    mujoco.mj_forward(m, d)
    obs, out, errors = np.asarray(start.obs[i]), [], []
    for t in range(env.episode_length):
        action = np.asarray(policy(jnp.asarray(obs, jnp.float32)), np.float64)
        q0, v0, ws = d.qpos.copy(), d.qvel.copy(), d.qacc_warmstart.copy()
        d.ctrl[:] = action
        for _ in range(env.frame_skip):
            mujoco.mj_step(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        out.append(d.qpos.copy())
        if one_step is not None and t < 400:
            q1 = np.asarray(one_step(*(jnp.asarray(x, jnp.float32) for x in (q0, v0, ws, action))))
            errors.append(float(np.abs(q1 - d.qpos).max()))
        obs = np.concatenate([d.qpos[2:], d.qvel, np.clip(d.cfrc_ext[1:], -1, 1).ravel()])
        if not 0.2 <= d.qpos[2] <= 1.0:  # the Ant's termination
            break
    return np.array(out), errors


def measure(run_dir: str, episodes: int, length: int | None = None) -> list[dict]:
    rc, run_env, learner, state = load_run(run_dir)
    params = learner.policy_params(state)
    act = lambda obs: learner.act(params, obs)  # noqa: E731
    policy = jax.jit(act)
    rows = []
    settings = {"euler": run_env.model.solver_iterations, "rk4": None}
    for integrator, iterations in settings.items():
        env = envs.make(
            rc.env.name, integrator=integrator, solver_iterations=iterations, episode_length=length
        )
        key = jax.random.PRNGKey(0)
        start = reference.start_states(env, episodes, key)
        m = reference._asset_model(env, integrator)

        @jax.jit
        def one_step(q, v, warmstart, action, env=env):
            data = physics.make_data(env.model, qpos=q, qvel=v).replace(qacc_warmstart=warmstart)
            for _ in range(env.frame_skip):
                data = physics.step(env.model, data, action)
            return data.qpos

        ours = _fastrl_rollouts(env, act, key, episodes)
        for i in range(episodes):
            mj, errors = _mujoco_rollout(env, m, policy, start, i, 0.0, one_step)
            mj_moved, _ = _mujoco_rollout(env, m, policy, start, i, 1e-7)
            rows.append({
                "integrator": integrator, "solver_iterations": env.model.solver_iterations, "episode": i,
                "fastrl_vs_mujoco": _parting(ours[i], mj), "mujoco_vs_moved": _parting(mj, mj_moved),
                "one_step_median": float(np.median(errors)), "one_step_max": float(np.max(errors)),
            })  # fmt: skip
            print(rows[-1], flush=True)
    return rows


def render(rows: list[dict], command: str) -> str:
    fmt = lambda p: ", ".join("-" if s is None else str(s) for s in p)  # noqa: E731
    lines = [
        "# Where a trained Ant's trajectories part: fastrl against MuJoCo C",
        "",
        f"Date: {results.today()}. Machine: {results.machine()}. Command: `{command}`.",
        "First step (of 1000) at which max |qpos difference| exceeds 1e-4, 1e-3, 1e-2, 1e-1; '-': "
        "never. One-step error: max |qpos| difference after one fastrl env step from MuJoCo's "
        "state (first 400 steps).",
        "",
        "| integrator | iterations (fastrl) | episode | fastrl vs MuJoCo C "
        "| MuJoCo C vs MuJoCo C, qvel + 1e-7 | one-step error median | max |",
        "| --- | ---: | ---: | --- | --- | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['integrator']} | {r['solver_iterations']} | {r['episode']} "
            f"| {fmt(r['fastrl_vs_mujoco'])} | {fmt(r['mujoco_vs_moved'])} "
            f"| {r['one_step_median']:.1e} | {r['one_step_max']:.1e} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", nargs="?", help="an Ant run folder")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--out", default=str(results.RESULTS))
    parser.add_argument("--quick", action="store_true", help="an untrained Ant, 1 episode of 30 steps")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    command = results.command(None if argv is None else [__file__, *argv])
    if args.quick:
        with tempfile.TemporaryDirectory() as tmp:
            rows = measure(quick_run(pathlib.Path(tmp), "ant"), 1, length=30)
        name = "trajectory_parting_quick"
    else:
        rows = measure(args.run_dir, args.episodes)
        name = "trajectory_parting"
    results.save(out, name, {"command": command, "rows": rows}, render(rows, command))
    print(f"wrote {out / name}.{{md,json}}")
    return 0


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    sys.exit(main())
