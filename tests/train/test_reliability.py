"""A trained policy loads anywhere, and no command loses or mixes a run's saved files.

The command-line checks run ``python -m fastrl.train`` / ``fastrl.evaluate`` as users do, in
fresh processes with 1, 2 and 4 CPU devices (the device count is fixed when JAX starts).
"""

import hashlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl import envs, physics
from fastrl.cli.train import run
from fastrl.tools import evaluate
from fastrl.training.checkpoint import CheckpointError
from fastrl.training.config import ConfigError
from fastrl.training.files import RunDirError
from fastrl.training.policy import load_policy, load_run
from fastrl.training.start import RunDirLock

from .test_front_door import QUICK, compose_cfg

REPO = Path(__file__).resolve().parents[2]
QUICK_CLI = ["env=inverted_pendulum", "algo=ppo", "debug=quick", "logger=quiet"]


def _env(devices: int | None = None, **extra) -> dict:
    """A child process's environment: fastrl's own XLA flags recomputed by the child, the CPU
    device count as asked, and the repo's compilation cache shared with the test process."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "FASTRL_XLA_FLAGS_ADDED")}
    env.pop("FASTRL_CPU_DEVICES", None)
    if devices is not None:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_COMPILATION_CACHE_DIR"] = str(REPO / ".jax_cache")
    env.update(extra)
    return env


def _cli(args: list[str], cwd: Path, env: dict, ok: bool = True) -> subprocess.CompletedProcess:
    out = subprocess.run(
        [sys.executable, "-m", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    if ok and out.returncode != 0:
        raise AssertionError(f"{args} exited {out.returncode}:\n{out.stdout}\n{out.stderr}")
    return out


def _record(run_dir: Path) -> dict[str, str]:
    """Hashes of a run's saved files other than its checkpoints."""
    return {
        str(p.relative_to(run_dir)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(run_dir.rglob("*"))
        if p.is_file() and "checkpoints" not in p.parts and p.name != ".lock"
    }


def test_command_line_runs_load_anywhere_and_rejected_starts_change_nothing(tmp_path):
    run_dir = tmp_path / "r"
    # Trained on 2 CPU devices (as the CLI picks for PPO on a 2-core machine), stopped early.
    out = _cli(
        ["fastrl.train", *QUICK_CLI, f"hydra.run.dir={run_dir}", "train.stop_after_chunks=2"],
        tmp_path,
        _env(FASTRL_CPU_DEVICES="2"),
    )
    assert "on 2 cpu devices" in out.stdout
    assert f"continue with: python -m fastrl.train resume={run_dir}" in out.stdout
    saved = _record(run_dir)
    assert {"config.json", ".hydra/config.yaml", ".hydra/overrides.yaml", "metrics.csv"} <= set(saved)

    # Rejected starts exit 2, name the problem, and leave every file as it was.
    for args, why in [
        ([*QUICK_CLI, f"hydra.run.dir={run_dir}"], "already holds checkpoints"),  # a new run into it
        (["env=ant", f"hydra.run.dir={run_dir}"], "already holds checkpoints"),
        ([f"resume={run_dir}", "env=hopper"], "env.name: 'inverted_pendulum' -> 'hopper'"),
    ]:
        bad = _cli(["fastrl.train", *args], tmp_path, _env(), ok=False)
        assert bad.returncode == 2 and why in bad.stderr, bad.stderr
        assert "Traceback" not in bad.stderr
        assert _record(run_dir) == saved
    assert not (tmp_path / "runs").exists()  # no empty run folder left behind

    # Saved on 2 devices: evaluated in a 1-device process, loaded in a 4-device one.
    out = _cli(["fastrl.evaluate", str(run_dir), "--episodes", "4"], tmp_path, _env(1))
    assert "inverted_pendulum / ppo at 512 env steps: return" in out.stdout
    code = (
        "import jax, numpy as np; from fastrl import load_policy; assert jax.device_count() == 4; "
        f"print(np.asarray(load_policy({str(run_dir)!r})(np.zeros(4, np.float32))).shape)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=_env(4), capture_output=True, text=True
    )
    assert out.returncode == 0 and out.stdout.strip() == "(1,)", out.stderr

    # resume=true with the run's folder continues THAT run, with its own saved command line,
    # on 1 device; the run then holds checkpoints saved on 1 device, evaluated on 2.
    one = _env(FASTRL_CPU_DEVICES="1")
    out = _cli(["fastrl.train", f"hydra.run.dir={run_dir}", "resume=true"], tmp_path, one)
    assert f"resumed {run_dir} at chunk 2" in out.stdout and "on 1 device" in out.stdout
    assert "inverted_pendulum / ppo: 4 chunks" in out.stdout
    out = _cli(["fastrl.evaluate", str(run_dir), "--episodes", "4"], tmp_path, _env(2))
    assert "at 1,024 env steps" in out.stdout

    # resume=PATH alone (the README's form) keeps the run's config; a dotted key extends it.
    out = _cli(["fastrl.train", f"resume={run_dir}", "train.total_env_steps=1536"], tmp_path, _env())
    assert "inverted_pendulum / ppo: 6 chunks" in out.stdout, out.stdout
    assert not (tmp_path / "runs").exists()
    assert "train.total_env_steps=1536" in (run_dir / ".hydra" / "overrides.yaml").read_text()

    # init_from=PATH: a new run on 2 devices starts from the run's weights (saved on 1 device);
    # weights that do not fit are refused by name, exit 2, nothing written.
    tuned = tmp_path / "tuned"
    args = ["fastrl.train", *QUICK_CLI, f"init_from={run_dir}", "train.stop_after_chunks=1"]
    out = _cli([*args, f"hydra.run.dir={tuned}"], tmp_path, _env(FASTRL_CPU_DEVICES="2"))
    assert f"started from {run_dir}'s params, obs_stats" in out.stdout and "on 2 cpu devices" in out.stdout
    bad = _cli(
        [*args, f"hydra.run.dir={tmp_path}/narrow", "network.value_hidden=[8]"], tmp_path, _env(), ok=False
    )
    assert bad.returncode == 2 and "saved (16,) -> now (8,)" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "narrow").exists() and not (tmp_path / "runs").exists()


def test_two_runs_started_in_the_same_second_get_their_own_folders(tmp_path):
    # Both also share a fresh persistent compilation cache (FASTRL_COMPILE_CACHE), writing the
    # same entry at once; a third launch, identical to the first, then reads its chunk from it,
    # traced program and compiled program both, and trains to the same numbers.
    env = _env(FASTRL_CPU_DEVICES="1", FASTRL_COMPILE_CACHE=str(tmp_path / "cache"))
    env.pop("JAX_COMPILATION_CACHE_DIR")
    args = [sys.executable, "-m", "fastrl.train", *QUICK_CLI, "train.total_env_steps=512"]
    procs = [
        subprocess.Popen(
            [*args, f"seed={s}"],
            cwd=tmp_path,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for s in (0, 1)
    ]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        assert "compilation cache miss" in out or "compilation cache hit" in out, out
    dirs = sorted((tmp_path / "runs" / "inverted_pendulum-ppo").iterdir())
    assert len(dirs) == 2
    seeds = sorted(load_run(d)[0].seed for d in dirs)
    assert seeds == [0, 1]
    for d in dirs:  # each folder holds one run: one row per chunk
        assert len((d / "metrics.csv").read_text().strip().splitlines()) == 1 + 2
    third = subprocess.run([*args, "seed=0"], cwd=tmp_path, env=env, capture_output=True, text=True)
    read = "traced program read from the cache, compilation cache hit"
    assert read in third.stdout, third.stdout + third.stderr
    again = (set((tmp_path / "runs" / "inverted_pendulum-ppo").iterdir()) - set(dirs)).pop()
    first = next(d for d in dirs if load_run(d)[0].seed == 0)
    for a, b in zip(jax.tree.leaves(load_run(first)[3]), jax.tree.leaves(load_run(again)[3]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    off = subprocess.run(
        [*args, "seed=3"],
        cwd=tmp_path,
        env={**env, "FASTRL_COMPILE_CACHE": ""},
        capture_output=True,
        text=True,
    )
    assert "compilation cache off" in off.stdout, off.stdout + off.stderr


def test_a_run_folder_in_use_is_refused_before_anything_is_written(tmp_path):
    with RunDirLock(tmp_path), pytest.raises(RunDirError, match="in use by another fastrl run"):
        run(compose_cfg([*QUICK, f"run_dir={tmp_path}"]))
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock"]


def _corrupt(step_dir: Path) -> None:
    for path in (step_dir / "state").rglob("*"):
        if path.is_file() and path.stat().st_size > 0 and "metadata" not in path.name.lower():
            path.write_bytes(b"garbage")


def test_a_corrupt_newest_checkpoint_falls_back_to_the_one_before(tmp_path, capfd):
    overrides = [*QUICK, "checkpoint.every=1"]
    run(compose_cfg([*overrides, f"run_dir={tmp_path}", "train.stop_after_chunks=2"]))
    _corrupt(tmp_path / "checkpoints" / "2")
    capfd.readouterr()

    rc, _, _, state = load_run(tmp_path)  # the newest that restores, said on stderr
    assert int(state.env_steps) == 256
    err = capfd.readouterr().err
    assert "could not be read, using step 1" in err and "checkpoints/2" in err
    assert "Event loop is closed" not in err and "tensorstore_spec" not in err

    assert evaluate.run([str(tmp_path), "--step", "1", "--episodes", "2"]) == 0
    assert "at 256 env steps" in capfd.readouterr().out
    assert evaluate.run([str(tmp_path), "--step", "7"]) == 2
    assert "no checkpoint of step 7" in capfd.readouterr().err

    # Resume continues from chunk 1; the unreadable chunk 2 is moved aside, never deleted.
    out = run(compose_cfg([*overrides, f"run_dir={tmp_path}/unused", f"resume={tmp_path}"]))
    assert out["status"] == "done" and out["chunks"] == 4
    aside = list((tmp_path / "checkpoints_set_aside").iterdir())
    assert len(aside) == 1 and (aside[0] / "2").is_dir() and (aside[0] / "metrics.csv").is_file()
    assert "Event loop is closed" not in capfd.readouterr().err


def test_resume_step_picks_a_checkpoint_and_sets_newer_ones_aside(tmp_path):
    overrides = [*QUICK, "checkpoint.every=1", "checkpoint.keep=4"]
    run(compose_cfg([*overrides, f"run_dir={tmp_path}", "train.stop_after_chunks=3"]))
    out = run(compose_cfg([*overrides, f"run_dir={tmp_path}/u", f"resume={tmp_path}", "resume_step=1"]))
    assert out["chunks"] == 4
    (aside,) = (tmp_path / "checkpoints_set_aside").iterdir()
    assert sorted(p.name for p in aside.iterdir() if p.is_dir()) == ["2", "3"]
    with pytest.raises(ConfigError, match="resume_step"):
        run(compose_cfg([*QUICK, f"run_dir={tmp_path}/v", "resume_step=1"]))


@pytest.mark.parametrize("key", ["episode_length", "frame_skip"])
def test_zero_episode_length_or_frame_skip_is_an_error_not_the_default(key):
    with pytest.raises(ConfigError, match=f"{key} must be an integer >= 1, got 0"):
        compose_and_make([f"env.{key}=0"])
    with pytest.raises(ValueError, match=f"{key} must be an integer >= 1"):
        envs.make("hopper", **{key: 0})


def compose_and_make(overrides):
    from .test_front_door import typed

    return typed(["env=hopper", *overrides]).env.make()


def test_a_wrong_action_shape_names_the_expected_one():
    env = envs.make("hopper")
    state = env.reset(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"action of shape \(3,\), got \(4,\)"):
        env.step(state, jnp.zeros(4))
    gym_env = envs.make_gym("hopper")
    gym_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action has shape \(2,\); expected \(3,\)"):
        gym_env.step(np.zeros(2))


def test_make_vec_flags_envs_whose_physics_diverged():
    # NaN controls make the physics NaN; an inf control is clamped to ctrlrange by the physics
    # (as in MuJoCo) but makes the hopper's control cost -inf: both are divergence.
    vec = envs.make_vec("hopper", 4, seed=0)
    vec.reset(seed=0)
    actions = np.zeros((4, 3), np.float32)
    actions[1, 0] = np.nan
    actions[3, 2] = np.inf
    _, reward, terminated, _, info = vec.step(actions)
    np.testing.assert_array_equal(info["diverged"], [False, True, False, True])
    np.testing.assert_array_equal(terminated, [False, True, False, True])
    assert reward[1] == 0.0
    _, _, _, _, info = vec.step(np.zeros((4, 3), np.float32))
    assert not info["diverged"].any()  # the diverged envs restarted cleanly


PLANE_ONLY = '<mujoco><worldbody><geom type="plane" size="1 1 1"/></worldbody></mujoco>'


@pytest.mark.parametrize("xml", ["<mujoco/>", PLANE_ONLY])
def test_a_world_with_nothing_to_move_is_refused_by_name(xml):
    with pytest.raises(ValueError, match="no degrees of freedom"):
        physics.load_mjcf(xml)


def test_load_policy_names_a_missing_run(tmp_path):
    with pytest.raises(CheckpointError, match="not a fastrl run folder"):
        load_policy(tmp_path)


def test_the_cached_program_key_follows_what_builds_the_program(tmp_path):
    """The key of a kept traced program changes with the configuration, the model and the state's
    shapes, not with memory addresses in reprs or the state's values; an entry that cannot be
    read is traced again."""
    from fastrl.runtime import compile_cache

    model = envs.make("inverted_pendulum").model
    state = {"params": jnp.zeros((3, 2)), "step": jnp.int32(0)}
    config = {"seed": 0, "fn": lambda: 0}  # a repr holding "at 0x..."
    key = compile_cache.program_key((config, model), state)
    assert compile_cache.program_key(({"seed": 0, "fn": lambda: 0}, model), state) == key
    assert compile_cache.program_key((config, model), {**state, "params": jnp.ones((3, 2))}) == key
    assert compile_cache.program_key(({**config, "seed": 1}, model), state) != key
    assert compile_cache.program_key((config, model.replace(timestep=model.timestep * 2)), state) != key
    assert compile_cache.program_key((config, model), {**state, "params": jnp.zeros((3, 3))}) != key

    jax.config.update("jax_compilation_cache_dir", str(tmp_path))  # restored below
    try:
        calls = []

        def export():
            calls.append(1)
            return jax.export.export(jax.jit(lambda x: 2 * x))(jnp.zeros(3))

        first, read = compile_cache.exported(key, export)
        assert not read and len(calls) == 1
        again, read = compile_cache.exported(key, export)
        assert read and len(calls) == 1
        np.testing.assert_array_equal(again.call(jnp.ones(3)), 2 * np.ones(3))
        (tmp_path / f"{key}.exported").write_bytes(b"not a program")
        _, read = compile_cache.exported(key, export)
        assert not read and len(calls) == 2
    finally:
        jax.config.update("jax_compilation_cache_dir", str(Path(__file__).parents[2] / ".jax_cache"))


class _Env(NamedTuple):
    metrics: dict
    obs: jax.Array
    data: Any


class _OldData(NamedTuple):  # physics data before the engine gained Data.contact_pair
    contact_dist: jax.Array


class _NewData(NamedTuple):
    contact_dist: jax.Array
    contact_pair: jax.Array


class _Saved(NamedTuple):
    params: dict
    env_state: _Env


def test_a_checkpoint_restores_only_into_the_state_layout_it_was_saved_from(tmp_path):
    """A checkpoint restores exactly into a state of the same leaves. One whose leaves differ,
    even only in per-step metrics or the engine's contact pairs (a checkpoint of an earlier
    layout: an env since given a new metric or rid of one, the engine before
    ``Data.contact_pair``), is refused, naming the leaves and the earlier layout."""
    from fastrl.training.checkpoint import Checkpointer, EarlierLayout

    train = {"num_seeds": 1, "vmap_sweep": None}
    config = {"env": {"name": "toy"}, "algo": {}, "network": {}, "seed": 0, "train": train}
    meta = {"config": config, "env_steps": 0, "chunk": 1, "updates": 1, "wall_s": 0.0,
            "eval_history": {}, "reached": [None]}  # fmt: skip
    old_data = _OldData(jnp.ones((4, 5)))
    saved = _Saved(
        {"w": jnp.arange(3.0)}, _Env({"speed": jnp.ones(4), "old": jnp.ones(4)}, jnp.ones((4, 2)), old_data)
    )
    ckpt = Checkpointer(tmp_path / "checkpoints")
    try:
        ckpt.save(1, saved, meta)
        state, _ = ckpt.restore(jax.eval_shape(lambda: saved), config, 1)
        for x, y in zip(jax.tree.leaves(state), jax.tree.leaves(saved), strict=True):
            np.testing.assert_array_equal(x, y)
        new_data = _NewData(jnp.zeros((4, 5)), jnp.ones((4, 5), jnp.int32))
        now = _Saved(
            saved.params, _Env({"speed": jnp.zeros(4), "new": jnp.zeros(4)}, jnp.zeros((4, 2)), new_data)
        )
        every = r"(?=.*metrics\['new'\])(?=.*metrics\['old'\])(?=.*data\.contact_pair)"
        with pytest.raises(EarlierLayout, match=every + r".*other state leaves.*earlier layout"):
            ckpt.restore(jax.eval_shape(lambda: now), config, 1)
        other = _Saved({"w": jnp.zeros(3), "b": jnp.zeros(2)}, saved.env_state)
        with pytest.raises(CheckpointError, match=r"other state .*\['b'\]"):
            ckpt.restore(jax.eval_shape(lambda: other), config, 1)
    finally:
        ckpt.close()


@pytest.mark.parametrize(("eval_every", "chunks"), [(0, []), (1, [1, 2, 3, 4, 5]), (2, [1, 2, 4])])
def test_eval_every_evaluates_chunk_one_then_its_multiples_and_zero_only_at_the_end(eval_every, chunks):
    from types import SimpleNamespace

    from fastrl.training.evaluation import due
    from fastrl.training.progress import Progress

    train = SimpleNamespace(eval_every=eval_every, num_evals=10)
    setup = SimpleNamespace(cfg=SimpleNamespace(train=train), total_updates=60)
    progress, seen = Progress.fresh(1), []
    for chunk in range(1, 7):
        progress.advance(1.0, 10)
        if due(setup, progress, 10):
            seen.append(chunk)
    assert seen == [*chunks, 6]  # the last chunk always evaluates
