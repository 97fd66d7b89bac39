"""Trained policies from run folders: ``fastrl.load_policy(RUN_DIR)``."""

from __future__ import annotations

import json
from pathlib import Path

import jax

from fastrl import agents
from fastrl.checkpoint import Checkpointer, CheckpointError
from fastrl.config import RunConfig
from fastrl.runner import CHECKPOINT_DIR


def load_run(run_dir: str | Path, step: int | None = None):
    """(RunConfig, env, learner, state) of a run's checkpoint (default: the latest)."""
    run_dir = Path(run_dir)
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"{run_dir} is not a fastrl run folder (no {CHECKPOINT_DIR}/ inside)")
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR)
    try:
        step, meta = ckpt.read_meta(step)
        config = meta["config"]
        rc = RunConfig.from_dict(config)
        env = rc.env.make()
        learner = agents.make_learner(rc.algo_name, rc.algo, env, rc.network, 1)
        abstract = jax.eval_shape(learner.init, jax.random.PRNGKey(rc.seed))
        state, _ = ckpt.restore(abstract, config, step)
    finally:
        ckpt.close()
    return rc, env, learner, state


def load_policy(run_dir: str | Path, step: int | None = None):
    """A jittable deterministic ``policy(obs) -> action`` from a run's latest checkpoint.

    The observation normaliser is folded in, so the function takes raw observations of the
    env's layout (see the env's docstring) and returns actions within its action bounds. It
    works for a single (obs_size,) observation or a batch (..., obs_size).
    """
    _, _, learner, state = load_run(run_dir, step)
    params = learner.policy_params(state)

    def policy(obs: jax.Array) -> jax.Array:
        return learner.act(params, obs)

    policy.run_config = json.loads((Path(run_dir) / "config.json").read_text())
    return policy
