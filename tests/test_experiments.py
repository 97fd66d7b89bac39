"""Each experiment script runs end to end in its tiny mode, so the evidence cannot rot."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_bench_physics_quick(tmp_path):
    subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "bench_physics.py"), "--quick", "--out", str(tmp_path)],
        check=True,
        cwd=ROOT,
        timeout=600,
    )
    result = json.loads((tmp_path / "physics_throughput_quick.json").read_text())
    engines = {r["engine"] for r in result["rows"]}
    assert "fastrl" in engines and "MuJoCo C rollout (2 thread)" in engines
    assert all(r["steps_per_s"] > 0 for r in result["rows"])
    assert (tmp_path / "physics_throughput_quick.md").read_text().startswith("# Physics throughput")


def test_bench_contacts_quick(tmp_path):
    subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "bench_contacts.py"), "--quick", "--out", str(tmp_path)],
        check=True,
        cwd=ROOT,
        timeout=900,
    )
    rows = json.loads((tmp_path / "contacts_throughput_quick.json").read_text())
    assert {r["engine"] for r in rows} == {"fastrl rk4 0.01x5", "fastrl euler 0.01x5"}
    assert all(r["control_steps_per_s"] > 0 and r["diverged_fraction"] == 0 for r in rows)
    assert (tmp_path / "contacts_throughput_quick.png").stat().st_size > 0
