"""Moved to ``fastrl.training.checkpoint`` (the training layer's package); this path stays importable."""

from fastrl.training.checkpoint import *  # noqa: F403
from fastrl.training.checkpoint import __all__  # noqa: F401
