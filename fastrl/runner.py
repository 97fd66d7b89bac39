"""Moved to ``fastrl.training.runner`` (the training layer's package); this path stays importable."""

from fastrl.training.runner import *  # noqa: F403
from fastrl.training.runner import __all__  # noqa: F401
