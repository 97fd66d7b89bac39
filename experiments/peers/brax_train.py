"""Brax's own SAC, ES or APG on one of Brax's envs, printing its learning curve as JSON lines.

Run inside the peer venv (see experiments/peers/setup_peers.sh), e.g.

    .venv-peers/bin/python experiments/peers/brax_train.py --algo sac --env hopper \\
        --hidden 256 256 --set num_envs=64 grad_updates_per_step=16 batch_size=256 \\
        learning_rate=6e-4 discounting=0.99 min_replay_size=10000 num_timesteps=1000000 num_evals=21

``--set KEY=VALUE`` passes keyword arguments to ``brax.training.agents.<algo>.train.train``
(values are Python literals; anything else is a string); ``--hidden`` sets the networks'
hidden layers (``hidden_layer_sizes`` of Brax's network factory for that algorithm; ``--hidden``
with no widths makes the policy linear). Everything
not set keeps Brax 0.14's defaults except ``episode_length=1000`` and
``normalize_observations=True``. With ``--stop-at-return X`` the run stops at its first
evaluation whose return is at least X (``progress_fn`` raises; Brax has no such option).

Output, like ``brax_ppo.py``: one ``{"event": "eval", "elapsed_s", "time_unix", "env_steps",
"eval_return", ...}`` line per evaluation, then ``{"event": "done", ...}``; everything else goes to
stderr. Brax's APG reports its epoch index to ``progress_fn``; this script converts it to env
steps (epochs x updates per epoch x ``num_envs`` x ``horizon_length``).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import functools
import importlib
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

ALGOS = ("sac", "es", "apg")


def parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"--set {item!r}: expected KEY=VALUE")
        try:
            out[key] = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            out[key] = raw
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--algo", choices=ALGOS, required=True)
    parser.add_argument("--env", required=True)
    parser.add_argument("--backend", default=None, help="Brax's default for the env when left out")
    parser.add_argument("--hidden", type=int, nargs="*", default=None, help="none given: a linear policy")
    parser.add_argument("--set", nargs="*", action="extend", default=[], metavar="KEY=VALUE")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--stop-at-return", type=float, default=None)
    args = parser.parse_args()

    train_mod = importlib.import_module(f"brax.training.agents.{args.algo}.train")
    nets_mod = importlib.import_module(f"brax.training.agents.{args.algo}.networks")
    config = {"episode_length": 1000, "normalize_observations": True, "seed": args.seed}
    config.update(parse_sets(args.set))
    if isinstance(config.get("fitness_shaping"), str):  # ES: an enum member by name, e.g. CENTERED_RANK
        config["fitness_shaping"] = getattr(train_mod.FitnessShaping, config["fitness_shaping"])
    network = {} if args.hidden is None else {"hidden_layer_sizes": tuple(args.hidden)}

    out = sys.stdout

    def emit(record: dict) -> None:
        out.write(json.dumps(record, default=str) + "\n")  # enums (ES fitness shaping) by name
        out.flush()

    emit({"event": "config", "peer": f"brax-{args.algo}", "env": args.env, "backend": args.backend,
          **config, **network, "brax_version": brax.__version__, "jax_version": jax.__version__,
          "jax_backend": jax.default_backend(), "device_put_replicated_shim": SHIMMED})  # fmt: skip

    with contextlib.redirect_stdout(sys.stderr):
        kw = {} if args.backend is None else {"backend": args.backend}
        env = envs.get_environment(args.env, **kw)

    t0 = time.perf_counter()

    steps_per_call = 1
    if args.algo == "apg":  # Brax's APG reports its epoch index, not env steps
        epochs = max(config.get("num_evals", 1) - 1, 1)
        updates = round(config["policy_updates"] / epochs)
        steps_per_call = updates * config.get("num_envs", 1) * config.get("horizon_length", 32)

    def progress_fn(num_steps: int, metrics: dict) -> None:
        num_steps = int(num_steps) * steps_per_call
        ret = float(metrics["eval/episode_reward"])
        emit({"event": "eval", "elapsed_s": time.perf_counter() - t0, "time_unix": time.time(),
              "env_steps": int(num_steps), "eval_return": ret,
              "eval_return_std": float(metrics.get("eval/episode_reward_std", float("nan")))})  # fmt: skip
        if args.stop_at_return is not None and ret >= args.stop_at_return:
            raise TargetReached

    factory = functools.partial(getattr(nets_mod, f"make_{args.algo}_networks"), **network)
    train_until_target(
        train_mod.train, emit, t0, environment=env, progress_fn=progress_fn, network_factory=factory, **config
    )


if __name__ == "__main__":
    main()
