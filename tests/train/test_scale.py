"""Agent batches in one program (num_seeds, vmap_sweep) and sharding over host devices."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from fastrl import agents
from fastrl.tools import callbacks, report
from fastrl.training import runner, scale
from fastrl.training.checkpoint import CheckpointError
from fastrl.training.config import ConfigError

from .test_front_door import QUICK, typed

ROOT = Path(__file__).resolve().parents[2]


def test_expand_lists_every_value_times_every_seed():
    cfg = typed([*QUICK, "seed=3", "train.num_seeds=2", "train.vmap_sweep={learning_rate:[1e-3,3e-4]}"])
    specs = scale.expand(cfg)
    expected = [(3, 1e-3), (4, 1e-3), (3, 3e-4), (4, 3e-4)]
    assert [(s.seed, s.config.algo.learning_rate) for s in specs] == expected
    assert len({s.tag for s in specs}) == 4
    for s in specs:  # each agent's config is that of the single run it reproduces
        assert s.config.train.num_seeds == 1 and s.config.train.vmap_sweep is None
        assert s.config.seed == s.seed


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.vmap_sweep={num_envs:[8,16]}", "only float options"),
        ("train.vmap_sweep={learning_rate:3e-4}", "non-empty list"),
        ("train.vmap_sweep={learning_rate:[-1.0]}", "learning_rate=-1.0 must be > 0"),
        ("train.num_seeds=0", "num_seeds=0 must be >= 1"),
    ],
)
def test_bad_agent_batches_are_refused_before_compiling(override, message):
    with pytest.raises(ConfigError, match=message):
        scale.expand(typed([*QUICK, override]))


def test_a_sweep_of_one_value_trains_that_value(monkeypatch):
    """A ``vmap_sweep`` of one value with one seed is a batch of one agent: a single run, whose
    learner has the swept value (it had the unswept config's before)."""
    cfg = typed([*QUICK, "train.vmap_sweep={learning_rate:[7e-4]}"])
    assert cfg.algo.learning_rate != 7e-4
    built = []
    make = agents.make_learner
    monkeypatch.setattr(
        agents, "make_learner", lambda name, algo, *a, **k: built.append(algo) or make(name, algo, *a, **k)
    )
    scale.run_learner(cfg, scale.expand(cfg), cfg.env.make(), 4, None)
    assert [algo.learning_rate for algo in built] == [7e-4]


def _two_updates(learner):
    return jax.jit(lambda s: jax.lax.scan(lambda s, _: learner.update(s), s, None, length=2))


# SAC's batch (about a minute) runs with the slow tests; PPO's covers the vmapped machinery here.
@pytest.mark.parametrize("algo", ["ppo", pytest.param("sac", marks=pytest.mark.slow)])
def test_each_agent_of_a_batch_matches_its_single_run(algo):
    cfg = typed([*QUICK, f"algo={algo}", "train.num_seeds=2", "train.vmap_sweep={learning_rate:[1e-3,3e-4]}"])
    env = cfg.env.make()
    specs = scale.expand(cfg)
    batch = scale.batch_learner(cfg, specs, env, 4)
    batched, _ = _two_updates(batch)(jax.jit(batch.init)(scale.init_keys(specs)))
    finals = [np.concatenate([np.ravel(x[i]) for x in jax.tree.leaves(batched.params)]) for i in range(4)]
    for i in (0, 3):  # first seed at the first rate, second seed at the second
        spec = specs[i]
        single = agents.make_learner(algo, spec.config.algo, env, cfg.network, 4)
        state = jax.jit(single.init)(jax.random.PRNGKey(spec.seed))
        state, _ = _two_updates(single)(state)
        mine = jax.tree.map(lambda x, i=i: x[i], batched)
        for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(state), strict=True):
            np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=2e-4, atol=2e-5)
    # independent RNG streams: agents of different seeds differ (and PPO's learning rates act at once)
    for i in range(4):
        for j in range(i):
            if specs[i].seed != specs[j].seed or algo == "ppo":
                assert not np.allclose(finals[i], finals[j]), (specs[i].tag, specs[j].tag)


def test_batch_run_logs_each_agent_and_resumes_bit_exactly(tmp_path):
    overrides = [
        *QUICK,
        "logger.plot=true",
        "logger.tensorboard=true",
        "train.num_seeds=2",
        "train.vmap_sweep={entropy_cost:[0.0,0.01]}",
    ]
    cfg = typed(overrides)
    full = runner.train(cfg, tmp_path / "full", callbacks=callbacks.standard())  # the curves among them
    assert full["status"] == "done" and len(full["agents"]) == 4
    agent_dirs = sorted((tmp_path / "full" / "agents").iterdir())
    assert [d.name for d in agent_dirs] == full["agents"]
    for d in agent_dirs:
        for name in ("config.json", "metrics.csv", "curve.png"):
            assert (d / name).exists(), d / name
        assert any((d / "tb").iterdir())
        assert json.loads((d / "config.json").read_text())["train"]["num_seeds"] == 1
    # a batch split 1 + rest chunks equals the whole batch bit for bit
    typed_split = typed([*overrides, "train.stop_after_chunks=1"])
    assert runner.train(typed_split, tmp_path / "split")["status"] == "stopped"
    with pytest.raises(CheckpointError, match="train.num_seeds: 2 -> 3"):
        runner.train(typed([*overrides, "train.num_seeds=3"]), tmp_path / "split", resume=True)
    runner.train(cfg, tmp_path / "split", resume=True)
    for d in agent_dirs:
        a = report.read_metrics(d / "metrics.csv")
        b = report.read_metrics(tmp_path / "split" / "agents" / d.name / "metrics.csv")
        for key in ("loss/policy_loss", "loss/value_loss", "eval/episode_return"):
            np.testing.assert_array_equal(a[key], b[key])
    # One agent's policy out of the batch checkpoint: by index, by tag, or by its own folder.
    import fastrl
    from fastrl.tools import evaluate

    with pytest.raises(CheckpointError, match="batch of 4 agents.*agent=0"):
        fastrl.load_policy(tmp_path / "full")
    with pytest.raises(CheckpointError, match="agent=7 is not one of"):
        fastrl.load_policy(tmp_path / "full", agent=7)
    obs = jax.random.normal(jax.random.PRNGKey(0), (5, 4))
    acts = [np.asarray(fastrl.load_policy(tmp_path / "full", agent=i)(obs)) for i in range(4)]
    np.testing.assert_array_equal(acts[1], fastrl.load_policy(agent_dirs[1])(obs))
    by_tag = fastrl.load_policy(tmp_path / "full", agent=full["agents"][2])
    np.testing.assert_array_equal(acts[2], by_tag(obs))
    assert not np.array_equal(acts[0], acts[1])  # seeds 0 and 1: different networks
    assert fastrl.load_policy(agent_dirs[3]).run_config["algo"]["entropy_cost"] == 0.01
    assert evaluate.run([str(tmp_path / "full"), "--agent", "1", "--episodes", "2"]) == 0
    assert report.run([str(tmp_path / "full")]) == 0
    table = (tmp_path / "full" / "report.md").read_text()
    assert "algo.entropy_cost=0.0" in table and "algo.entropy_cost=0.01" in table


_SHARD_SCRIPT = """
import json, sys, jax, numpy as np
import fastrl
fastrl.use_recommended_xla_flags()
from fastrl.training import runner
from tests.train.test_front_door import typed
cfg = typed(sys.argv[2:])
out = runner.train(cfg, sys.argv[1])
print(json.dumps({"devices": jax.device_count(), "status": out["status"]}))
"""


_COMPARED = ("loss/policy_loss", "loss/value_loss", "train/episode_return", "eval/episode_return")


def _device_run(run_dir: Path, n: int) -> subprocess.CompletedProcess:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}", PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-c", _SHARD_SCRIPT, str(run_dir), *QUICK]
    return subprocess.run(cmd, check=True, env=env, cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def two_device_run(tmp_path_factory) -> Path:
    """The QUICK run in one process on 2 CPU devices (env batch split, gradients all-reduced)."""
    run_dir = tmp_path_factory.mktemp("dev2") / "run"
    out = _device_run(run_dir, 2)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"devices": 2, "status": "done"}
    assert "2 cpu devices" in out.stdout
    return run_dir


def test_two_host_devices_give_the_one_device_result(tmp_path, two_device_run):
    """The same run on 1 and on 2 CPU devices (the env batch split, gradients all-reduced): equal
    curves. (Agent batches split by agent share nothing across devices.)"""
    out = _device_run(tmp_path / "dev1", 1)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"devices": 1, "status": "done"}
    assert "cpu devices" not in out.stdout
    runs = {n: sorted(d.rglob("metrics.csv")) for n, d in ((1, tmp_path / "dev1"), (2, two_device_run))}
    assert len(runs[1]) == len(runs[2]) == 1
    for a, b in zip(runs[1], runs[2], strict=True):
        ma, mb = report.read_metrics(a), report.read_metrics(b)
        for key in _COMPARED:
            np.testing.assert_allclose(ma[key], mb[key], rtol=1e-4, atol=1e-5, err_msg=key)


def test_two_processes_train_as_one_process_on_two_devices(tmp_path, two_device_run):
    """Multi-host training, two local processes: ``jax.distributed`` on the loopback address,
    one CPU device each, launched as a cluster would launch them (``distributed=true`` and the
    FASTRL_COORDINATOR / FASTRL_NUM_PROCESSES / FASTRL_PROCESS_ID variables). The run equals the
    one-process run on 2 devices to float rounding, and process 0 alone writes the outputs."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    run_dir = tmp_path / "run"
    # chunks sized by time and checkpoints by time, decided by process 0 for both processes
    timed = ["train.updates_per_chunk=null", "train.chunk_seconds=0.2", "checkpoint.seconds=0.3"]
    cmd = [
        sys.executable,
        "-m",
        "fastrl.train",
        *QUICK,
        *timed,
        "distributed=true",
        f"hydra.run.dir={run_dir}",
    ]
    procs = []
    for i in range(2):
        env = dict(os.environ, PYTHONPATH=str(ROOT), FASTRL_COORDINATOR=f"127.0.0.1:{port}",
                   FASTRL_NUM_PROCESSES="2", FASTRL_PROCESS_ID=str(i), FASTRL_CPU_DEVICES="1")  # fmt: skip
        env.pop("XLA_FLAGS", None)
        procs.append(
            subprocess.Popen(
                cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            )
        )
    outs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    assert "chunk compiled" in outs[0] and "on 2 cpu devices" in outs[0]  # the start line
    assert "chunk compiled" not in outs[1]  # process 0 alone reports
    ma, mb = report.read_metrics(run_dir / "metrics.csv"), report.read_metrics(two_device_run / "metrics.csv")
    assert list(ma["chunk"]) == list(range(1, len(ma["chunk"]) + 1))  # one row per chunk: one writer
    assert ma["env_steps"][-1] == mb["env_steps"][-1] == 1024
    # where the chunks end changes nothing: the final evaluation and the trained weights agree
    np.testing.assert_allclose(ma["eval/episode_return"][-1], mb["eval/episode_return"][-1], rtol=1e-4)
    from fastrl.training.policy import load_run

    a, b = (jax.tree.leaves(load_run(d)[-1]) for d in (run_dir, two_device_run))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=1e-4, atol=1e-5)
