"""fastrl's experiments: each module is one command, ``python -m experiments.<name>``, whose
outputs go to ``experiments/results/`` through :mod:`experiments.results`."""
