"""Hostile and damaged run folders, signals and failed writes: each ends in a named error or a
correct continuation, and nothing outside the run folder (or saved inside it) is lost.

A run folder is untrusted input (it may come from someone else), so the symlink checks plant
real links to files outside the folder and compare those files' bytes afterwards. The signal and
write-failure checks run ``python -m fastrl.train`` in a child process, as users do.
"""

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fastrl.cli.resume import resumed_config
from fastrl.cli.train import run
from fastrl.training import Callback, Evaluation, runner
from fastrl.training.checkpoint import Checkpointer
from fastrl.training.config import ConfigError
from fastrl.training.files import RunDirError
from fastrl.training.signals import StopFlag

from .test_front_door import QUICK, QUICK_RESUME, _weights_of, compose_cfg, typed
from .test_reliability import QUICK_CLI, _env

# 40 chunks of 2 updates: long enough to signal or fill the disk part way through.
LONG_CLI = [*QUICK_CLI, "train.total_env_steps=10240", "train.updates_per_chunk=2", "checkpoint.every=1"]


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory) -> Path:
    """A run stopped after 2 of its 4 chunks, a checkpoint at each: copied by the tests that
    damage it."""
    run_dir = tmp_path_factory.mktemp("saved") / "run"
    run(compose_cfg([*QUICK_RESUME, "checkpoint.every=1", f"run_dir={run_dir}", "train.stop_after_chunks=2"]))
    return run_dir


def _copy(run_dir: Path, to: Path) -> Path:
    subprocess.run(["cp", "-a", str(run_dir), str(to)], check=True)
    return to


def _resume(run_dir: Path, *extra: str) -> dict:
    line = [*QUICK_RESUME, "checkpoint.every=1", f"run_dir={run_dir}/unused", f"resume={run_dir}", *extra]
    return run(compose_cfg(line))


# ----------------------------------------------------------------------------- links


@pytest.mark.parametrize("name", ["config.json.tmp", ".lock", "metrics.csv", "config.json", "checkpoints/1"])
def test_a_link_in_a_run_folder_is_refused_and_its_target_untouched(saved_run, tmp_path, name):
    run_dir = _copy(saved_run, tmp_path / "run")
    victim = tmp_path / "victim"
    victim.write_bytes(b"the user's own file\n")
    target = run_dir / name
    if target.is_dir():
        shutil.rmtree(target)
    target.unlink(missing_ok=True)
    os.symlink(victim, target)
    with pytest.raises(RunDirError, match=f"{name} is a symbolic link"):
        _resume(run_dir)
    assert victim.read_bytes() == b"the user's own file\n"


def test_the_writers_never_follow_a_link_planted_after_the_check(tmp_path):
    from fastrl.training import files

    victim = tmp_path / "victim"
    victim.write_bytes(b"keep\n")
    for name in ("a.json.tmp", "b.csv", "c.lock"):
        os.symlink(victim, tmp_path / name)
    with pytest.raises(RunDirError, match="a.json.tmp is a symbolic link"):
        files.write_text(tmp_path / "a.json", "{}")
    with pytest.raises(RunDirError, match="b.csv is a symbolic link"):
        files.append_text(tmp_path / "b.csv", "1,2\n")
    with pytest.raises(RunDirError, match="c.lock is a symbolic link"):
        files.open_lock(tmp_path / "c.lock")
    assert victim.read_bytes() == b"keep\n"
    # a plain leftover temporary (a crash mid-write) is replaced; the write is whole
    (tmp_path / "d.json.tmp").write_text("half")
    files.write_text(tmp_path / "d.json", "{}")
    assert (tmp_path / "d.json").read_text() == "{}" and not (tmp_path / "d.json.tmp").exists()


@pytest.mark.parametrize(
    "record, why",
    [
        ("- init_from='$(touch pwned)'\n", "does not belong to this run"),
        ("- [unclosed\n", "invalid YAML"),
        ('- env=inverted_pendulum\n- "seed=0\\nrm -rf ~"\n', "not a command line's key=value override"),
        ("- hydra.run.dir=/etc\n", "never sets hydra.run.dir"),
        ("- resume=/elsewhere\n", "never sets resume"),
        ("env: ant\n", "should be a list"),
        ("- 12\n", "not a command line's key=value override"),
        ("- no_such_key=1\n", "cannot be composed"),
    ],
)
def test_a_replayed_command_line_is_checked_as_untrusted_input(saved_run, tmp_path, record, why):
    run_dir = _copy(saved_run, tmp_path / "run")
    (run_dir / ".hydra").mkdir(exist_ok=True)
    (run_dir / ".hydra" / "overrides.yaml").write_text(record)
    with pytest.raises(ConfigError, match=why):
        resumed_config(run_dir, [])


# ----------------------------------------------------------------------------- damaged files


def test_a_half_written_last_metrics_row_is_set_aside_and_the_run_continues(saved_run, tmp_path, capfd):
    run_dir = _copy(saved_run, tmp_path / "run")
    good = (run_dir / "metrics.csv").read_text()
    with (run_dir / "metrics.csv").open("a") as f:
        f.write("3.0,4.1,0.0,0")  # a crash mid-append: no line end
    out = _resume(run_dir)
    assert out["status"] == "done" and out["chunks"] == 4
    assert "damaged row(s)" in capfd.readouterr().err
    (aside,) = run_dir.glob("metrics.csv.damaged-*")
    assert aside.read_text() == "3.0,4.1,0.0,0\n"
    lines = (run_dir / "metrics.csv").read_text().splitlines()
    assert len(lines) == 1 + 4 and (run_dir / "metrics.csv").read_text().startswith(good)


@pytest.mark.parametrize("damage", ["null", "[1]", "{}"])
def test_damaged_checkpoint_metadata_falls_back_to_the_one_before(saved_run, tmp_path, damage, capfd):
    from fastrl.tools import evaluate

    run_dir = _copy(saved_run, tmp_path / "run")
    (run_dir / "checkpoints" / "2" / "meta" / "metadata").write_text(damage)
    assert evaluate.run([str(run_dir), "--episodes", "2"]) == 0
    out, err = capfd.readouterr()
    assert "at 256 env steps" in out and "using step 1 instead" in err and "metadata" in err


def test_a_checkpoint_of_an_earlier_layout_is_refused_naming_what_differs(saved_run, tmp_path):
    """Only checkpoints in the layout this fastrl saves are read: an earlier layout's metadata,
    config or state leaves are refused at once (no fallback to an older step of the same run),
    naming what differs, and its checkpoints are left as they were."""
    import jax
    import jax.numpy as jnp

    from fastrl.training import checkpoint
    from fastrl.training.policy import load_run

    run_dir = _copy(saved_run, tmp_path / "run")
    for meta in run_dir.glob("checkpoints/*/meta/metadata"):  # before time-sized chunks and evaluations
        saved = json.loads(meta.read_text())
        del saved["updates"], saved["eval_history"]
        meta.write_text(json.dumps(saved))
    before = sorted((p, p.stat().st_mtime_ns) for p in (run_dir / "checkpoints").rglob("*"))
    for attempt in (lambda: load_run(run_dir), lambda: _resume(run_dir)):
        with pytest.raises(
            checkpoint.EarlierLayout, match="checkpoints/2 lacks updates, eval_history: .*earlier layout"
        ):
            attempt()
    assert sorted((p, p.stat().st_mtime_ns) for p in (run_dir / "checkpoints").rglob("*")) == before
    # a config from before agent batches: the resume names the settings it lacks
    config = json.loads((run_dir / "config.json").read_text())
    del config["train"]["num_seeds"], config["train"]["vmap_sweep"]
    (run_dir / "config.json").write_text(json.dumps(config))
    with pytest.raises(
        checkpoint.EarlierLayout, match="lacks train.num_seeds, train.vmap_sweep: .*earlier layout"
    ):
        resumed_config(run_dir, [])
    # state leaves this fastrl's learner does not make (or lacks)
    target = {"['params']": jax.ShapeDtypeStruct((2,), jnp.float32)}
    saved_leaves = {"['params']": None, "['env_state'].metrics['old']": None}
    with pytest.raises(
        checkpoint.EarlierLayout, match=r"other state leaves.*metrics\['old'\]: .*earlier layout"
    ):
        checkpoint._check_leaves(target, saved_leaves, run_dir)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite_numbers_in_the_config_are_named(value):
    with pytest.raises(ConfigError, match=f"train.total_env_steps={value} should be a finite number"):
        typed([*QUICK, f"train.total_env_steps={value}"])
    with pytest.raises(ConfigError, match="algo.learning_rate=nan should be a finite number"):
        typed([*QUICK, "algo.learning_rate=nan"])


def test_a_missing_asset_file_is_a_config_error():
    with pytest.raises(ConfigError, match="/nonexistent.xml does not exist"):
        typed([*QUICK, "+env.options.asset=/nonexistent.xml"]).env.make()


@pytest.mark.parametrize("damage", [lambda t: t[:100], lambda t: "null"])
def test_a_damaged_config_json_resumes_with_the_checkpoints_config_on_the_same_devices(tmp_path, damage):
    # Read as plain JSON, the checkpoint's config leaves the device count free to choose: the run
    # trained on 2 CPU devices resumes on 2 (reading it through JAX would start JAX on 1).
    run_dir = tmp_path / "r"
    cli = [sys.executable, "-m", "fastrl.train"]
    two = _env(FASTRL_CPU_DEVICES="2")
    args = [*QUICK_CLI, f"hydra.run.dir={run_dir}", "train.stop_after_chunks=1"]
    subprocess.run([*cli, *args], cwd=tmp_path, env=two, check=True, capture_output=True, timeout=300)
    config = run_dir / "config.json"
    config.write_text(damage(config.read_text()))
    out = subprocess.run([*cli, f"resume={run_dir}"], cwd=tmp_path, env=two, capture_output=True, text=True,
                         timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "config.json is damaged; using the copy in" in out.stderr
    assert "on 2 cpu devices" in out.stdout and "resumed" in out.stdout


# ----------------------------------------------------------------------------- signals


def test_sigterm_stops_after_the_chunk_saves_and_resumes_bit_for_bit(tmp_path, capsys):
    class Terminate(Callback):
        def on_chunk(self, run, chunk):
            if chunk.index == 1:
                os.kill(os.getpid(), signal.SIGTERM)

    split, full = tmp_path / "split", tmp_path / "full"
    handler = signal.getsignal(signal.SIGTERM)
    out = runner.train(typed(QUICK_RESUME), split, callbacks=[Evaluation(), Terminate()])
    assert out["status"] == "stopped" and out["chunks"] == 1 and out["signal"] == signal.SIGTERM
    said = capsys.readouterr().out
    assert "stopped by SIGTERM after chunk 1 of 4, checkpoint saved" in said
    assert f"continue with: python -m fastrl.train resume={split}" in said
    assert signal.getsignal(signal.SIGTERM) is handler  # the run's handler is taken away again
    assert _resume_quick(split)["chunks"] == 4
    run(compose_cfg([*QUICK_RESUME, f"run_dir={full}"]))
    for x, y in zip(_weights_of(full), _weights_of(split), strict=True):
        np.testing.assert_array_equal(x, y)


def _resume_quick(run_dir: Path) -> dict:
    return run(compose_cfg([*QUICK_RESUME, f"run_dir={run_dir}/unused", f"resume={run_dir}"]))


def test_a_second_signal_waits_for_a_save_in_flight_and_aborts_otherwise():
    with StopFlag() as stop:
        os.kill(os.getpid(), signal.SIGHUP)
        assert stop.set and stop.name == "SIGHUP"
        with stop.saving():
            os.kill(os.getpid(), signal.SIGTERM)  # held back: the save completes
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)


def _start(run_dir: Path, cwd: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "fastrl.train", *LONG_CLI, f"hydra.run.dir={run_dir}"]
    return subprocess.Popen(cmd, cwd=cwd, env=_env(FASTRL_CPU_DEVICES="1"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


def _wait_for_checkpoint(proc: subprocess.Popen, run_dir: Path, step: int) -> None:
    deadline = time.monotonic() + 240
    while not (run_dir / "checkpoints" / str(step)).is_dir():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run never saved"
        time.sleep(0.05)


def test_sigterm_to_the_command_line_exits_143_with_a_checkpoint_and_the_resume_command(tmp_path):
    run_dir = tmp_path / "r"
    proc = _start(run_dir, tmp_path)
    _wait_for_checkpoint(proc, run_dir, 1)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "SIGTERM: stopping after this chunk" in err and "Traceback" not in err
    assert f"continue with: python -m fastrl.train resume={run_dir}" in out
    ckpt = Checkpointer(run_dir / "checkpoints")
    try:
        step, meta = ckpt.read_meta()
    finally:
        ckpt.close()
    rows = (run_dir / "metrics.csv").read_text().splitlines()
    assert step == meta["chunk"] == len(rows) - 1 < 40  # saved at the chunk it stopped after
    assert not list((run_dir / "checkpoints").glob("*tmp*"))


# ----------------------------------------------------------------------------- failed writes


def test_a_failed_write_ends_the_run_at_once_with_one_line_and_loses_nothing(tmp_path):
    # The run's file size limit drops to 0 mid-run: every write that grows a file fails, as on a
    # full disk. The run must end promptly with one named error, keep its earlier checkpoints and
    # outputs whole, and resume once writes work again.
    run_dir = tmp_path / "r"
    proc = _start(run_dir, tmp_path)
    _wait_for_checkpoint(proc, run_dir, 3)
    resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (0, 0))
    t = time.monotonic()
    out, err = proc.communicate(timeout=120)
    assert time.monotonic() - t < 60
    assert proc.returncode == 74, err
    errors = [line for line in err.splitlines() if line.startswith("[fastrl] error:")]
    assert (
        len(errors) == 1 and "File too large" in errors[0] and "the last good checkpoint is" in errors[0]
    ), err
    assert f"resume={run_dir}" in errors[0]
    assert "Traceback" not in err and len(err.splitlines()) < 10, err
    for p in run_dir.rglob("*"):  # nothing half-written: no empty curve, no cut csv row
        assert not (p.is_file() and p.suffix in (".png", ".json", ".csv") and p.stat().st_size == 0), p
    assert (run_dir / "metrics.csv").read_text().endswith("\n")
    cmd = [sys.executable, "-m", "fastrl.train", f"resume={run_dir}", "train.total_env_steps=2560"]
    done = subprocess.run(cmd, cwd=tmp_path, env=_env(FASTRL_CPU_DEVICES="1"), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "resumed" in done.stdout and "damaged" not in done.stderr
    # a partial save that orbax's writer threads left behind is tidied by the run that owns the folder
    assert not list((run_dir / "checkpoints").glob("*tmp*"))


def test_interleaved_closed_loop_tracebacks_are_dropped_and_nothing_else():
    from fastrl.training.checkpoint import _drop_loop_closed

    frame = '  File "/x/asyncio/base_events.py", line 806, in call_soon\n    self._check_closed()\n'
    noise = (
        f"Traceback (most recent call last):\n{frame}RuntimeErrorTraceback (most recent call last):\n"
        f": Event loop is closed\n\n{frame}RuntimeError: Event loop is closed\n"
    )
    kept = "[fastrl] warning: something the user must see\nValueError: a real error\n"
    assert _drop_loop_closed(noise + kept) == kept
    assert _drop_loop_closed(kept + "\n") == kept + "\n"  # no noise: the text as it was


def test_a_failed_saves_late_writer_tracebacks_never_reach_stderr(tmp_path, capfd):
    """The writers of a failed save go on failing in their own threads, each printing an "Event
    loop is closed" traceback straight to the stderr descriptor; however they are timed against
    the save's failure, none reaches stderr, and what fastrl itself prints meanwhile does."""
    import os
    import threading
    import time

    from fastrl.training.checkpoint import Checkpointer, WriteError

    noise = (
        b'Traceback (most recent call last):\n  File "/x/asyncio/base_events.py", line 806, in '
        b"call_soon_threadsafe\n    self._check_closed()\nRuntimeError: Event loop is closed\n"
    )
    ckpt = Checkpointer(tmp_path / "checkpoints")
    done = threading.Event()

    def writers():  # tracebacks written on and on, across the save's failure and after it
        while not done.is_set():
            os.write(2, noise)
            time.sleep(0.0002)

    class FailingManager:
        def save(self, *args, **kwargs):
            threading.Thread(target=writers, daemon=True).start()
            time.sleep(0.05)
            raise OSError(28, "No space left on device")

        def wait_until_finished(self):
            time.sleep(0.05)

        def close(self):
            done.set()
            time.sleep(0.01)

    real, ckpt._manager = ckpt._manager, FailingManager()
    with pytest.raises(WriteError, match="No space left on device"):
        ckpt.save(1, {"x": np.zeros(2)}, {"config": {}, "env_steps": 0})
    print("[fastrl] warning: a line the user must see", file=sys.stderr, flush=True)
    ckpt.close()
    real.close()
    err = capfd.readouterr().err
    assert "Event loop is closed" not in err and "Traceback" not in err, err[:500]
    assert "a line the user must see" in err
