"""The training front door: config composition and errors, GAE, runs, checkpoints, resume."""

import dataclasses
import os
import shutil
import signal

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import MissingConfigException

from fastrl import agents, envs
from fastrl.agents.ppo import gae
from fastrl.cli.conf import CONF_DIR
from fastrl.cli.train import run
from fastrl.training.checkpoint import CheckpointError
from fastrl.training.config import ConfigError, RunConfig

QUICK = ["env=inverted_pendulum", "debug=quick", "logger=quiet"]


def compose_cfg(overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        return compose("train", overrides=overrides)


def typed(overrides):
    from omegaconf import OmegaConf

    cfg = compose_cfg([*overrides, "run_dir=/unused"])
    container = OmegaConf.to_container(cfg, resolve=True)
    for key in ("resume", "run_dir"):
        container.pop(key)
    return RunConfig.from_dict(container)


def test_gae_matches_a_python_loop():
    rng = np.random.default_rng(0)
    t, n, gamma, lam = 12, 5, 0.97, 0.9
    rewards, values, next_values = (rng.normal(size=(t, n)) for _ in range(3))
    terminated = rng.random((t, n)) < 0.1
    done = terminated | (rng.random((t, n)) < 0.1)
    adv, targets = gae(
        *(jnp.asarray(x) for x in (rewards, values, next_values, terminated, done)), gamma, lam
    )
    expected = np.zeros((t, n))
    for j in range(n):
        running = 0.0
        for i in reversed(range(t)):
            delta = rewards[i, j] + gamma * (1 - terminated[i, j]) * next_values[i, j] - values[i, j]
            running = delta + gamma * lam * (1 - done[i, j]) * running
            expected[i, j] = running
    np.testing.assert_allclose(adv, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(targets, expected + values, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("env_name", envs.names())
@pytest.mark.parametrize("algo", sorted(agents.ALGORITHMS))
def test_every_env_algo_pair_composes(env_name, algo):
    rc = typed([f"env={env_name}", f"algo={algo}"])
    assert rc.env.name == env_name and rc.algo_name == algo


def test_config_errors_name_the_key_before_compiling():
    with pytest.raises(ConfigError, match="algo.learning_rate='fast' should be of type float"):
        typed(["algo.learning_rate=fast"])
    with pytest.raises(ConfigError, match="num_minibatches=7.*divisors"):
        typed(["algo.num_envs=64", "algo.unroll_length=10", "algo.num_minibatches=7"])
    with pytest.raises(ConfigError, match="network.activation='gelu2'"):
        typed(["network.activation=gelu2"])
    with pytest.raises(MissingConfigException, match="antt"):
        typed(["env=antt"])
    with pytest.raises(ConfigError, match="stop_at_return=950.0 is checked at evaluations.*eval_every >= 1"):
        typed(["train.stop_at_return=950", "train.eval_every=0"])


def test_env_options_reach_the_env_and_bad_ones_are_named():
    env = typed(["env=hand_reorient", "algo=ppo", "env.options.target=faces"]).env.make()
    assert env.target == "faces"
    with pytest.raises(ConfigError, match="target='spin'.*'yaw', 'faces'"):
        typed(["env=hand_reorient", "algo=ppo", "env.options.target=spin"]).env.make()
    with pytest.raises(ConfigError, match="env.options of ant.*'target'"):
        typed(["env=ant", "algo=ppo", "+env.options.target=faces"]).env.make()
    with pytest.raises(ConfigError, match="set it as env.frame_skip"):
        typed(["env=hand_reorient", "algo=ppo", "+env.options.frame_skip=2"]).env.make()


def _weights_of(run_dir):
    """The leaves of the latest checkpoint's training state, and its step."""
    from fastrl.training.policy import load_run

    *_, state = load_run(run_dir)
    return jax.tree.leaves(state)


QUICK_RESUME = [*QUICK, "train.total_env_steps=1024", "train.updates_per_chunk=2"]  # 4 chunks


def test_resume_2_plus_2_chunks_equals_4_chunks_bit_for_bit(tmp_path):
    full, split = tmp_path / "full", tmp_path / "split"
    out = run(compose_cfg([*QUICK_RESUME, f"run_dir={full}"]))
    assert out["status"] == "done" and out["chunks"] == 4
    out = run(compose_cfg([*QUICK_RESUME, f"run_dir={split}", "train.stop_after_chunks=2"]))
    assert out["status"] == "stopped" and out["chunks"] == 2
    out = run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/ignored", f"resume={split}"]))
    assert out["status"] == "done" and out["chunks"] == 4 and out["run_dir"] == str(split)
    a, b = _weights_of(full), _weights_of(split)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    rows = (split / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 4  # header + one row per chunk, no duplicates after the resume
    assert (split / "config.json").exists()


def test_ctrl_c_saves_a_checkpoint_and_stops(tmp_path, capsys):
    from fastrl.training import Callback, Evaluation, runner

    class Interrupt(Callback):
        def on_chunk(self, run, chunk):
            if chunk.index == 1:
                os.kill(os.getpid(), signal.SIGINT)

    cfg = compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}"])
    rc = typed(QUICK_RESUME)
    out = runner.train(rc, tmp_path, callbacks=[Evaluation(), Interrupt()])
    assert out["status"] == "stopped" and out["chunks"] == 1 and out["interrupted"]
    assert (tmp_path / "checkpoints" / "1").is_dir()
    # the stop says how to continue (and the command line exits 130, the shell's Ctrl-C code)
    assert (
        f"stopped by Ctrl-C after chunk 1 of 4, checkpoint saved; continue with: python -m "
        f"fastrl.train resume={tmp_path}" in capsys.readouterr().out
    )
    del cfg


def test_evaluation_is_a_callback_the_command_line_hands_the_runner(tmp_path):
    """The runner evaluates through its ``Evaluation`` callback: the default, the command line's
    first; a run whose callbacks have none cannot stop at an evaluation return, and is refused
    before anything is written."""
    from fastrl.tools import callbacks
    from fastrl.training import Evaluation, runner

    assert isinstance(callbacks.standard()[0], Evaluation)
    with pytest.raises(ConfigError, match="stop_at_return.*no Evaluation is among the callbacks"):
        runner.train(typed([*QUICK, "train.stop_at_return=100"]), tmp_path / "run", callbacks=[])
    assert not (tmp_path / "run").exists()


def test_max_seconds_stops_the_run_on_time_with_a_checkpoint(tmp_path, capsys):
    from fastrl.training.checkpoint import Checkpointer

    long = [*QUICK, "train.total_env_steps=100_000_000", "train.updates_per_chunk=null"]
    out = run(compose_cfg([*long, f"run_dir={tmp_path}", "train.max_seconds=0.001"]))
    assert out["status"] == "stopped" and out["chunks"] == 1 and not out["interrupted"]
    assert "stopped by train.max_seconds=0.001 after chunk 1 (1 of " in capsys.readouterr().out
    ckpt = Checkpointer(tmp_path / "checkpoints")
    try:
        assert ckpt.steps() == [1] and ckpt.read_meta(1)[1]["saved_at"] > 0
    finally:
        ckpt.close()
    with pytest.raises(ConfigError, match="train.max_seconds=0"):
        typed([*QUICK, "train.max_seconds=0"])
    # a run whose last chunk ends past the limit has finished: "done", not "stopped"
    one = [*QUICK, "train.total_env_steps=256", "train.updates_per_chunk=2", "train.max_seconds=0.001"]
    assert run(compose_cfg([*one, f"run_dir={tmp_path}/one"]))["status"] == "done"


def test_a_time_limit_shortens_the_chunk_that_reaches_it():
    from fastrl.training.chunk import ChunkSizer
    from fastrl.training.progress import Clock, Progress

    sizer = ChunkSizer.__new__(ChunkSizer)
    sizer.fixed, sizer.seconds, sizer.total, sizer.per_update = None, 10.0, 1000, 0.5
    progress = Progress.fresh(1)
    clock = Clock(None)
    assert sizer.next(progress, clock) == 20  # ~10 s of 0.5 s updates
    clock = Clock(3.2)
    assert sizer.next(progress, clock) in (6, 7)  # what is left of 3.2 s, at 0.5 s an update
    clock.start -= 10
    assert clock.out() and sizer.next(progress, clock) == 1


def test_corrupt_or_incompatible_checkpoint_gives_a_clear_error(tmp_path):
    run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}", "train.stop_after_chunks=1"]))
    # A different network cannot continue this run: the error names the keys.
    with pytest.raises(CheckpointError, match=r"network.policy_hidden: \[16\] -> \[8\]"):
        run(
            compose_cfg(
                [*QUICK_RESUME, f"run_dir={tmp_path}/x", f"resume={tmp_path}", "network.policy_hidden=[8]"]
            )
        )
    # A fresh run never overwrites a folder that holds checkpoints.
    with pytest.raises(CheckpointError, match="already holds checkpoints"):
        run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}"]))
    # Corrupt array files: a clear error, and the checkpoint folder is left as it was.
    step_dir = tmp_path / "checkpoints" / "1"
    backup = tmp_path / "backup"
    shutil.copytree(step_dir, backup)
    for path in (step_dir / "state").rglob("*"):
        if path.is_file() and path.stat().st_size > 0 and "metadata" not in path.name:
            path.write_bytes(b"garbage" * 3)
    with pytest.raises(CheckpointError, match="could not be restored|unreadable"):
        run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/y", f"resume={tmp_path}"]))
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == ["1"]


def test_init_from_starts_a_new_run_from_another_runs_weights(tmp_path, capsys):
    from fastrl.training.policy import load_run, start_from

    source = tmp_path / "source"
    run(compose_cfg([*QUICK_RESUME, f"run_dir={source}", "train.stop_after_chunks=1"]))
    _, _, learner, saved = load_run(source)
    # The learned fields are the source's, in every agent of a batch; the rest stays fresh.
    for n in (1, 2):
        keys = jax.random.split(jax.random.PRNGKey(7), n)
        fresh = learner.init(keys[0]) if n == 1 else jax.vmap(learner.init)(keys)
        weights, line = start_from(fresh, source, "ppo", n)
        state = dataclasses.replace(fresh, **weights)
        assert "params, obs_stats" in line and "at 256 env steps" in line
        for name in ("params", "obs_stats"):
            for x, y in zip(jax.tree.leaves(getattr(state, name)), jax.tree.leaves(getattr(saved, name)),
                            strict=True):  # fmt: skip
                np.testing.assert_array_equal(x, np.broadcast_to(y, x.shape))
        for x, y in zip(jax.tree.leaves(state.opt_state), jax.tree.leaves(fresh.opt_state), strict=True):
            np.testing.assert_array_equal(x, y)
        assert int(np.max(state.env_steps)) == 0
    # The front door: a new run that records where it started; a resume of it ignores the key.
    out = run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/tuned", f"init_from={source}"]))
    assert out["status"] == "done" and out["chunks"] == 4
    started = f"[fastrl] started from {source}'s params, obs_stats (inverted_pendulum / ppo"
    assert started in capsys.readouterr().out
    import json

    assert json.loads((tmp_path / "tuned" / "config.json").read_text())["init_from"] == str(source)
    more = [*QUICK_RESUME, f"run_dir={tmp_path}/x", f"resume={tmp_path}/tuned", "train.total_env_steps=1536"]
    out = run(compose_cfg([*more, f"init_from={source}"]))  # continues its own checkpoints
    assert out["status"] == "done" and out["chunks"] == 6 and "started from" not in capsys.readouterr().out
    # Weights that do not fit, or of another algorithm: a clear error, and nothing written.
    with pytest.raises(CheckpointError, match=r"params\['policy'\].*saved \(16,\) -> now \(8,\)"):
        narrow = "network.policy_hidden=[8]"
        run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/a", f"init_from={source}", narrow]))
    with pytest.raises(CheckpointError, match="that run trained ppo, this one sac"):
        run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/b", f"init_from={source}", "algo=sac"]))
    with pytest.raises(CheckpointError, match="not a fastrl run folder"):
        run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}/c", f"init_from={tmp_path}/none"]))
    assert not any((tmp_path / d / "config.json").exists() for d in "abc")
    with pytest.raises(ConfigError, match="init_from=3 should be a run folder"):
        typed(["init_from=3"])


def test_a_diverging_run_is_reported_and_never_saved(tmp_path, capsys):
    # Rewards scaled past float32's range make the value loss infinite in the first chunk.
    out = run(compose_cfg([*QUICK_RESUME, f"run_dir={tmp_path}", "algo.reward_scaling=1e38"]))
    assert out["status"] == "diverged" and out["chunks"] == 0
    assert "training diverged (non-finite loss) in chunk 1" in capsys.readouterr().err
    assert not (tmp_path / "checkpoints").exists() or not any((tmp_path / "checkpoints").iterdir())


def test_dropped_contacts_are_logged_and_warned_about_once(tmp_path, capsys):
    """A Hopper with one contact slot drops contacts once it is down on its foot: the run logs
    ``env/contact_overflow`` and warns once, naming the option that gives more slots."""
    overrides = ["env=hopper", "debug=quick", "logger=quiet", f"run_dir={tmp_path}", "+env.options.nconmax=1"]
    run(compose_cfg([*overrides, "env.episode_length=200"]))
    err = capsys.readouterr().err
    assert err.count("the scene's contact budgets dropped contacts") == 1
    assert "+env.options.nconmax=N" in err
    assert max(float(r["env/contact_overflow"]) for r in _csv_rows(tmp_path)) > 0


def test_collapse_watch_flags_a_return_that_falls_back():
    from fastrl.training.progress import CollapseWatch

    w = CollapseWatch(2)
    # Agent 0 learns (10 -> 100) then falls to 40: more than half the gain lost.
    assert [w.update(0, r) for r in (10, 60, 100, 70, 40)] == [False, False, False, False, True]
    assert w.update(0, 90) is False and w.ever[0]  # recovered; it did collapse once
    # Agent 1 never gains more than noise (15% of |first| + 1), so no fall counts as a collapse:
    # an untrained HalfCheetah's evaluations (PPO, halfcheetah, first 5 chunks) are no collapse.
    assert not any(w.update(1, r) for r in (-180.3, -159.5, -181.5, -195.8, -208.1))
    # A large baseline (the Ant's ~1000 for standing): a wobble of 12% of the best is no
    # collapse even though it gives back most of a small gain; losing half the return is.
    ant = CollapseWatch(1)
    assert not any(ant.update(0, r) for r in (944, 1008, 1113, 988, 1032))
    assert ant.update(0, 500) is True
    # The history survives a checkpoint (JSON metadata) and judges the same way after a resume.
    import json

    again = CollapseWatch(2, history=json.loads(json.dumps(w.history())))
    assert again.update(0, 40) is True and again.best[0] == 100


def test_ppo_improves_inverted_pendulum_within_a_minute(tmp_path, capsys):
    # Told to stop at a return of 100 (a random policy survives ~5-20 steps), the run stops at its
    # first evaluation that gets there, within a minute of training, saves it and says where.
    overrides = ["env=inverted_pendulum", "logger=quiet", "train.total_env_steps=40000"]
    overrides += ["train.updates_per_chunk=10", "train.eval_every=1"]
    out = run(compose_cfg([*overrides, f"run_dir={tmp_path}", "train.stop_at_return=100"]))
    assert out["status"] == "reached" and out["wall_s"] < 60
    evals = [row["eval/episode_return"] for row in _csv_rows(tmp_path)]
    assert len(evals) == out["chunks"] == out["reached"]["chunk"] < 4  # of 4 chunks of 10 x 1024 steps
    assert evals[-1] == out["reached"]["eval_return"] >= 100 > max(evals[:-1], default=0)
    assert "evaluation return reached train.stop_at_return=100 by chunk" in capsys.readouterr().out
    assert sorted(int(p.name) for p in (tmp_path / "checkpoints").iterdir())[-1] == out["chunks"]


def test_chunks_sized_by_time_train_the_same_agent(tmp_path, capsys):
    # With train.updates_per_chunk=null a chunk runs as many updates as fit in chunk_seconds,
    # the first just one; the size is an argument of one compiled program, so where the chunks
    # end changes nothing in training. Evaluations follow train.num_evals (evenly spaced in
    # updates), checkpoints checkpoint.seconds, and metrics.csv gains the evaluation columns
    # when the first evaluation comes.
    base = ["env=inverted_pendulum", "debug=quick", "logger=quiet", "train.total_env_steps=1024"]  # 8 updates
    run(compose_cfg([*base, f"run_dir={tmp_path}/fixed"]))  # 4 chunks of 2 updates
    timed = ["train.updates_per_chunk=null", "train.eval_every=null", "train.num_evals=4"]
    out = run(compose_cfg([*base, *timed, "train.chunk_seconds=1e-9", "checkpoint.seconds=1e9",
                           f"run_dir={tmp_path}/ones"]))  # fmt: skip
    assert out["status"] == "done" and out["chunks"] == 8 and out["env_steps"] == 1024
    for x, y in zip(_weights_of(tmp_path / "fixed"), _weights_of(tmp_path / "ones"), strict=True):
        np.testing.assert_array_equal(x, y)
    rows = _csv_rows(tmp_path / "ones")
    assert [r["env_steps"] for r in rows if "eval/episode_return" in r] == [256, 512, 768, 1024]
    assert "eval/episode_return" not in rows[0] and len(rows) == 8
    assert sorted(p.name for p in (tmp_path / "ones" / "checkpoints").iterdir()) == ["8"]  # the last only
    out = run(compose_cfg([*base, *timed, "train.chunk_seconds=1e9", f"run_dir={tmp_path}/one"]))
    assert out["chunks"] == 2  # one update, then the other seven in one chunk
    for x, y in zip(_weights_of(tmp_path / "fixed"), _weights_of(tmp_path / "one"), strict=True):
        np.testing.assert_array_equal(x, y)


def _csv_rows(run_dir):
    import csv

    with open(run_dir / "metrics.csv") as f:
        return [{k: float(v) for k, v in row.items() if v} for row in csv.DictReader(f)]


def test_load_policy_and_evaluate_cli(tmp_path, capsys):
    import fastrl
    from fastrl.tools import evaluate

    run(compose_cfg([*QUICK, f"run_dir={tmp_path}"]))
    policy = fastrl.load_policy(tmp_path)
    action = jax.jit(policy)(jnp.zeros((3, 4)))
    assert action.shape == (3, 1) and np.all(np.abs(np.asarray(action)) <= 3.0)
    assert evaluate.run([str(tmp_path), "--episodes", "4", "--export", str(tmp_path / "ep.npz")]) == 0
    out = capsys.readouterr().out
    assert "return" in out and "+-" in out
    assert np.load(tmp_path / "ep.npz")["qpos"].shape[1] == 2
    assert evaluate.run([str(tmp_path / "nothing")]) == 2


def test_cpu_devices_per_core_for_ppo_only(monkeypatch):
    """The command line gives PPO one CPU device per core, as many as divide its batches: the
    layout's decision (``fastrl.training.layout``), which ``FASTRL_CPU_DEVICES`` overrides."""
    from fastrl.cli import train
    from fastrl.training import layout

    monkeypatch.delenv("FASTRL_CPU_DEVICES", raising=False)
    ppo = typed(["env=inverted_pendulum", "algo=ppo", "algo.num_envs=6", "algo.unroll_length=4"])
    assert ppo.algo.minibatch_size % 2 == 0
    assert train.cpu_devices(ppo, 2) == layout.cpu_devices(ppo, 2) == 2
    assert layout.cpu_devices(ppo, 4) == 3  # 4 does not divide 6 envs; 3 divides both batches
    assert layout.cpu_devices(ppo, 1) == 1
    assert layout.cpu_devices(typed(["env=inverted_pendulum", "algo=sac"]), 2) == 1
    seeds = typed(["env=inverted_pendulum", "algo=ppo", "train.num_seeds=2"])
    assert layout.cpu_devices(seeds, 2) == 1  # agent batches keep one device
    # robot tasks whose step runs slower split keep one device; the Go1's splits
    assert layout.cpu_devices(typed(["env=humanoid_joystick", "algo=ppo"]), 2) == 1
    assert layout.cpu_devices(typed(["env=go1_joystick", "algo=ppo"]), 2) == 2
    # the learner splits its own work over exactly those device counts, and only in a single run
    assert [layout.learner_splits(ppo, 1, n) for n in (1, 2, 3, 4)] == [False, True, True, False]
    assert not layout.learner_splits(ppo, 2, 2)
    monkeypatch.setenv("FASTRL_CPU_DEVICES", "1")
    assert train.cpu_devices(ppo, 2) == 1
    monkeypatch.setenv("FASTRL_CPU_DEVICES", "two")
    with pytest.raises(ConfigError, match="FASTRL_CPU_DEVICES='two'"):
        train.cpu_devices(ppo, 2)


@pytest.mark.parametrize("algo", sorted(agents.ALGORITHMS))
def test_a_start_builds_its_learner_once(monkeypatch, algo):
    """The run's env steps per update come from the learner's registry record, so its total
    updates are known before the learner is built, once; the built learner agrees."""
    from fastrl.training import run_setup

    built = []
    make = agents.make_learner
    monkeypatch.setattr(agents, "make_learner", lambda *a, **k: built.append(a) or make(*a, **k))
    setup = run_setup.make_setup(typed([*QUICK, f"algo={algo}"]))
    assert len(built) == 1 and built[0][4] == setup.total_updates
    assert setup.steps_per_update == setup.learner.env_steps_per_update


def test_cli_xla_flags_keep_what_the_user_set(monkeypatch):
    from jax._src import xla_bridge

    from fastrl.cli import train
    from fastrl.runtime import xla_flags

    ppo = typed(["env=inverted_pendulum", "algo=ppo", "algo.num_envs=6", "algo.unroll_length=4"])
    monkeypatch.setenv("FASTRL_CPU_DEVICES", "2")
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    monkeypatch.setenv(xla_flags.ADDED_VAR, os.environ.get(xla_flags.ADDED_VAR, ""))  # restored after
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    train._set_cpu_flags(ppo)
    added = [
        "--xla_force_host_platform_device_count=2",
        "--xla_cpu_use_fusion_emitters=false",
        "--xla_cpu_experimental_ynn_fusion_type=-reduce,-eltwise",
    ]
    assert os.environ["XLA_FLAGS"].split() == ["--xla_dump_to=/tmp/x", *added]
    mine = (
        "--xla_force_host_platform_device_count=1 --xla_cpu_use_fusion_emitters=true "
        "--xla_cpu_experimental_ynn_fusion_type=+dot"
    )
    monkeypatch.setenv("XLA_FLAGS", mine)
    train._set_cpu_flags(ppo)
    assert os.environ["XLA_FLAGS"] == mine
    monkeypatch.setenv("FASTRL_XLA_FLAGS", "0")  # the opt-out keeps only the device count
    monkeypatch.setenv("XLA_FLAGS", "")
    train._set_cpu_flags(ppo)
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=2"
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: True)  # too late to change
    monkeypatch.setenv("XLA_FLAGS", "")
    train._set_cpu_flags(ppo)
    assert os.environ["XLA_FLAGS"] == ""


def test_cli_xla_flags_per_learner(monkeypatch):
    """SAC runs with XLA's fusion emitters (faster for its networks): the command line takes out
    the flag ``fastrl.use_recommended_xla_flags()`` added (here or in a parent process), never the
    user's own."""
    from jax._src import xla_bridge

    from fastrl.cli import train
    from fastrl.runtime import xla_flags

    sac = typed(["env=inverted_pendulum", "algo=sac", "algo.num_envs=4"])
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    monkeypatch.delenv("FASTRL_XLA_FLAGS", raising=False)
    emitters, ynn = (
        "--xla_cpu_use_fusion_emitters=false",
        "--xla_cpu_experimental_ynn_fusion_type=-reduce,-eltwise",
    )
    monkeypatch.setenv(xla_flags.ADDED_VAR, "")
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    xla_flags.apply()  # what ``fastrl.use_recommended_xla_flags()`` does
    assert emitters in os.environ["XLA_FLAGS"].split()
    xla_flags.apply()  # a child process that inherited both variables opts in again
    train._set_cpu_flags(sac)
    assert os.environ["XLA_FLAGS"].split() == ["--xla_dump_to=/tmp/x", ynn]
    # The user's own setting of the flag stays.
    monkeypatch.setenv(xla_flags.ADDED_VAR, "")
    monkeypatch.setenv("XLA_FLAGS", emitters)
    xla_flags.apply()
    train._set_cpu_flags(sac)
    assert os.environ["XLA_FLAGS"].split() == [emitters, ynn]


def test_progress_line_says_when_no_training_episode_has_ended_instead_of_printing_nan():
    from fastrl.training.outputs import progress_line

    row = {"env_steps": 20480, "perf/env_steps_per_s": 1600.0}
    waiting = progress_line(row, 10_000_000, 13.0, float("nan"))
    assert "no episode ended yet" in waiting and "nan" not in waiting
    assert "train return    123.46" in progress_line(row, 10_000_000, 13.0, 123.456)


def test_a_run_trained_with_a_training_aid_loads_and_scores_the_task(tmp_path):
    """A leap_cube_reorient run trained with near targets (a training aid whose episodes carry
    an extra countdown) restores its checkpoint, and the loaded env is the task's (no aid)."""
    from fastrl.training.policy import load_policy, load_run

    overrides = ["env=leap_cube_reorient", "algo=ppo", "debug=quick", "logger=quiet",
                 "env.options.near_targets=0.5", "env.episode_length=4", "algo.num_envs=4"]  # fmt: skip
    run(compose_cfg([*overrides, f"run_dir={tmp_path}"]))
    rc, env, _, state = load_run(tmp_path)
    assert rc.env.options["near_targets"] == 0.5 and env.near_targets == 0.0
    assert "near_in" in state.env_state.task  # the saved training envs carry the aid
    assert "near_in" not in env.reset(jax.random.PRNGKey(0)).task
    policy = load_policy(tmp_path)
    action = policy(env.reset(jax.random.PRNGKey(1)).obs)
    assert action.shape == (16,) and bool(jnp.isfinite(action).all())
