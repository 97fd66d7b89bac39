"""``python -m fastrl.evaluate RUN_DIR``: evaluate a run's latest policy.

Runs N deterministic episodes (one per env, in one batch), prints the mean and standard deviation
of the return, and can show the first episode:

  --html out.html    a self-contained page that plays it in 3D in any browser (fastrl.tools.viewer)
  --video out.gif    a video rendered by MuJoCo (.gif, or .mp4 with imageio-ffmpeg); needs EGL
                     or OSMesa (exit status 2, with a hint, when neither works)
  --export out.npz   its qpos per step, the env name and timestep, for replay in MuJoCo
  --reference        also score the policy in MuJoCo C (Gymnasium's own v5 env for the standard
                     suite) from the same initial states, side by side (fastrl.tools.reference)
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

import jax
import numpy as np

from fastrl import agents
from fastrl.agents.evaluation import make_rollout
from fastrl.runtime import compile_cache, xla_flags
from fastrl.tools import reference, viewer
from fastrl.training.checkpoint import CheckpointError, quiet_library_logs
from fastrl.training.policy import load_run

__all__ = ["main", "make_rollout", "rollout_frames", "rollout_qpos", "run"]


def rollout_frames(env, act, params, key, length: int | None = None) -> tuple[np.ndarray, ...]:
    """(T, nq) positions, (T, M, 3) marker positions and (T,) contacts the scene's budgets
    dropped of one deterministic episode (until it ends, at most ``length`` steps)."""
    qpos, alive, marks, dropped = jax.device_get(jax.jit(make_rollout(env, act, length))(params, key))
    alive = np.asarray(alive)
    return np.asarray(qpos)[alive], np.asarray(marks)[alive], np.asarray(dropped)[alive]


def rollout_qpos(env, act, params, key, length: int | None = None) -> np.ndarray:
    """(T, nq) positions of one deterministic episode (until it ends, at most ``length`` steps)."""
    return rollout_frames(env, act, params, key, length)[0]


def main(argv: list[str] | None = None) -> NoReturn:
    """The command (``python -m fastrl.evaluate``): sets fastrl's XLA:CPU flags, which importing
    never does, then exits with ``run``'s status."""
    xla_flags.apply()
    sys.exit(run(argv))


def run(argv: list[str] | None = None) -> int:
    """Evaluates a run as the command line asks; returns the exit status (2: an unreadable run or
    no video)."""
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("run_dir", help="a run folder written by python -m fastrl.train")
    parser.add_argument("--episodes", type=int, default=16, help="episodes to run (default 16)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--export", metavar="OUT.npz", help="save the first episode's qpos trajectory")
    parser.add_argument("--html", metavar="OUT.html", help="write a 3D viewer page of the first episode")
    parser.add_argument("--video", metavar="OUT.gif", help="render the first episode (.gif or .mp4)")
    parser.add_argument("--steps", type=int, help="show at most this many steps of it (default: all)")
    parser.add_argument("--agent", help="of a batch run (train.num_seeds > 1): the agent's index or tag")
    parser.add_argument(
        "--reference", action="store_true",
        help="also score it in MuJoCo C (Gymnasium's v5 env for the standard suite), side by side",
    )  # fmt: skip
    parser.add_argument(
        "--step", type=int, help="the checkpoint (chunk) to evaluate (default: the newest that can be read)"
    )
    args = parser.parse_args(argv)
    quiet_library_logs()
    if not compile_cache.is_enabled():
        compile_cache.enable()
    agent = int(args.agent) if args.agent is not None and args.agent.isdigit() else args.agent
    try:
        rc, env, learner, state = load_run(args.run_dir, step=args.step, agent=agent)
    except CheckpointError as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        return 2
    params = learner.policy_params(state)
    evaluate = jax.jit(agents.make_evaluator(env, learner.act, args.episodes))
    ret, length, final = jax.device_get(evaluate(params, jax.random.PRNGKey(args.seed)))
    print(
        f"{rc.env.name} / {rc.algo_name} at {int(state.env_steps):,d} env steps: return "
        f"{ret.mean():.2f} +- {ret.std():.2f} over {args.episodes} episodes (length {length.mean():.0f})"
        + "".join(f", {k} {float(v.mean()):.2f}" for k, v in final.items())
    )
    if args.reference or rc.env.integrator is not None or rc.env.solver_iterations is not None:
        if args.reference:
            policy = lambda obs: learner.act(params, obs)  # noqa: E731
            scores = reference.Scores(ret, length, "fastrl")
            print(reference.side_by_side(reference.compare(rc.env, policy, args.episodes, args.seed, scores)))
        else:  # e.g. the Ant PPO run's Euler, whose scores differ from Gymnasium's RK4 Ant's
            label = reference.physics_label(env)
            print(f"(at the run's physics, {label}; --reference adds the asset's and MuJoCo C's)")
    if args.export or args.html or args.video:
        return _show(args, rc, env, learner, params, int(state.env_steps))
    return 0


def _show(args, rc, env, learner, params, env_steps: int) -> int:
    """Writes the first episode as --export, --html and --video ask (exit status 2: no video)."""
    try:
        if args.video:
            viewer.video.check_format(args.video)  # before the rollout: fail fast
        key = jax.random.PRNGKey(args.seed)
        traj, marks, dropped = rollout_frames(env, learner.act, params, key, args.steps)
        if args.export:
            np.savez(args.export, qpos=traj, env=rc.env.name, dt=env.dt)
            print(f"wrote {args.export} ({len(traj)} frames)")
        if args.html:
            title = f"{rc.env.name} / {rc.algo_name} at {env_steps:,d} env steps"
            path = viewer.write_html(env, traj, args.html, title, markers=marks, overflow=dropped)
            print(f"wrote {path} ({len(traj)} frames, {path.stat().st_size / 1e6:.2f} MB)")
        if args.video:
            print(f"wrote {viewer.render_video(env, traj, args.video)} ({len(traj)} frames)")
    except viewer.VideoError as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        return 2
    return 0
