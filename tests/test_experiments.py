"""Each experiment script runs end to end in its tiny mode, so the evidence cannot rot.

The four whose tiny mode takes over half a minute on two cores (each compiles several learners
or a two-device split) are ``slow`` (``pytest -m slow tests/test_experiments.py``); what they
exercise underneath (the vector env, two devices, divergence detection, the solver settings) has
its own quick tests in ``tests/envs`` and ``tests/train``. So is the height-field contact check
(about 30 s), to keep CI within its time. The shared results module and the
scripts' shape (short functions, each runnable as ``python -m experiments.<name>``) are checked
first, in a second (no script runs)."""

from __future__ import annotations

import ast
import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from omegaconf import OmegaConf

from experiments import results

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / "experiments").glob("*.py") if p.stem not in ("__init__", "results"))
HELPERS = {"shipped"}  # imported by the scripts, not run
MAX_LINES = 60


def _module(name: str, *args: str) -> list[str]:
    """The command line of ``python -m experiments.<name> ARGS``."""
    return [sys.executable, "-m", f"experiments.{name}", *args]


def _run_quick(script: str, out: pathlib.Path, result: str):
    """Runs ``python -m experiments.<script> --quick`` into ``out`` and returns its JSON result."""
    subprocess.run(_module(script, "--quick", "--out", str(out)), check=True, cwd=ROOT, timeout=900)
    return json.loads((out / result).read_text())


def test_results_table_number_save_load_round_trip(tmp_path):
    assert results.number(1234567) == "1,234,567" and results.number(0.000123) == "1.23e-04"
    assert results.number(3.14159) == "3.14" and results.number(None) == results.number(float("nan")) == "–"
    table = results.table(["env", "steps/s", "note"], [["ant", 12345, "x"], ["hopper", 0.5, None]])
    assert table.splitlines() == [
        "| env | steps/s | note |",
        "| --- | ---: | --- |",
        "| ant | 12,345 | x |",
        "| hopper | 0.5 | – |",
    ]
    assert results.table(["a", "b"], [], align="lr").splitlines()[1] == "| --- | ---: |"
    with pytest.raises(ValueError):
        results.table(["a", "b"], [[1]])
    record = {"machine": results.machine(), "command": results.command(["x/exp.py", "--quick"]),
              "rows": [{"k": 1, "v": [0.5, None]}]}  # fmt: skip
    assert record["command"] == "python -m experiments.exp --quick"
    written = results.save(tmp_path / "out", "exp", record, table)
    assert [p.name for p in written] == ["exp.json", "exp.md"]
    saved = {**record, "date": results.today()}  # a dict record without a date gets today's
    assert results.load("exp", tmp_path / "out") == results.load(written[0]) == saved
    dated = {"meta": {"date": "2026-01-02"}}  # a record that names its date keeps it
    assert results.load(results.save(tmp_path / "out", "dated", dated)[0]) == dated
    assert (tmp_path / "out" / "exp.md").read_text() == table + "\n"
    assert results.save(tmp_path / "out", "page", None, "# page") == [tmp_path / "out" / "page.md"]


def _path_hacks(tree: ast.AST) -> list[int]:
    """Lines that reach other files through the import path: ``sys.path`` or importlib's
    ``spec_from_file_location``."""
    return [
        n.lineno
        for n in ast.walk(tree)
        if isinstance(n, ast.Attribute)
        and (n.attr == "spec_from_file_location" or (n.attr == "path" and ast.unparse(n.value) == "sys"))
    ]


def test_experiment_functions_are_short_and_every_script_runs_as_a_module():
    """No function in ``experiments/*.py`` is over ``MAX_LINES`` lines; every script has a
    ``__main__`` guard (``python -m experiments.<name>`` runs it, importing it runs nothing), and
    none reaches its siblings through ``sys.path``: they import ``experiments.<name>``."""
    long, unguarded, hacks = [], [], []
    for path in [*SCRIPTS, ROOT / "experiments" / "results.py"]:
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            lines = fn.end_lineno - fn.lineno + 1 if isinstance(fn, ast.FunctionDef) else 0
            if lines > MAX_LINES:
                long.append(f"{path.name}:{fn.lineno} {fn.name} ({lines} lines)")
        hacks += [f"{path.name}:{line}" for line in _path_hacks(tree)]
        guarded = any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)
        if path.stem not in HELPERS and path.stem != "results" and not guarded:
            unguarded.append(path.name)
    assert not long, f"functions over {MAX_LINES} lines:\n  " + "\n  ".join(long)
    assert not unguarded, f"scripts without an `if __name__ == '__main__':` guard: {unguarded}"
    assert not hacks, f"imports by path: {hacks}"


def test_bench_physics_quick(tmp_path):
    result = _run_quick("bench_physics", tmp_path, "physics_throughput_quick.json")
    engines = {r["engine"] for r in result["rows"]}
    assert "fastrl" in engines and "MuJoCo C rollout (2 thread)" in engines
    assert all(r["steps_per_s"] > 0 for r in result["rows"])
    assert (tmp_path / "physics_throughput_quick.md").read_text().startswith("# Physics throughput")


def test_bench_contacts_quick(tmp_path):
    rows = _run_quick("bench_contacts", tmp_path, "contacts_throughput_quick.json")["rows"]
    shipped = OmegaConf.load(ROOT / "conf" / "experiment" / "ant_ppo.yaml").env
    one = f"fastrl {shipped.integrator} 0.01x5, {shipped.solver_iterations} iters"
    assert [r["engine"] for r in rows] == [one, f"{one}, 2 devices"]  # the batch split over 2 CPU devices
    assert all(r["control_steps_per_s"] > 0 and r["diverged_fraction"] == 0 for r in rows)
    assert (tmp_path / "contacts_throughput_quick.png").stat().st_size > 0


@pytest.mark.slow
def test_stability_sweep_quick(tmp_path):
    rows = _run_quick("stability_sweep", tmp_path, "stability_sweep_quick.json")
    assert {r["integrator"] for r in rows} == {"euler", "rk4"}
    assert all(0.0 <= r["guard_fraction"] <= r["blowup_fraction"] <= 1.0 for r in rows)


@pytest.mark.slow
def test_bench_envs_quick(tmp_path):
    result = _run_quick("bench_envs", tmp_path, "env_throughput_quick.json")
    assert all(r["control_steps_per_s"] > 0 and r["diverged"] == 0 for r in result["envs"])
    split = [r["split_2_devices"] for r in result["envs"]]
    assert all(r["engine"] == "fastrl, 2 devices" and r["control_steps_per_s"] > 0 for r in split)
    assert all(v["ratio"] > 0 and v["ratio_2_devices"] > 0 for v in result["vector"])
    assert all(
        v["ratio_training_settings"] > 0 and v["ratio_training_settings_2_devices"] > 0
        for v in result["vector"]
    )


def test_speed_accuracy_quick(tmp_path):
    result = _run_quick("speed_accuracy", tmp_path, "speed_accuracy_quick.json")
    (res,) = result["models"].values()
    rows = res["rows"]
    res_rows_before = [dict(r) for r in rows]
    assert {r["engine"] for r in rows} == {"fastrl", "MuJoCo C"}
    assert all(r["control_steps_per_s"] > 0 and r["error"] is not None for r in rows)
    assert sum(r["shipped"] for r in rows) == 1 and any(r["pareto"] for r in rows)
    # The converged-vs-converged floor sits far below every setting, finer timesteps are more
    # accurate, and fastrl (float32) and MuJoCo C err alike at the same timestep and integrator.
    assert all(res["floor"] < 1e-3 * r["error"] for r in rows)
    err = {(r["engine"], r["substeps"]): r["error"] for r in rows}
    assert err["fastrl", 5] < 1e-2 * err["fastrl", 1]
    assert all(0.5 < err["fastrl", n] / err["MuJoCo C", n] < 2 for n in (1, 5))
    assert (tmp_path / "speed_accuracy_quick.png").stat().st_size > 0
    assert (tmp_path / "speed_accuracy_quick.md").read_text().startswith("# Speed vs accuracy")
    # --from-json marks the shipped setting anew from the configs (here: after it was unmarked).
    saved = tmp_path / "speed_accuracy_quick.json"
    for r in rows:
        r["shipped"] = False
    saved.write_text(json.dumps(result))
    cmd = _module("speed_accuracy", "--quick", "--from-json", "--out", str(tmp_path))
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=300)
    (again,) = json.loads(saved.read_text())["models"].values()
    assert [r["shipped"] for r in again["rows"]] == [r["shipped"] for r in res_rows_before]
    assert "marked anew" in (tmp_path / "speed_accuracy_quick.md").read_text()


def test_conservation_quick(tmp_path):
    result = _run_quick("conservation", tmp_path, "conservation_quick.json")
    dts = result["protocol"]["timesteps"]
    assert len(dts) == 2
    # The shared float64 measurement agrees with fastrl's own momentum and energy at the kick.
    assert result["validation"]["max_relative_difference"] < 1e-12
    rows = {(r["label"], r["timestep"]): r for r in result["rows"]}
    keys = ("momentum_drift", "energy_drift")
    assert all(r[k] is not None and 0 < r[k] < 1 for r in rows.values() for k in keys)
    assert all(r["joint_travel"] > 0.2 for r in rows.values())  # the torques really moved the legs
    fine, coarse = sorted(dts)
    for engine in ("fastrl", "MuJoCo C"):
        tag = " float64" if engine == "fastrl" else ""
        euler = {dt: rows[f"{engine} euler{tag}", dt] for dt in dts}
        rk4 = {dt: rows[f"{engine} rk4{tag}", dt] for dt in dts}
        for k in keys:
            # RK4 conserves far better than Euler at the same timestep, and the drifts fall with the
            # timestep at each integrator's order: about 2x (Euler, first) and 16x (RK4, fourth).
            assert all(rk4[dt][k] < euler[dt][k] / 100 for dt in dts), (engine, k)
            assert 1.5 < euler[coarse][k] / euler[fine][k] < 3, (engine, k)
            assert rk4[coarse][k] / rk4[fine][k] > 8, (engine, k)
    # fastrl in float64 drifts as MuJoCo C does, integrator by integrator and timestep by timestep.
    for integrator in ("euler", "rk4"):
        for dt in dts:
            ours, theirs = rows[f"fastrl {integrator} float64", dt], rows[f"MuJoCo C {integrator}", dt]
            assert all(0.99 < ours[k] / theirs[k] < 1.01 for k in keys), (integrator, dt)
    # float32 rounding floors RK4's drift: at the finer timestep it stays above float64's.
    assert (
        rows["fastrl rk4 float32", fine]["momentum_drift"]
        > 2 * rows["fastrl rk4 float64", fine]["momentum_drift"]
    )
    assert (tmp_path / "conservation_quick.png").stat().st_size > 0
    assert (tmp_path / "conservation_quick.md").read_text().startswith("# Conservation")


def test_stability_map_quick(tmp_path):
    result = _run_quick("stability_map", tmp_path, "stability_map_quick.json")
    (res,) = result["envs"].values()
    rows = res["rows"]
    assert len(rows) == 4 and sum(r["shipped"] for r in rows) == 1
    assert all(0.0 <= r["guard"] <= r["diverged"] <= 1.0 for r in rows)
    # Stable at the asset's timestep; with a timestep of four control steps every episode blows up
    # and the guard flags it.
    assert all(r["diverged"] == 0 for r in rows if not r["beyond_dt"])
    assert all(r["guard"] == 1 for r in rows if r["beyond_dt"])
    (limit,) = res["limits"].values()
    assert limit["guard"] == limit["diverged"] == max(r["timestep"] for r in rows)
    assert (tmp_path / "stability_map_quick.png").stat().st_size > 0
    text = (tmp_path / "stability_map_quick.md").read_text()
    assert text.startswith("# Stability map")
    assert [r["envs"] for r in result["runs"]] == [list(result["envs"])]
    # Re-rendering the saved map reproduces its markdown, its shipped cells marked anew from the
    # configs (here: after they were unmarked).
    saved = tmp_path / "stability_map_quick.json"
    for r in rows:
        r["shipped"] = False
    res["limits"] = {}
    saved.write_text(json.dumps(result))
    again = tmp_path / "again"
    again.mkdir()
    cmd = _module(
        "stability_map", "--from-json", str(tmp_path / "stability_map_quick.json"), "--out", str(again)
    )
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=300)
    assert (again / "stability_map_quick.md").read_text() == text


@pytest.mark.slow
def test_learner_stability_quick(tmp_path):
    result = _run_quick("learner_stability", tmp_path, "learner_stability_quick.json")
    assert [c["algo"] for c in result["cells"]] == ["ppo", "sac"]
    for cell in result["cells"]:
        by_lr = {a["learning_rate"]: a for a in cell["agents"]}
        # The absurd rate is caught by the runner as diverged; the sane one in the same program is not.
        assert by_lr[1e4]["diverged"] and by_lr[1e4]["outcome"] == "diverged"
        assert not by_lr[1e-3]["diverged"] and by_lr[1e-3]["outcome"] in ("learned", "stalled", "collapsed")
        assert by_lr[1e-3]["final_return"] > 0
    md = (tmp_path / "learner_stability_quick.md").read_text()
    assert md.startswith("# Learner stability") and "| 256 | *" in md
    assert (tmp_path / "learner_stability_quick.png").stat().st_size > 0


def test_sb3_compare_quick(tmp_path):
    """fastrl PPO, SB3 PPO and SB3 SAC (in .venv-peers, which the test line sets up) each train on
    a wall-clock budget, and every snapshot is scored in Gymnasium's Hopper-v5."""
    result = _run_quick("sb3_compare", tmp_path, "sb3_compare_quick.json")
    runs = result["runs"]["hopper"]
    assert list(runs) == ["fastrl_ppo", "sb3_ppo", "sb3_sac"]
    for learner, snaps in runs.items():
        assert snaps and all(len(s["returns"]) == 2 and s["env_steps"] > 0 for s in snaps), learner
        assert [s["seconds"] for s in snaps] == sorted(s["seconds"] for s in snaps)
        assert snaps[-1]["seconds"] >= result["seconds"] or learner == "fastrl_ppo"  # ends at the budget
        assert snaps[-1]["seconds"] < result["seconds"] + 60, learner
    assert [len(runs[k]) for k in ("sb3_ppo", "sb3_sac")] == [2, 2]
    last = {k: np.mean(snaps[-1]["returns"]) for k, snaps in runs.items()}
    target = min(last["fastrl_ppo"], max(last["sb3_ppo"], last["sb3_sac"]))
    assert result["summary"]["hopper"]["target"] == pytest.approx(target)
    md = (tmp_path / "sb3_compare_quick.md").read_text()
    assert md.startswith("# fastrl vs Stable-Baselines3") and "| hopper | SB3 SAC |" in md


def test_sb3_compare_time_to_the_same_return():
    from experiments.sb3_compare import summarize, time_ratio

    snap = lambda t, r: {"seconds": t, "env_steps": 10 * t, "returns": [r - 1, r + 1]}  # noqa: E731
    runs = {"fastrl_ppo": [snap(30, 50), snap(60, 900), snap(90, 800)],
            "sb3_ppo": [snap(45, 300), snap(90, 700)],
            "sb3_sac": [snap(30, 750), snap(45, 100), snap(90, 400)]}  # fmt: skip
    out = summarize(runs)
    assert out["target"] == 700  # the lower of fastrl's last (800) and SB3's better last (700)
    fastrl, ppo, sac = (out["learners"][k] for k in runs)
    assert fastrl["seconds_to_target"] == 60 and ppo["seconds_to_target"] == 90
    assert sac["seconds_to_target"] is None  # 750 at 30 s, then back below: not reached
    assert fastrl["last_return"] == 800 and fastrl["best_return"] == 900 and fastrl["last_std"] == 1
    assert time_ratio(out) == pytest.approx(60 / 90)
    runs["fastrl_ppo"][-1] = snap(90, 500)  # fastrl ends lower: the target is its last return
    out = summarize(runs)
    assert out["target"] == 500 and out["learners"]["fastrl_ppo"]["seconds_to_target"] == 60
    assert out["learners"]["sb3_ppo"]["seconds_to_target"] == 90


def test_sb3_compare_merge_replaces_only_the_envs_measured_again(tmp_path):
    from experiments.sb3_compare import merged

    record = {"machine": "m", "command": "first", "fastrl": "aaa", "sb3_versions": "v", "seconds": 300.0,
              "episodes": 10, "seeds": 0, "runs": {"hopper": {"old": 1}, "humanoid": {"old": 2}}}  # fmt: skip
    path = tmp_path / "sb3_compare.json"
    path.write_text(json.dumps(record))
    new = {**record, "command": "second", "fastrl": "bbb", "runs": {"humanoid": {"new": 3}}}
    out = merged(path, new)
    assert out["runs"] == {"hopper": {"old": 1}, "humanoid": {"new": 3}}
    assert out["command"] == "first" and "humanoid: measured again" in out["note"] and "bbb" in out["note"]
    with pytest.raises(SystemExit, match="seconds"):
        merged(path, {**new, "seconds": 60.0})
    assert merged(tmp_path / "missing.json", new) is new


def test_sb3_budgets_medians_best_learners_and_time_to_the_target():
    from experiments.sb3_budgets import summarize

    snap = lambda t, r: {"seconds": t, "env_steps": 10 * t, "returns": [r - 1, r + 1]}  # noqa: E731
    runs = {
        "fastrl_sac": {"0": [snap(50, 100), snap(110, 900), snap(170, 950)],
                       "1": [snap(55, 200), snap(115, 400), snap(175, 990)],
                       "2": [snap(60, 900), snap(120, 100), snap(180, 960)]},
        "fastrl_ppo": {"0": [snap(60, 300), snap(120, 300), snap(170, 300)]},
        "sb3_ppo": {"0": [snap(60, 500), snap(120, 800), snap(180, 940)],
                    "1": [snap(60, 400), snap(120, 700), snap(180, 920)]},
    }  # fmt: skip
    out = summarize(runs, [100.0, 180.0])
    early, late = out["budgets"]["100"], out["budgets"]["180"]
    # At 100 s: the last snapshot by then (fastrl_sac: 100, 200, 900 -> median 200).
    assert early["medians"] == {"fastrl_sac": 200, "fastrl_ppo": 300, "sb3_ppo": 450}
    assert tuple(early["fastrl_best"]) == ("fastrl_ppo", 300)
    assert tuple(early["sb3_best"]) == ("sb3_ppo", 450)
    assert late["medians"]["fastrl_sac"] == 960 and tuple(late["sb3_best"]) == ("sb3_ppo", 930)
    # Target 930: seeds reach it to stay at 170, 175 and 180 s (seed 2's early 900 falls back).
    assert out["target"] == 930 and out["times"]["fastrl_sac"] == 175
    assert out["times"]["fastrl_ppo"] is None and out["speedup"] == pytest.approx(180 / 175)


def test_sb3_budgets_quick_keeps_its_cells(tmp_path):
    """FastTD3 and SB3 PPO each train on a wall-clock budget, every snapshot scored in Gymnasium's
    Hopper-v5; a second command skips the cells the record already holds."""
    from experiments.sb3_budgets import SLACK

    result = _run_quick("sb3_budgets", tmp_path, "sb3_budgets_quick.json")
    runs = result["runs"]["hopper"]
    assert list(runs) == ["fastrl_fasttd3", "sb3_ppo"]
    assert all(list(seeds) == ["0"] for seeds in runs.values())
    for learner, seeds in runs.items():
        snaps = seeds["0"]
        assert snaps and all(len(s["returns"]) == 2 and s["env_steps"] > 0 for s in snaps), learner
        assert [s["seconds"] for s in snaps] == sorted(s["seconds"] for s in snaps)
        assert any(s["seconds"] <= 40 + SLACK for s in snaps), learner  # a snapshot within the budget
    summary = result["summary"]["hopper"]
    assert summary["budgets"]["40"]["medians"]["sb3_ppo"] == pytest.approx(
        np.mean([s for s in runs["sb3_ppo"]["0"] if s["seconds"] <= 40 + SLACK][-1]["returns"])
    )
    assert len(result["log"]) == 2
    md = (tmp_path / "sb3_budgets_quick.md").read_text()
    assert "| hopper | fastrl FastTD3 | 1 |" in md
    before = (tmp_path / "sb3_budgets_quick.json").read_text()
    subprocess.run(
        _module("sb3_budgets", "--quick", "--out", str(tmp_path)), check=True, cwd=ROOT, timeout=300
    )
    assert json.loads((tmp_path / "sb3_budgets_quick.json").read_text())["runs"] == json.loads(before)["runs"]


def test_time_to_return_quick(tmp_path):
    stem = "time_to_return_inverted_pendulum"
    result = _run_quick("time_to_return", tmp_path, f"{stem}_quick.json")
    (run,) = result["runs"]
    assert run["learner"] == "fastrl" and run["curve"], run
    seconds, steps, _ = run["curve"][-1]
    assert seconds > 0 and steps == 1024
    assert result["summary"]["fastrl"]["runs"] == 1
    # the saved run re-renders with --from-json
    again = tmp_path / "again"
    saved = tmp_path / f"{stem}_quick.json"
    subprocess.run(
        _module("time_to_return", "--from-json", str(saved), "--out", str(again)), check=True, cwd=ROOT
    )
    md = (again / "time_to_return_inverted_pendulum.md").read_text()
    assert md.startswith("# Time to eval return 950: inverted_pendulum") and "| fastrl | 1 |" in md
    assert (again / "time_to_return_inverted_pendulum.png").stat().st_size > 0


def test_time_to_return_reuses_saved_brax_runs_and_says_so(tmp_path):
    from experiments import time_to_return as ttr

    brax = [{"learner": "brax", "seed": s, "curve": [[10.0 + s, 1000, 900.0]]} for s in (0, 1)]
    saved = tmp_path / "saved.json"
    runs = brax + [{"learner": "fastrl", "seed": 0}]
    saved.write_text(json.dumps({"task": "ant", "command": "python x", "note": "old caveat", "runs": runs}))
    runs, note = ttr.reused_brax_runs(saved, "ant", [1])
    assert runs == [brax[1]] and "not measured again" in note and "old caveat" in note
    with pytest.raises(SystemExit, match="no Brax run for seeds \\[2\\]"):
        ttr.reused_brax_runs(saved, "ant", [1, 2])
    with pytest.raises(SystemExit, match="holds task 'ant'"):
        ttr.reused_brax_runs(saved, "inverted_pendulum", [0])


@pytest.mark.slow
def test_solver_iterations_quick(tmp_path):
    rows = _run_quick("solver_iterations", tmp_path, "solver_iterations_quick.json")
    assert [r["name"] for r in rows] == ["inverted_pendulum", "hopper"]
    for r in rows:
        converged = [r["mujoco_converged"][str(k)] for k in range(1, 9)]
        assert converged == sorted(converged)  # a CDF of iteration counts
        assert 1 <= r["rule"] <= 8 and r["shipped"] >= 1
        assert r["fastrl_off_1e-4"]  # fastrl was checked at some count


def test_float32_floor_quick(tmp_path):
    result = _run_quick("float32_floor", tmp_path, "float32_floor_quick.json")
    (row,) = result["scenes"].values()
    assert row["steps"] == 12 and 0 <= row["once_mm"] < 1 and row["per_step_mm"] >= 0  # 0.05 s of 4 ms steps
    assert 0 <= row["mixed_mm"] < 1
    assert (tmp_path / "float32_floor_quick.md").read_text().startswith("# The float32 floor")


def test_float32_floor_mixed_step_is_mj_step_on_a_float32_state():
    """Where the state is already float32, the mixed-precision step rounds nothing, so it must be
    MuJoCo C's own step to the bit (Euler and implicitfast)."""
    import mujoco

    from experiments import float32_floor

    xml = """<mujoco><option integrator="{}"/><worldbody><geom type="plane" size="1 1 .1"/>
      <body pos="0 0 .5"><freejoint/><geom type="box" size=".1 .2 .05"/>
      <body pos=".2 0 0"><joint type="hinge" damping=".3"/><geom type="capsule" size=".03 .1"/></body>
      </body></worldbody></mujoco>"""
    for integrator in ("Euler", "implicitfast"):
        mj = mujoco.MjModel.from_xml_string(xml.format(integrator))
        a, b = mujoco.MjData(mj), mujoco.MjData(mj)
        for d in (a, b):
            d.qvel[:] = np.float32([0.5, -0.25, 1.0, 2.0, -1.5, 0.75, 3.0])
        mujoco.mj_step(mj, a)
        float32_floor._mixed_step(mj, b)
        np.testing.assert_array_equal(a.qpos, b.qpos)
        np.testing.assert_array_equal(a.qvel, b.qvel)


@pytest.mark.slow  # ~30 s of compile and MuJoCo C's converged collisions; CI is near its 30 minutes
def test_hfield_contacts_quick(tmp_path):
    """Where G1's rough-terrain contacts first part from MuJoCo C's, fastrl's depths are the
    ones MuJoCo C's own convex collision finds for the same prisms given as meshes."""
    result = _run_quick("hfield_contacts", tmp_path, "hfield_contacts_quick.json")
    (row,) = result["rows"].values()
    assert row["step"] is not None and row["geoms"]
    for g in row["geoms"]:
        assert len(g["fastrl"]) == len(g["as_meshes"]) > 0
        pairs = zip(sorted(g["fastrl"]), sorted(g["as_meshes"]), strict=True)
        assert max(abs(a - b) for a, b in pairs) < 1e-5
    assert (tmp_path / "hfield_contacts_quick.md").read_text().startswith("# Height-field contacts")


@pytest.mark.slow  # compiles the Go1 scene for training and for the measurement (~2 min)
def test_joystick_commands_quick(tmp_path):
    """A tiny go1_joystick run, then its policy under held commands in fastrl and MuJoCo C: the
    measurement runs end to end, and the two simulators agree on what the policy does."""
    run_dir = tmp_path / "run"
    train = [sys.executable, "-m", "fastrl.train", "env=go1_joystick", "algo=ppo", "debug=quick",
             "logger=quiet", f"hydra.run.dir={run_dir}"]  # fmt: skip
    subprocess.run(train, check=True, cwd=ROOT, timeout=900)
    cmd = _module("joystick_commands", str(run_dir), "--quick", "--out", str(tmp_path))
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=900)
    rows = json.loads((tmp_path / "commands_go1_joystick_quick.json").read_text())["rows"]
    assert [r["command"] for r in rows] == [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    assert [round(r["standing_still"], 2) for r in rows] == [1.5, 0.52]
    for r in rows:
        ours, theirs = r["fastrl"], r["mujoco"]
        assert 0 <= ours["score"] <= 1.5 and 0 <= theirs["score"] <= 1.5
        assert abs(ours["score"] - theirs["score"]) < 0.2  # same policy, same starts, 1.5 s


@pytest.mark.slow  # compiles the Panda scene for training and for both simulators (~3 min)
def test_sim_to_sim_quick(tmp_path):
    """A tiny panda_pick_cube run, then its policy for 10 control steps from the same starts in
    fastrl and in MuJoCo C: the measurement runs end to end and the two agree on the return."""
    run_dir = tmp_path / "run"
    train = [sys.executable, "-m", "fastrl.train", "env=panda_pick_cube", "algo=ppo", "debug=quick",
             "logger=quiet", f"hydra.run.dir={run_dir}"]  # fmt: skip
    subprocess.run(train, check=True, cwd=ROOT, timeout=900)
    cmd = _module("sim_to_sim", str(run_dir), "--episodes", "2", "--steps", "10", "--out", str(tmp_path))
    subprocess.run(cmd, check=True, cwd=ROOT, timeout=900)
    row = json.loads((tmp_path / "sim_to_sim_panda_pick_cube.json").read_text())
    assert row["episodes"] == 2 and row["steps"] == 10 and set(row["fastrl"]) == set(row["mujoco"])
    assert row["fastrl"]["return"] > 0 and row["kept"]["return"] == pytest.approx(1.0, abs=0.1)
    assert "| MuJoCo C / fastrl |" in (tmp_path / "sim_to_sim_panda_pick_cube.md").read_text()


def test_first_minute_quick(tmp_path):
    result = _run_quick("first_minute", tmp_path, "first_minute_quick.json")
    cold, cached = result["results"]["inverted_pendulum"].values()
    assert cold["cache"] == "miss" and cached["cache"] == "hit"
    assert cold["tracing_s"] > 0 and cached["tracing_s"] == 0  # the traced program read back
    assert 0 < cold["first_line_s"] < cold["wall_s"] and cached["train_steps_per_s"] > 0


def test_compile_time_quick(tmp_path):
    """The compile-time experiment on its generated tree: every stage and the whole step timed."""
    (row,) = _run_quick("compile_time", tmp_path, "compile_time_quick.json")["rows"]
    assert row["step"]["compile_s"] > 0 and row["step"]["hlo"] > 0 and row["stages"]


def test_attack_run_quick(tmp_path):
    """The link and replayed-command-line attacks each end in a named error, their victims intact."""
    rows = _run_quick("attack_run", tmp_path, "attack_run_quick.json")["results"]
    assert len(rows) == 9 and all(r["ok"] for r in rows.values()), rows
    assert all(r["rc"] == 2 and r["nothing_lost"] for r in rows.values())


def test_robot_training_reads_runs_and_interpolates_playgrounds_curve(tmp_path):
    """``experiments.robot_training`` on a run folder as ``fastrl.train`` writes it: every
    evaluation with its steps, wall time and eval metrics, Playground's return interpolated at
    those steps (none past its last point or for a task without one)."""
    from experiments import robot_training

    assert robot_training.playground_at("humanoid_joystick", 5.4e6) == pytest.approx(2.35)
    assert robot_training.playground_at("humanoid_joystick", 200e6) is None
    assert robot_training.playground_at("panda_pick_cube", 1e6) is None
    run = tmp_path / "run"
    run.mkdir()
    config = {"env": {"name": "humanoid_joystick"}, "seed": 0, "algo": {"num_envs": 1024}}
    (run / "config.json").write_text(json.dumps(config))
    header = "env_steps,wall_s,train/episode_return,perf/env_steps_per_s,perf/compile_s,"
    header += "eval/episode_return,eval/episode_return_std,eval/episode_length,eval/success\n"
    rows = ["20480,30.0,0.1,600.0,50.0,,,,", "10800000,900.0,4.0,1000.0,,5.0,1.0,300.0,0.25"]
    (run / "metrics.csv").write_text(header + "\n".join(rows) + "\n")
    out = robot_training.read_run(run)
    assert out["compile_s"] == 50.0 and out["env_steps"] == 10_800_000 and out["train_return"] == 4.0
    [e] = out["evals"]
    assert (e["env_steps"], e["eval_return"], e["success"]) == (10_800_000, 5.0, 0.25)
    assert e["playground_return"] == pytest.approx(4.7)
    page = robot_training.markdown([out])
    assert "| humanoid_joystick | 10,800,000 | 900 | 5.0 | 300 | success 0.25 | 4.7 |" in page
    # A run fine-tuned from another (init_from) names what it started from.
    tuned = tmp_path / "tuned"
    tuned.mkdir()
    (tuned / "config.json").write_text(json.dumps({**config, "init_from": str(run)}))
    (tuned / "metrics.csv").write_text(header + "\n".join(rows) + "\n")
    page = robot_training.markdown([robot_training.read_run(tuned)])
    assert "| humanoid_joystick (from humanoid_joystick at 11M steps) | 10,800,000 | 900 |" in page


def test_robot_scene_lean_measures_fewer_iterations_with_and_without_the_caps():
    """The Leap's variants: its own settings, 1 and half its 5 Newton iterations, half its
    slots, the scene's slots, and without MJX's caps at the loader's and the env's slots and at
    half the iterations (against MuJoCo C's own contacts); a one-iteration scene gets none."""
    from experiments import robot_scene_lean
    from fastrl import envs

    leap = dict(robot_scene_lean.variants(envs.make("leap_cube_reorient")))
    assert leap["3 Newton iterations"] == {"solver_iterations": 3}
    assert leap["1 Newton iteration"] == {"solver_iterations": 1} and leap["as the env steps it"] == {}
    assert leap["without MJX's caps, the env's contact slots, 3 Newton iterations"] == {
        "mjx_caps": False, "nconmax": 32, "solver_iterations": 3,
    }  # fmt: skip
    go1 = [label for label, _ in robot_scene_lean.variants(envs.make("go1_joystick"))]
    assert not any("iteration" in label for label in go1)


def test_stage_profile_times_every_stage_and_counts_what_touches(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "experiments.stage_profile", "--only", "go1_joystick", "--batch", "8",
         "--warmup", "20", "--repeats", "1", "--out", str(tmp_path)],
        check=True, cwd=ROOT, timeout=900,
    )  # fmt: skip
    (row,) = results.load("stage_profile", tmp_path)["rows"]
    times, touch = row["times"], row["touching"]
    assert {"kinematics", "solver", "integrate", "step", "task"} <= set(times)
    assert all(t > 0 for k, t in times.items() if k != "task"), times
    narrow = [k for k in times if k.startswith("narrow: ")]
    assert narrow == ["narrow: " + name for name in touch["groups"]]  # the four feet on the floor
    (group,) = touch["groups"].values()
    assert group["pairs"] == 4 and 0 <= group["contacts"] <= 4 and touch["candidates"] == 4
    assert "| solver |" in (tmp_path / "stage_profile.md").read_text()


def test_solver_trace_times_the_solve_operation_by_operation():
    out = subprocess.run(
        [sys.executable, "-m", "experiments.solver_trace", "humanoid_joystick", "--batch", "8",
         "--warmup", "4", "--calls", "2", "--top", "5"],
        check=True, cwd=ROOT, timeout=900, capture_output=True, text=True,
    ).stdout  # fmt: skip
    groups = out.split("runs per call | us/env | operations\n")[1].split("the 5 costliest")[0]
    runs = {int(line.split("|")[0]): float(line.split("|")[1]) for line in groups.splitlines()}
    assert 1 in runs and all(us >= 0 for us in runs.values()) and sum(runs.values()) > 0, out
    assert max(runs) > 1, out  # the Newton steps and line-search passes run more than once per solve


def test_device_split_times_the_step_on_each_device_count(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "experiments.device_split", "hopper", "--batch", "8", "--devices", "1", "2",
         "--out", str(tmp_path)],
        check=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    rows = results.load("device_split", tmp_path)["rows"]
    assert [(r["env"], r["devices"], r["batch"]) for r in rows] == [("hopper", 1, 8), ("hopper", 2, 8)]
    assert all(r["control_steps_per_s"] > 0 and r["compile_s"] > 0 for r in rows)
    assert "| hopper | 8 | 2 |" in (tmp_path / "device_split.md").read_text()


def test_dense_factor_times_each_design_and_they_agree(tmp_path):
    subprocess.run(_module("dense_factor", "--sizes", "14", "--batch", "128", "--out", str(tmp_path)),
                   check=True, cwd=ROOT, timeout=600)  # fmt: skip
    (row,) = results.load("dense_factor", tmp_path)["rows"]
    designs = ("lapack", "columns", "minor", "chunked")
    assert all(row[d] > 0 for d in designs) and all(row[f"{d}_err"] < 1e-4 for d in designs), row
    assert "| 14 | 128 |" in (tmp_path / "dense_factor.md").read_text()


def test_contact_counts_quick_counts_a_standing_quadruped(tmp_path):
    """Go1 standing on its four feet (four candidate contacts, one per foot): MuJoCo C's most
    contacts at once is between one and four, and fastrl's slots hold them."""
    (row,) = _run_quick("contact_counts", tmp_path, "contact_counts.json")["rows"]
    assert row["candidates"] == 4 and 1 <= row["most_contacts"] <= 4 <= row["slots"]
    assert row["unstable_runs"] == 0
    assert (tmp_path / "contact_counts.md").read_text().startswith("# Contacts at once in MuJoCo C")
