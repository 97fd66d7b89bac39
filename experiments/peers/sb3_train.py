"""Stable-Baselines3 on Gymnasium's own v5 MuJoCo envs, on a wall-clock budget (run in .venv-peers).

    .venv-peers/bin/python experiments/peers/sb3_train.py train --env Hopper-v5 --algo sac \\
        --seconds 600 --snapshots 8 --out DIR [--t0 UNIX_TIME] [--seed 0] [--env-kwargs JSON]
    .venv-peers/bin/python experiments/peers/sb3_train.py score --env Hopper-v5 --algo sac \\
        --out DIR --episodes 10 [--env-kwargs JSON]

``train`` runs SB3's PPO or SAC with the RL Baselines3 Zoo's hyperparameters for the env
(``ZOO`` below; the Zoo's tuned MuJoCo entries, its MuJoCo defaults where it has none) until
``--seconds`` have passed since ``--t0`` (default: this process's start), and saves the model
``--snapshots`` times, evenly spaced over the budget (the last at its end). Each save prints one
JSON line: ``{"event": "snapshot", "index", "seconds" (since t0), "env_steps", "path"}``.

``score`` loads every snapshot in ``--out`` and runs ``--episodes`` episodes of its deterministic
policy (the mean action) in a fresh Gymnasium env, reset with seeds 1000, 1001, ...; observation
normalisation statistics saved with the snapshot are applied frozen. One JSON line per snapshot:
``{"event": "score", "index", "returns", "lengths"}``.

Everything else goes to stderr. PyTorch uses the machine's cores as it does by default.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

STARTED = time.time()

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import PPO, SAC  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402
from stable_baselines3.common.logger import Logger  # noqa: E402
from stable_baselines3.common.vec_env import VecNormalize  # noqa: E402

# The RL Baselines3 Zoo's hyperparameters (hyperparams/ppo.yml and sac.yml, MuJoCo section).
# PPO: the Zoo's tuned entries for HalfCheetah, Hopper, Walker2d (SB3's default network) and
# Humanoid; the Ant has only the Zoo's MuJoCo defaults (SB3's PPO defaults with normalisation).
# All PPO entries normalise observations and rewards (VecNormalize) with one env. SAC: SB3's
# defaults with 10,000 random steps first (the Zoo's MuJoCo entries).
_TUNED_PPO_NET = {"log_std_init": -2, "ortho_init": False, "activation_fn": "relu", "net_arch": [256, 256]}
ZOO = {
    "ppo": {
        "HalfCheetah": {"batch_size": 64, "n_steps": 512, "gamma": 0.98, "learning_rate": 2.0633e-05,
                        "ent_coef": 0.000401762, "clip_range": 0.1, "n_epochs": 20, "gae_lambda": 0.92,
                        "max_grad_norm": 0.8, "vf_coef": 0.58096, "policy_kwargs": _TUNED_PPO_NET},
        "Hopper": {"batch_size": 32, "n_steps": 512, "gamma": 0.999, "learning_rate": 9.80828e-05,
                   "ent_coef": 0.00229519, "clip_range": 0.2, "n_epochs": 5, "gae_lambda": 0.99,
                   "max_grad_norm": 0.7, "vf_coef": 0.835671, "policy_kwargs": _TUNED_PPO_NET},
        "Humanoid": {"batch_size": 256, "n_steps": 512, "gamma": 0.95, "learning_rate": 3.56987e-05,
                     "ent_coef": 0.00238306, "clip_range": 0.3, "n_epochs": 5, "gae_lambda": 0.9,
                     "max_grad_norm": 2, "vf_coef": 0.431892, "policy_kwargs": _TUNED_PPO_NET},
        "Walker2d": {"batch_size": 32, "n_steps": 512, "gamma": 0.99, "learning_rate": 5.05041e-05,
                     "ent_coef": 0.000585045, "clip_range": 0.1, "n_epochs": 20, "gae_lambda": 0.95,
                     "max_grad_norm": 1, "vf_coef": 0.871923},
        "Ant": {},
    },
    "sac": {name: {"learning_starts": 10_000}
            for name in ("HalfCheetah", "Hopper", "Walker2d", "Humanoid", "Ant")},
}  # fmt: skip


def hyperparameters(env_id: str, algo: str) -> dict:
    """The Zoo's keyword arguments for ``PPO``/``SAC`` on ``env_id`` (e.g. ``"Hopper-v5"``)."""
    name = env_id.split("-")[0]
    if name not in ZOO[algo]:
        raise SystemExit(f"sb3_train: no hyperparameters for {env_id}; known: {sorted(ZOO[algo])}")
    kwargs = json.loads(json.dumps(ZOO[algo][name]))  # a deep copy
    if "policy_kwargs" in kwargs:
        kwargs["policy_kwargs"]["activation_fn"] = {"relu": torch.nn.ReLU}[
            kwargs["policy_kwargs"]["activation_fn"]
        ]
        kwargs["policy_kwargs"]["net_arch"] = {"pi": kwargs["policy_kwargs"]["net_arch"],
                                               "vf": kwargs["policy_kwargs"]["net_arch"]}  # fmt: skip
    return kwargs


class _Budget(BaseCallback):
    """Saves snapshots at evenly spaced times and ends training when the budget is spent."""

    def __init__(self, t0: float, seconds: float, snapshots: int, out: pathlib.Path, vec):
        super().__init__()
        self.t0, self.seconds, self.out, self.vec = t0, seconds, out, vec
        self.times = [seconds * (i + 1) / snapshots for i in range(snapshots)]
        self.index = 0

    def _on_step(self) -> bool:
        elapsed = time.time() - self.t0
        if self.index < len(self.times) - 1 and elapsed >= self.times[self.index]:
            self._save(elapsed)
        return elapsed < self.seconds

    def _on_training_end(self) -> None:
        self._save(time.time() - self.t0)

    def _save(self, elapsed: float) -> None:
        path = self.out / f"snapshot_{self.index:02d}"
        self.model.save(path.with_suffix(".zip"))
        if self.vec is not None:
            self.vec.save(str(path.with_suffix(".vecnorm.pkl")))
        rec = {"event": "snapshot", "index": self.index, "seconds": elapsed,
               "env_steps": int(self.model.num_timesteps), "path": str(path)}  # fmt: skip
        print(json.dumps(rec), flush=True)
        self.index += 1


def train(args) -> None:
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env_kwargs = json.loads(args.env_kwargs)
    kwargs = hyperparameters(args.env, args.algo)
    vec = make_vec_env(args.env, n_envs=1, seed=args.seed, env_kwargs=env_kwargs)
    if args.algo == "ppo":
        vec = VecNormalize(vec, gamma=kwargs.get("gamma", 0.99))
        model = PPO("MlpPolicy", vec, seed=args.seed, verbose=0, device="cpu", **kwargs)
    else:
        model = SAC("MlpPolicy", vec, seed=args.seed, verbose=0, device="cpu", **kwargs)
    # SB3's default logger makes a folder under /tmp even with verbose=0; log nowhere instead
    model.set_logger(Logger(folder=None, output_formats=[]))
    t0 = args.t0 if args.t0 is not None else STARTED
    budget = _Budget(t0, args.seconds, args.snapshots, out, vec if args.algo == "ppo" else None)
    print(json.dumps({"event": "start", "seconds": time.time() - t0, "hyperparameters": ZOO[args.algo]
                      [args.env.split("-")[0]], "torch": torch.__version__,
                      "threads": torch.get_num_threads()}), flush=True)  # fmt: skip
    model.learn(total_timesteps=10**12, callback=budget)


def score(args) -> None:
    out = pathlib.Path(args.out)
    env_kwargs = json.loads(args.env_kwargs)
    cls = {"ppo": PPO, "sac": SAC}[args.algo]
    for path in sorted(out.glob("snapshot_*.zip")):
        model = cls.load(path, device="cpu")
        stats = path.with_suffix(".vecnorm.pkl")
        norm = None
        if stats.exists():
            norm = VecNormalize.load(str(stats), make_vec_env(args.env, n_envs=1, env_kwargs=env_kwargs))
            norm.training = False
        returns, lengths = [], []
        for episode in range(args.episodes):
            env = gym.make(args.env, **env_kwargs)
            obs, _ = env.reset(seed=1000 + episode)
            total, steps, done = 0.0, 0, False
            while not done:
                o = norm.normalize_obs(obs[None])[0] if norm is not None else obs
                action, _ = model.predict(o, deterministic=True)
                obs, reward, terminated, truncated, _ = env.step(action)
                total, steps, done = total + float(reward), steps + 1, terminated or truncated
            returns.append(total)
            lengths.append(steps)
        index = int(path.stem.split("_")[1])
        print(
            json.dumps({"event": "score", "index": index, "returns": returns, "lengths": lengths}), flush=True
        )
        print(f"sb3_train: {path.name}: {np.mean(returns):.1f} +- {np.std(returns):.1f}", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("mode", choices=["train", "score"])
    parser.add_argument("--env", required=True, help="a Gymnasium id, e.g. Hopper-v5")
    parser.add_argument("--algo", choices=["ppo", "sac"], required=True)
    parser.add_argument("--out", required=True, help="the snapshots' folder")
    parser.add_argument("--env-kwargs", default="{}", help="JSON keyword arguments for gymnasium.make")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seconds", type=float, default=600.0, help="train: wall-clock budget from --t0")
    parser.add_argument("--snapshots", type=int, default=8)
    parser.add_argument("--t0", type=float, default=None, help="train: the launch time (Unix seconds)")
    parser.add_argument("--episodes", type=int, default=10, help="score: episodes per snapshot")
    args = parser.parse_args()
    (train if args.mode == "train" else score)(args)


if __name__ == "__main__":
    main()
