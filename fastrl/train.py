"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training command line.

The code is ``fastrl.training.train``; this module keeps the documented command and import path.
"""

from fastrl.training.train import *  # noqa: F403
from fastrl.training.train import __all__, main  # noqa: F401

if __name__ == "__main__":
    main()
