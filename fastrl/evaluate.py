"""``python -m fastrl.evaluate RUN_DIR``: evaluate a run's latest policy.

An entry point only: the code is ``fastrl.tools.evaluate``, and code imports it from there.
"""

from fastrl.tools.evaluate import main

if __name__ == "__main__":
    main()
