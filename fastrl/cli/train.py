"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training front door.

Hydra composes ``conf/`` (see conf/train.yaml and ``fastrl.cli.conf``); this module turns the
result into a typed ``RunConfig`` (failing before any compilation on a bad value), sets the CPU
devices and XLA flags, and hands it to the runner with the command line's callbacks
(``fastrl.tools.callbacks.standard()``: the evaluation, the physics note, viewer pages,
learning curves).
``resume=PATH`` continues a given run with its own saved command line (further ``key=value``
arguments apply on top; ``resume_step=N`` picks a checkpoint), ``resume=true`` the run in
``hydra.run.dir`` or else the latest run of the same env/algo (``fastrl.cli.resume``).
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import sys
from pathlib import Path

import hydra
import jax
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from fastrl.cli.conf import CONF_DIR, merge_overrides
from fastrl.cli.resume import OVERRIDES_FILE, find_resume_dir, has_checkpoints, resumed_config
from fastrl.runtime import compile_cache, xla_flags
from fastrl.tools import callbacks
from fastrl.training import files, layout, runner
from fastrl.training.checkpoint import CHECKPOINT_DIR, CheckpointError
from fastrl.training.config import ConfigError, RunConfig
from fastrl.training.files import WriteError

__all__ = ["cpu_devices", "init_distributed", "main", "run"]

# The exit status of a run ended by a failed write (a full disk, a read-only folder): EX_IOERR.
EXIT_WRITE_FAILED = 74


def init_distributed() -> None:
    """``jax.distributed.initialize`` for a multi-host run (one process per host).

    Slurm, Open MPI and Cloud TPU launches are detected by JAX itself; elsewhere set
    ``FASTRL_COORDINATOR`` (host:port of process 0), ``FASTRL_NUM_PROCESSES`` and
    ``FASTRL_PROCESS_ID`` in each process's environment.
    """
    if "FASTRL_COORDINATOR" in os.environ:
        try:
            jax.distributed.initialize(
                coordinator_address=os.environ["FASTRL_COORDINATOR"],
                num_processes=int(os.environ["FASTRL_NUM_PROCESSES"]),
                process_id=int(os.environ["FASTRL_PROCESS_ID"]),
            )
        except (KeyError, ValueError) as e:
            raise ConfigError(
                "distributed=true with FASTRL_COORDINATOR set also needs integer FASTRL_NUM_PROCESSES "
                f"and FASTRL_PROCESS_ID ({type(e).__name__}: {e})"
            ) from None
    else:
        jax.distributed.initialize()


def cpu_devices(rc: RunConfig, cores: int) -> int:
    """How many XLA CPU devices to give a run on a host with ``cores`` cores: the layout's
    choice (``fastrl.training.layout.cpu_devices``), unless ``FASTRL_CPU_DEVICES=N`` says."""
    if "FASTRL_CPU_DEVICES" in os.environ:
        value = os.environ["FASTRL_CPU_DEVICES"]
        if not value.isdigit() or int(value) < 1:
            raise ConfigError(f"FASTRL_CPU_DEVICES={value!r} should be a positive integer")
        return int(value)
    return layout.cpu_devices(rc, cores)


def _set_cpu_flags(rc: RunConfig) -> None:
    """Sets the CPU device count (``cpu_devices``) and fastrl's XLA:CPU flags for this learner
    (``xla_flags.apply``) while JAX has not started a backend yet. Whatever the user's
    ``XLA_FLAGS`` sets, the device count included, is left as it is."""
    named = xla_flags.names(os.environ.get("XLA_FLAGS", ""))
    devices = None if xla_flags.DEVICE_FLAG in named else cpu_devices(rc, len(os.sched_getaffinity(0)))
    xla_flags.apply(devices, rc.algo_name)


def run(cfg: DictConfig, split_cpu: bool = False, overrides: list[str] | None = None) -> dict:
    """Runs the composed config (also used in-process by tests).

    ``split_cpu``: set the CPU device count and XLA:CPU flags first (``_set_cpu_flags``); the
    command line does, in-process callers keep the devices their process already has.
    ``overrides``: the command line's ``key=value`` arguments (Hydra's task overrides). A new
    run records them in ``RUN_DIR/.hydra/``; a resumed run applies them on top of its own
    record (``resumed_config``). Without them a resumed run takes ``cfg`` as given.
    """
    container = OmegaConf.to_container(cfg, resolve=True)
    container.pop("hydra", None)
    resume = container.pop("resume", False)
    resume_step = container.pop("resume_step", None)
    if container.pop("distributed", False):
        init_distributed()
    run_dir = Path(container.pop("run_dir"))
    target = find_resume_dir(resume, run_dir.parent, run_dir)
    if target is None and resume_step is not None:
        raise ConfigError("resume_step=N picks the checkpoint to continue from: use it with resume=PATH")
    line = merge_overrides([], overrides or [])
    if target is not None:
        files.refuse_links(target)  # before anything in it is read, let alone replayed
    if target is not None and overrides is not None:
        container, line = resumed_config(target, overrides)
    rc = RunConfig.from_dict(container)
    if split_cpu:
        _set_cpu_flags(rc)
    record = {}
    if overrides is not None:
        record = {
            OVERRIDES_FILE: OmegaConf.to_yaml(line),
            ".hydra/config.yaml": OmegaConf.to_yaml(rc.to_dict()),
        }
    return runner.train(
        rc,
        target or run_dir,
        resume=target is not None,
        resume_step=resume_step,
        record=record,
        callbacks=callbacks.standard(),
    )


def _discard_unused(output_dir: Path, used: Path | None) -> None:
    """Removes the folder Hydra made for this command when the command did not use it (a resume
    of another run, or a rejected start) and it holds nothing but Hydra's log of this command."""
    if used is not None and output_dir.absolute() == used.absolute():
        return
    if not output_dir.is_dir():
        return
    leftovers = {p.name for p in output_dir.iterdir()}
    if leftovers <= {"train.log", ".lock", CHECKPOINT_DIR} and not has_checkpoints(output_dir):
        shutil.rmtree(output_dir, ignore_errors=True)
        for parent in output_dir.parents[:2]:  # runs/<env>-<algo>/ and runs/, when left empty
            try:
                parent.rmdir()
            except OSError:
                break


@hydra.main(version_base=None, config_path=CONF_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    hc = HydraConfig.get()
    output_dir = Path(hc.runtime.output_dir)
    logging.raiseExceptions = False  # a full disk under train.log must not print a traceback per line
    summary = None
    if not compile_cache.is_enabled():  # a cache the user set (JAX_COMPILATION_CACHE_DIR) is kept
        compile_cache.enable()  # FASTRL_COMPILE_CACHE= (empty) turns it off
    failed = None
    try:
        summary = run(cfg, split_cpu=True, overrides=list(hc.overrides.task))
    except (ConfigError, CheckpointError, files.RunDirError) as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        sys.exit(2)
    except WriteError as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        failed = EXIT_WRITE_FAILED
    except KeyboardInterrupt:
        print(
            "[fastrl] stopped at once by a second signal; the last checkpoint saved is kept", file=sys.stderr
        )
        sys.exit(130)
    finally:
        logging.shutdown()  # Hydra's log file is closed before its folder may be removed
        _discard_unused(output_dir, Path(summary["run_dir"]) if summary else None)
    if failed is not None:
        # After a failed write orbax's writer threads can wait minutes on their own timeouts, and
        # a normal exit joins them: end the process now (the error is said, the files closed).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(failed)
    if summary["status"] == "diverged":
        sys.exit(1)
    if summary["interrupted"]:  # the checkpoint is saved and the hint printed
        sys.exit(128 + (summary["signal"] or signal.SIGINT))  # the shell's code: 130 Ctrl-C, 143 SIGTERM
    # The return value lets Hydra sweepers (Optuna) maximise the final evaluation return.
    return summary["last"].get("eval/episode_return")


if __name__ == "__main__":
    main()
