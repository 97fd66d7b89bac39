"""The command lines: what a user runs, wiring the layers below together.

- ``train``: the training command line (Hydra), run as ``python -m fastrl.train``
  (``fastrl/train.py`` is its entry point only): composes the config, resolves resumes, sets the
  CPU devices and XLA flags, and hands the runner the callbacks of ``fastrl.tools``.
- ``conf``: ``conf/`` and the defaults Hydra composes it over (the config dataclasses', the
  envs'), and the composition of a command line.
- ``resume``: which run folder a resume continues, and the config it continues with.

The top layer: may import every package of fastrl; none imports it. Importing this package
imports none of its modules.
"""
