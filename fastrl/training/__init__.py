"""The training layer: from a composed config to a trained, checkpointed, loadable policy.

- ``config``: the typed run configuration (``RunConfig``), built from Hydra's composed dict.
- ``scale``: agent batches in one program (seeds, ``vmap_sweep``) and the state's device layout.
- ``checkpoint``: the whole training state with orbax, plus the resolved config.
- ``runner``: the host loop over compiled chunks (``train``), calling the ``Callback`` objects
  its caller hands it; its pieces: ``run_setup`` (env, agents, learner, layout), ``start`` (the
  folder's lock, a fresh or restored state), ``chunk`` (the compiled chunk and its size),
  ``progress`` (where the run stands: evaluation, collapse, divergence, the decision to stop),
  ``outputs`` (rows, progress line, TensorBoard, metrics.csv) and ``signals`` (Ctrl-C and
  friends).
- ``files``: what a run writes into its folder, never through a link, whole or not at all.
- ``policy``: trained policies from run folders (``load_policy``, ``load_run``).

May import the runtime, physics, envs and agents; never the tools that look at runs
(``fastrl.tools``) or the command lines (``fastrl.cli``), which hand their pieces in.
"""

from fastrl.training.checkpoint import Checkpointer, CheckpointError
from fastrl.training.config import ConfigError, RunConfig
from fastrl.training.policy import load_policy, load_run
from fastrl.training.runner import Callback, RunInfo, train

__all__ = [
    "Callback",
    "CheckpointError",
    "Checkpointer",
    "ConfigError",
    "RunConfig",
    "RunInfo",
    "load_policy",
    "load_run",
    "train",
]
