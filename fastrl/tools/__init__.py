"""The tools that look at runs: they read what training wrote and show what a policy or scene does.

- ``evaluate``: a run's policy scored, exported, drawn (``python -m fastrl.evaluate RUN_DIR``).
- ``reference``: the same policy scored in MuJoCo C / Gymnasium, side by side with fastrl.
- ``report``: summaries of run folders over seeds (``python -m fastrl.report DIR``).
- ``curve``: ``metrics.csv`` read back and a run's learning curve drawn.
- ``callbacks``: the training runner's callbacks (viewer pages, the physics note, curves) that
  the command line hands it.
- ``viewer``: self-contained HTML/WebGL pages and MuJoCo-rendered videos of rollouts.
- ``scene_info``: what a scene holds and how fastrl will step it
  (``python -m fastrl.tools.scene_info MODEL.xml``).

May import every layer below it (runtime, physics, envs, agents, training); only the command
lines (``fastrl.cli`` and the entry points) import it. Importing this package imports none of
its modules.
"""
