"""Brax's own PPO on ``ant`` (spring backend) with Brax's published Ant hyperparameters.

Run inside the peer venv (see experiments/peers/setup_peers.sh):

    .venv-peers/bin/python experiments/peers/brax_ppo_ant.py                  # full run (GPU-sized)
    .venv-peers/bin/python experiments/peers/brax_ppo_ant.py --num-timesteps 20000 \\
        --num-envs 64 --batch-size 64 --num-minibatches 4 --episode-length 100 \\
        --num-eval-envs 16 --num-evals 2                                   # CPU smoke test

Calls ``brax.training.agents.ppo.train.train`` on ``brax.envs.get_environment('ant',
backend='spring')``. At every evaluation (``progress_fn``) it prints one JSON line to stdout:

    {"event": "eval", "elapsed_s": wall seconds since train() was called (compiles included),
     "env_steps": ..., "eval_return": mean eval episode return, "eval_return_std": ..., ...}

and a final ``{"event": "done", ...}`` line. Everything else (logs, warnings, MJX's import prints)
goes to stderr. Note: even a tiny ``--num-timesteps`` runs at least one full training step of
``batch_size * num_minibatches * unroll_length`` env steps (327,680 with the published settings),
plus evaluations of ``num_eval_envs`` x ``episode_length`` steps; shrink those for a CPU smoke test.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time

# Installs the jax.device_put_replicated shim (Brax 0.14 + new JAX) before brax is imported.
from brax_ant import SHIMMED, install_device_put_replicated_shim

install_device_put_replicated_shim()
with contextlib.redirect_stdout(sys.stderr):
    import brax
    import jax
    from brax import envs
    from brax.training.agents.ppo import train as ppo

# Brax's published PPO hyperparameters for Ant: the `train_fn` table of Brax's training notebook
# (google/brax notebooks/training.ipynb, the Brax v2 colab), entry 'ant':
#   ppo.train(num_timesteps=50_000_000, num_evals=10, reward_scaling=10, episode_length=1000,
#             normalize_observations=True, action_repeat=1, unroll_length=5, num_minibatches=32,
#             num_updates_per_batch=4, discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2,
#             num_envs=4096, batch_size=2048, seed=1)
# Everything not listed keeps ppo.train's defaults in brax 0.14 (e.g. clipping_epsilon=0.3,
# gae_lambda=0.95, num_eval_envs=128, network: 4x32 policy MLP and 5x256 value MLP).
NUM_TIMESTEPS = 50_000_000
NUM_EVALS = 10
REWARD_SCALING = 10.0
EPISODE_LENGTH = 1000
NORMALIZE_OBSERVATIONS = True
ACTION_REPEAT = 1
UNROLL_LENGTH = 5
NUM_MINIBATCHES = 32
NUM_UPDATES_PER_BATCH = 4
DISCOUNTING = 0.97
LEARNING_RATE = 3e-4
ENTROPY_COST = 1e-2
NUM_ENVS = 4096
BATCH_SIZE = 2048
SEED = 1
NUM_EVAL_ENVS = 128  # ppo.train's default
BACKEND = "spring"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--backend", default=BACKEND, choices=("spring", "positional", "generalized", "mjx"))
    parser.add_argument("--num-timesteps", type=int, default=NUM_TIMESTEPS)
    parser.add_argument("--num-evals", type=int, default=NUM_EVALS)
    parser.add_argument("--num-envs", type=int, default=NUM_ENVS)
    parser.add_argument("--batch-size", type=int, default=BATCH_SIZE)
    parser.add_argument("--num-minibatches", type=int, default=NUM_MINIBATCHES)
    parser.add_argument("--episode-length", type=int, default=EPISODE_LENGTH)
    parser.add_argument("--num-eval-envs", type=int, default=NUM_EVAL_ENVS)
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args()

    out = sys.stdout

    def emit(record: dict) -> None:
        out.write(json.dumps(record) + "\n")
        out.flush()

    config = {
        "num_timesteps": args.num_timesteps,
        "num_evals": args.num_evals,
        "reward_scaling": REWARD_SCALING,
        "episode_length": args.episode_length,
        "normalize_observations": NORMALIZE_OBSERVATIONS,
        "action_repeat": ACTION_REPEAT,
        "unroll_length": UNROLL_LENGTH,
        "num_minibatches": args.num_minibatches,
        "num_updates_per_batch": NUM_UPDATES_PER_BATCH,
        "discounting": DISCOUNTING,
        "learning_rate": LEARNING_RATE,
        "entropy_cost": ENTROPY_COST,
        "num_envs": args.num_envs,
        "batch_size": args.batch_size,
        "num_eval_envs": args.num_eval_envs,
        "seed": args.seed,
    }
    emit(
        {
            "event": "config",
            "peer": "brax-ppo",
            "env": "ant",
            "backend": args.backend,
            **config,
            "brax_version": brax.__version__,
            "jax_version": jax.__version__,
            "jax_backend": jax.default_backend(),
            "device_put_replicated_shim": SHIMMED,
        }
    )

    with contextlib.redirect_stdout(sys.stderr):
        env = envs.get_environment("ant", backend=args.backend)

    t0 = time.perf_counter()

    def progress_fn(num_steps: int, metrics: dict) -> None:
        emit(
            {
                "event": "eval",
                "elapsed_s": time.perf_counter() - t0,
                "env_steps": int(num_steps),
                "eval_return": float(metrics["eval/episode_reward"]),
                "eval_return_std": float(metrics.get("eval/episode_reward_std", float("nan"))),
                "training_sps": float(metrics["training/sps"]) if "training/sps" in metrics else None,
            }
        )

    with contextlib.redirect_stdout(sys.stderr):
        ppo.train(environment=env, progress_fn=progress_fn, **config)
    emit({"event": "done", "elapsed_s": time.perf_counter() - t0})


if __name__ == "__main__":
    main()
