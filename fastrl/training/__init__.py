"""The training layer: from a composed config to a trained, checkpointed, loadable policy.

- ``config``: the typed run configuration (``RunConfig``), built from Hydra's composed dict.
- ``scale``: agent batches in one program (seeds, ``vmap_sweep``) and the state's device layout.
- ``checkpoint``: the whole training state with orbax, plus the resolved config.
- ``runner``: the host loop over compiled chunks (``train``).
- ``files``: what a run writes into its folder, never through a link, whole or not at all.
- ``curve``: ``metrics.csv`` read back and the learning curve drawn.
- ``policy``: trained policies from run folders (``load_policy``, ``load_run``).
- ``train``: the command line (Hydra), run as ``python -m fastrl.train`` (``fastrl/train.py`` is
  its entry point only).
"""

from fastrl.training.checkpoint import Checkpointer, CheckpointError
from fastrl.training.config import ConfigError, RunConfig
from fastrl.training.policy import load_policy, load_run
from fastrl.training.runner import train

__all__ = [
    "CheckpointError",
    "Checkpointer",
    "ConfigError",
    "RunConfig",
    "load_policy",
    "load_run",
    "train",
]
