"""Moved to ``fastrl.training.policy`` (the training layer's package); this path stays importable."""

from fastrl.training.policy import *  # noqa: F403
from fastrl.training.policy import __all__  # noqa: F401
