"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training command line.

An entry point only: the code is ``fastrl.training.train``, and code imports it from there.
"""

from fastrl.training.train import main

if __name__ == "__main__":
    main()
