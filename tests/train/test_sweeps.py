"""Hydra multirun end to end, summarised by ``python -m fastrl.report``."""

import os
import subprocess
import sys

from fastrl.tools import report


def test_multirun_2_learning_rates_x_2_seeds_and_report(tmp_path):
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "fastrl.train", "-m", "env=inverted_pendulum", "debug=quick",
           "algo.learning_rate=1e-3,3e-4", "seed=0,1", f"hydra.sweep.dir={tmp_path}/sweep"]  # fmt: skip
    subprocess.run(cmd, check=True, env=env, timeout=900, capture_output=True)
    runs = report.find_runs(tmp_path / "sweep")
    assert len(runs) == 4
    for run in runs:  # each job's folder is complete: config, events, checkpoints, curve
        for name in ("config.json", "metrics.csv", "curve.png"):
            assert (run / name).exists(), run / name
        assert any((run / "checkpoints").iterdir()) and any((run / "tb").iterdir())
    assert report.run([str(tmp_path / "sweep")]) == 0
    table = (tmp_path / "sweep" / "report.md").read_text()
    assert "algo.learning_rate=0.001" in table and "algo.learning_rate=0.0003" in table
    assert table.count("| 0,1 |") == 2  # two configurations, each over seeds 0 and 1
    assert (tmp_path / "sweep" / "report.png").stat().st_size > 0
