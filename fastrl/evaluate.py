"""``python -m fastrl.evaluate RUN_DIR``: evaluate a run's latest policy.

Runs N deterministic episodes (one per env, in one batch), prints the mean and standard deviation
of the return, and can export the first episode's trajectory (``--export out.npz``: qpos per
step, the env name and timestep) for viewing or for replay in MuJoCo.
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np

from fastrl import agents
from fastrl.checkpoint import CheckpointError
from fastrl.policy import load_run


def rollout_qpos(env, act, params, key) -> np.ndarray:
    """(episode_length + 1, nq) positions of one deterministic episode (until it ends)."""
    state = env.reset(key)

    def one(carry, _):
        s, alive = carry
        nxt = env.step(s, act(params, s.obs))
        return (nxt, alive & ~nxt.done), (nxt.data.qpos, alive)

    _, (qpos, alive) = jax.lax.scan(one, (state, jnp.ones((), bool)), None, length=env.episode_length)
    qpos, alive = np.asarray(qpos), np.asarray(alive)
    return np.concatenate([np.asarray(state.data.qpos)[None], qpos[alive]])


def main(argv=None) -> int:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("run_dir", help="a run folder written by python -m fastrl.train")
    parser.add_argument("--episodes", type=int, default=16, help="episodes to run (default 16)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--export", metavar="OUT.npz", help="save the first episode's qpos trajectory")
    args = parser.parse_args(argv)
    try:
        rc, env, learner, state = load_run(args.run_dir)
    except CheckpointError as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        return 2
    params = learner.policy_params(state)
    evaluate = jax.jit(agents.make_evaluator(env, learner.act, args.episodes))
    ret, length = jax.device_get(evaluate(params, jax.random.PRNGKey(args.seed)))
    print(
        f"{rc.env.name} / {rc.algo_name} at {int(state.env_steps):,d} env steps: return "
        f"{ret.mean():.2f} +- {ret.std():.2f} over {args.episodes} episodes (length {length.mean():.0f})"
    )
    if args.export:
        traj = rollout_qpos(env, learner.act, params, jax.random.PRNGKey(args.seed))
        np.savez(args.export, qpos=traj, env=rc.env.name, dt=env.dt)
        print(f"wrote {args.export} ({len(traj)} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
