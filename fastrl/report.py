"""``python -m fastrl.report DIR``: summaries of run folders.

An entry point only: the code is ``fastrl.tools.report``, and code imports it from there.
"""

from fastrl.tools.report import main

if __name__ == "__main__":
    main()
