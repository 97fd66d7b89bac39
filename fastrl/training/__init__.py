"""The training layer: from a composed config to a trained, checkpointed, loadable policy.

- ``config``: the typed run configuration (``RunConfig``), built from Hydra's composed dict.
- ``scale``: agent batches in one program (seeds, ``vmap_sweep``).
- ``checkpoint``: the whole training state with orbax, plus the resolved config.
- ``layout``: the one place that decides the device layout (CPU devices, the learner's own
  split, the state's sharding).
- ``runner``: the host loop over compiled chunks (``train``), calling the ``Callback`` objects
  its caller hands it (``hooks``: ``Callback``, ``RunInfo``, ``ChunkInfo``); ``evaluation``:
  the evaluation callback (the default); the runner's pieces: ``run_setup`` (env, agents,
  learner, layout), ``start`` (the folder's lock, a fresh or restored state), ``chunk`` (the
  compiled chunk and its size), ``progress`` (where the run stands: collapse watch,
  ``stop_at_return`` record, divergence, the decision to stop), ``outputs`` (rows, progress
  line, TensorBoard, metrics.csv) and ``signals`` (Ctrl-C and friends).
- ``files``: what a run writes into its folder, never through a link, whole or not at all.
- ``policy``: trained policies from run folders (``load_policy``, ``load_run``).

May import the runtime, physics, envs and agents; never the tools that look at runs
(``fastrl.tools``) or the command lines (``fastrl.cli``), which hand their pieces in.
"""

from fastrl.training.checkpoint import Checkpointer, CheckpointError
from fastrl.training.config import ConfigError, RunConfig
from fastrl.training.evaluation import Evaluation
from fastrl.training.hooks import Callback, ChunkInfo, RunInfo
from fastrl.training.policy import load_policy, load_run
from fastrl.training.runner import train

__all__ = [
    "Callback",
    "CheckpointError",
    "Checkpointer",
    "ChunkInfo",
    "ConfigError",
    "Evaluation",
    "RunConfig",
    "RunInfo",
    "load_policy",
    "load_run",
    "train",
]
