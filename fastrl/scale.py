"""Moved to ``fastrl.training.scale`` (the training layer's package); this path stays importable."""

from fastrl.training.scale import *  # noqa: F403
from fastrl.training.scale import __all__  # noqa: F401
