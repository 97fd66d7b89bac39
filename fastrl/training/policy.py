"""Trained policies from run folders: ``fastrl.load_policy(RUN_DIR)``, and the learned weights
a new run starts from (``init_from=RUN_DIR``: fine-tuning a policy on a changed task, e.g. a
flat-ground walker on rough ground, as Brax's ``restore_checkpoint_path`` does)."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp

from fastrl import agents
from fastrl.training import scale
from fastrl.training.checkpoint import CHECKPOINT_DIR, Checkpointer, CheckpointError
from fastrl.training.config import RunConfig

__all__ = [
    "LEARNED_FIELDS",
    "load_policy",
    "load_run",
    "start_from",
]

# The fields of a learner's state that ``init_from`` carries into a new run: network weights (PPO's
# policy and value; SAC's actor, critics, target critics and temperature; ES's parameter vector)
# and the observation normaliser. The optimiser state, envs, replay buffer, RNG and counters start
# fresh.
LEARNED_FIELDS = ("params", "theta", "obs_stats")


def load_run(run_dir: str | Path, step: int | None = None, agent: int | str | None = None):
    """(RunConfig, env, learner, state) of a run's checkpoint at ``step`` (default: the newest
    that can be read; an unreadable newer one is reported on stderr and skipped). The env is
    the one its policy is scored on (``Env.for_evaluation``: without training aids).

    The state is placed on this process's devices, whatever device count the run trained on.

    A batch run (``train.num_seeds > 1`` or a ``train.vmap_sweep``) holds several agents in one
    checkpoint: pick one with ``agent`` (its index or tag, e.g. ``0`` or ``"000-seed0"``), or pass
    the agent's own folder ``RUN_DIR/agents/<tag>``. The returned config and state are that
    agent's, as if it had been trained alone.
    """
    run_dir = Path(run_dir)
    if not (run_dir / CHECKPOINT_DIR).is_dir() and run_dir.parent.name == "agents":
        run_dir, agent = run_dir.parent.parent, run_dir.name if agent is None else agent
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"{run_dir} is not a fastrl run folder (no {CHECKPOINT_DIR}/ inside)")
    ckpt = Checkpointer(run_dir / CHECKPOINT_DIR)
    try:
        return ckpt.restore_newest(lambda s: _restore_agent(ckpt, run_dir, s, agent), step)
    finally:
        ckpt.close()


def _restore_agent(ckpt: Checkpointer, run_dir: Path, step: int, agent: int | str | None):
    """``load_run`` for one saved step (the config is the one saved with it)."""
    step, meta = ckpt.read_meta(step)
    config = meta["config"]
    rc = RunConfig.from_dict(config)
    env = rc.env.make()  # as trained: its saved env states are of this env's episodes
    specs = scale.expand(rc)
    index = _agent_index(run_dir, specs, agent)
    learner, key = scale.run_learner(rc, specs, env, 1, None)
    state, _ = ckpt.restore(jax.eval_shape(learner.init, key), config, step)
    if len(specs) == 1:
        return rc, env.for_evaluation(), learner, state
    one = specs[index].config
    learner = agents.make_learner(one.algo_name, one.algo, env, one.network, 1)
    return one, env.for_evaluation(), learner, jax.tree.map(lambda x: x[index], state)


def _agent_index(run_dir: Path, specs: list[scale.AgentSpec], agent: int | str | None) -> int:
    """The index of the agent ``agent`` (index, tag or None) names among a run's ``specs``."""
    tags = [spec.tag for spec in specs]
    if len(specs) == 1:
        if agent not in (None, 0, tags[0]):
            raise CheckpointError(f"{run_dir} holds one agent; agent={agent!r} does not name it")
        return 0
    if agent is None:
        raise CheckpointError(
            f"{run_dir} holds a batch of {len(specs)} agents ({', '.join(tags)}); choose one: "
            f"load_policy(run_dir, agent=0), python -m fastrl.evaluate RUN_DIR --agent 0, or the "
            f"agent's folder {run_dir / 'agents' / tags[0]}"
        )
    index = tags.index(agent) if agent in tags else agent
    if not isinstance(index, int) or not 0 <= index < len(specs):
        raise CheckpointError(
            f"agent={agent!r} is not one of {run_dir}'s agents: 0..{len(specs) - 1} or {tags}"
        )
    return index


def load_policy(run_dir: str | Path, step: int | None = None, agent: int | str | None = None):
    """A jittable deterministic ``policy(obs) -> action`` from a run's latest checkpoint (of a
    batch run: one agent's, chosen as ``load_run`` describes).

    The observation normaliser is folded in, so the function takes raw observations of the
    env's layout (see the env's docstring) and returns actions within its action bounds. It
    works for a single (obs_size,) observation or a batch (..., obs_size).
    """
    rc, _, learner, state = load_run(run_dir, step, agent)
    params = learner.policy_params(state)

    def policy(obs: jax.Array) -> jax.Array:
        return learner.act(params, obs)

    policy.run_config = rc.to_dict()
    return policy


def start_from(like, source: str | Path, algo_name: str, n_agents: int = 1):
    """The learned fields (``LEARNED_FIELDS``) of ``source``'s newest readable checkpoint, shaped
    as they are in ``like`` (a new run's learner state, or its ``jax.eval_shape``): every agent of
    a batch run gets the same copy.

    ``source`` is a run folder (of a batch run: an agent's folder ``RUN_DIR/agents/<tag>``).
    Returns ``{field: tree}`` (for ``dataclasses.replace`` on the new state) and a line saying
    what was taken. Raises ``CheckpointError`` naming the problem when the source is another
    algorithm, or when its weights do not fit (other network sizes, or an env with another
    observation or action size)."""
    rc, _, _, saved = load_run(source)
    if rc.algo_name != algo_name:
        raise CheckpointError(
            f"init_from={source}: that run trained {rc.algo_name}, this one {algo_name}; a run starts "
            "only from weights of its own algorithm"
        )
    taken, wrong = {}, []
    for name in (f for f in LEARNED_FIELDS if hasattr(like, f)):
        ours, treedef = jax.tree_util.tree_flatten_with_path(getattr(like, name))
        theirs, their_def = jax.tree_util.tree_flatten(getattr(saved, name))
        if treedef != their_def:
            wrong.append(f"{name}: other structure")
            continue
        misfits = [
            f"{name}{jax.tree_util.keystr(path)}: saved {y.shape} -> now {want}"
            for (path, x), y in zip(ours, theirs, strict=True)
            if y.shape != (want := x.shape[1:] if n_agents > 1 else x.shape)
        ]
        wrong += misfits
        if not misfits:
            leaves = [
                jnp.broadcast_to(jnp.asarray(y, x.dtype), x.shape)
                for (_, x), y in zip(ours, theirs, strict=True)
            ]
            taken[name] = jax.tree_util.tree_unflatten(treedef, leaves)
    if wrong:
        raise CheckpointError(
            f"init_from={source}: its learned weights do not fit this run (same network.* "
            "settings and an env with the same observation and action sizes are needed):\n  "
            + "\n  ".join(wrong[:8])
            + ("\n  ..." if len(wrong) > 8 else "")
        )
    line = (
        f"started from {Path(source)}'s {', '.join(taken)} ({rc.env.name} / {rc.algo_name} at "
        f"{int(saved.env_steps):,d} env steps); optimiser, envs and counters fresh"
    )
    return taken, line
