"""Moved to ``fastrl.training.config`` (the training layer's package); this path stays importable."""

from fastrl.training.config import *  # noqa: F403
from fastrl.training.config import __all__  # noqa: F401
