"""Brax's own PPO on one of Brax's envs, printing its learning curve as JSON lines.

Run inside the peer venv (see experiments/peers/setup_peers.sh). With no options it trains
``ant`` on the ``spring`` backend with Brax's published Ant hyperparameters:

    .venv-peers/bin/python experiments/peers/brax_ppo.py                       # full Ant run (GPU-sized)
    .venv-peers/bin/python experiments/peers/brax_ppo.py --env inverted_pendulum --backend generalized \\
        --num-envs 64 --batch-size 16 --num-minibatches 4 --unroll-length 16 --learning-rate 1e-3 \\
        --discounting 0.99 --entropy-cost 1e-3 --reward-scaling 1 --policy-hidden 32 32 \\
        --value-hidden 64 64 --num-timesteps 150000 --num-evals 10

Calls ``brax.training.agents.ppo.train.train`` on ``brax.envs.get_environment(env,
backend=...)``. At every evaluation (``progress_fn``) it prints one JSON line to stdout:

    {"event": "eval", "elapsed_s": wall seconds since train() was called (compiles included),
     "time_unix": time.time() at the evaluation, "env_steps": ...,
     "eval_return": mean eval episode return, "eval_return_std": ..., ...}

and a final ``{"event": "done", ...}`` line. Everything else (logs, warnings, MJX's import prints)
goes to stderr. Brax collects ``batch_size * num_minibatches * unroll_length`` env steps per
training step (327,680 with the published Ant settings), so even a tiny ``--num-timesteps`` runs
one of those, plus evaluations of ``num_eval_envs`` x ``episode_length`` steps.

Brax 0.14 evaluates with the *stochastic* policy (``deterministic_eval=False``, its default);
``--deterministic-eval`` evaluates the mean action like fastrl's evaluation.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import sys
import time

# Installs the jax.device_put_replicated shim (Brax 0.14 + new JAX) before brax is imported.
from brax_ant import SHIMMED, TargetReached, install_device_put_replicated_shim, train_until_target

install_device_put_replicated_shim()
with contextlib.redirect_stdout(sys.stderr):
    import brax
    import jax
    from brax import envs
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

# Brax's published PPO hyperparameters for Ant: the `train_fn` table of Brax's training notebook
# (google/brax notebooks/training.ipynb, the Brax v2 colab), entry 'ant':
#   ppo.train(num_timesteps=50_000_000, num_evals=10, reward_scaling=10, episode_length=1000,
#             normalize_observations=True, action_repeat=1, unroll_length=5, num_minibatches=32,
#             num_updates_per_batch=4, discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2,
#             num_envs=4096, batch_size=2048, seed=1)
# Everything not listed keeps ppo.train's defaults in brax 0.14 (e.g. clipping_epsilon=0.3,
# gae_lambda=0.95, num_eval_envs=128, network: 4x32 policy MLP and 5x256 value MLP, swish).
ANT = {
    "num_timesteps": 50_000_000,
    "num_evals": 10,
    "reward_scaling": 10.0,
    "episode_length": 1000,
    "unroll_length": 5,
    "num_minibatches": 32,
    "num_updates_per_batch": 4,
    "discounting": 0.97,
    "learning_rate": 3e-4,
    "entropy_cost": 1e-2,
    "num_envs": 4096,
    "batch_size": 2048,
    "seed": 1,
    "num_eval_envs": 128,  # ppo.train's default
}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="ant")
    parser.add_argument("--backend", default="spring", choices=("spring", "positional", "generalized", "mjx"))
    for key, value in ANT.items():
        parser.add_argument("--" + key.replace("_", "-"), type=type(value), default=value)
    parser.add_argument("--policy-hidden", type=int, nargs="+", default=[32] * 4)
    parser.add_argument("--value-hidden", type=int, nargs="+", default=[256] * 5)
    parser.add_argument("--deterministic-eval", action="store_true")
    parser.add_argument("--stop-at-return", type=float, default=None, help="stop at the first eval >= this")
    args = parser.parse_args()

    out = sys.stdout

    def emit(record: dict) -> None:
        out.write(json.dumps(record) + "\n")
        out.flush()

    config = {key: getattr(args, key) for key in ANT}
    config.update(normalize_observations=True, action_repeat=1, deterministic_eval=args.deterministic_eval)
    network = {"policy_hidden_layer_sizes": tuple(args.policy_hidden),
               "value_hidden_layer_sizes": tuple(args.value_hidden)}  # fmt: skip
    emit(
        {
            "event": "config",
            "peer": "brax-ppo",
            "env": args.env,
            "backend": args.backend,
            **config,
            **network,
            "brax_version": brax.__version__,
            "jax_version": jax.__version__,
            "jax_backend": jax.default_backend(),
            "device_put_replicated_shim": SHIMMED,
        }
    )

    with contextlib.redirect_stdout(sys.stderr):
        env = envs.get_environment(args.env, backend=args.backend)

    t0 = time.perf_counter()

    def progress_fn(num_steps: int, metrics: dict) -> None:
        emit(
            {
                "event": "eval",
                "elapsed_s": time.perf_counter() - t0,
                "time_unix": time.time(),
                "env_steps": int(num_steps),
                "eval_return": float(metrics["eval/episode_reward"]),
                "eval_return_std": float(metrics.get("eval/episode_reward_std", float("nan"))),
                "training_sps": float(metrics["training/sps"]) if "training/sps" in metrics else None,
            }
        )
        if args.stop_at_return is not None and float(metrics["eval/episode_reward"]) >= args.stop_at_return:
            raise TargetReached

    factory = functools.partial(ppo_networks.make_ppo_networks, **network)
    train_until_target(
        ppo.train, emit, t0, environment=env, progress_fn=progress_fn, network_factory=factory, **config
    )


if __name__ == "__main__":
    main()
