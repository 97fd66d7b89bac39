"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training command line.

An entry point only: the code is ``fastrl.cli.train``, and code imports it from there.
"""

from fastrl.cli.train import main

if __name__ == "__main__":
    main()
