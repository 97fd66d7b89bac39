"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training front door.

Hydra composes ``conf/`` (see conf/train.yaml); this module turns the result into a typed
``RunConfig`` (failing before any compilation on a bad value) and hands it to the runner.
``resume=true`` continues the latest run of the same env/algo, ``resume=PATH`` a given run.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from fastrl import agents, runner, xla_flags
from fastrl.checkpoint import CheckpointError
from fastrl.config import ConfigError, RunConfig

CONF_DIR = str(Path(__file__).resolve().parent.parent / "conf")


def find_resume_dir(resume, runs_root: Path, current: Path) -> Path | None:
    """The run folder to continue: None (new run), the latest of ``runs_root``, or a path."""
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        candidates = [
            p.parent.parent
            for p in runs_root.glob(f"*/{runner.CHECKPOINT_DIR}/*")
            if p.is_dir() and p.name.isdigit() and p.parent.parent != current
        ]
        if not candidates:
            raise CheckpointError(f"resume=true but no run with checkpoints under {runs_root}")
        return max(candidates, key=lambda p: (p / runner.CHECKPOINT_DIR).stat().st_mtime)
    path = Path(str(resume)).expanduser()
    if not (path / runner.CHECKPOINT_DIR).is_dir():
        raise CheckpointError(
            f"resume={resume}: {path} is not a run folder (no {runner.CHECKPOINT_DIR}/ inside)"
        )
    return path


def init_distributed() -> None:
    """``jax.distributed.initialize`` for a multi-host run (one process per host).

    Slurm, Open MPI and Cloud TPU launches are detected by JAX itself; elsewhere set
    ``FASTRL_COORDINATOR`` (host:port of process 0), ``FASTRL_NUM_PROCESSES`` and
    ``FASTRL_PROCESS_ID`` in each process's environment.
    """
    import jax

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
    """How many XLA CPU devices to give a run on a host with ``cores`` cores.

    XLA:CPU runs one program's operations on a thread pool, but the physics step is thousands
    of small fused loops that keep only about 1.45 of 2 cores busy (the Ant's step at batch
    1024); split over 2 devices, each device's copy runs on its own core (2.07x one core).
    Learners that split their own work (PPO: env slices and minibatch halves, see
    ``scale.learner_splits``) get one device per core, as many as divide the env batch and the
    minibatch; others, and agent batches, keep one device (XLA's automatic layout ran PPO's
    gradients in full on each device, so it would not be faster). ``FASTRL_CPU_DEVICES=N``
    overrides, and an ``XLA_FLAGS`` that sets the device count is left alone.
    """
    if "FASTRL_CPU_DEVICES" in os.environ:
        value = os.environ["FASTRL_CPU_DEVICES"]
        if not value.isdigit() or int(value) < 1:
            raise ConfigError(f"FASTRL_CPU_DEVICES={value!r} should be a positive integer")
        return int(value)
    if rc.train.num_seeds > 1 or rc.train.vmap_sweep or not agents.splits_over_devices(rc.algo_name):
        return 1
    n = max(1, cores)
    while not rc.algo.splits_evenly(n):
        n -= 1
    return n


def _set_cpu_flags(rc: RunConfig) -> None:
    """Sets the CPU device count (``cpu_devices``) and fastrl's XLA:CPU flags for this learner
    (``xla_flags.apply``) while JAX has not started a backend yet. Whatever the user's
    ``XLA_FLAGS`` sets is left as it is."""
    named = xla_flags.names(os.environ.get("XLA_FLAGS", ""))
    devices = None if xla_flags.DEVICE_FLAG in named else cpu_devices(rc, len(os.sched_getaffinity(0)))
    xla_flags.apply(devices, rc.algo_name)


def run(cfg: DictConfig, split_cpu: bool = False) -> dict:
    """Runs the composed config (also used in-process by tests).

    ``split_cpu``: set the CPU device count and XLA:CPU flags first (``_set_cpu_flags``); the
    command line does,
    in-process callers keep the devices their process already has.
    """
    container = OmegaConf.to_container(cfg, resolve=True)
    container.pop("hydra", None)
    resume = container.pop("resume", False)
    if container.pop("distributed", False):
        init_distributed()
    run_dir = Path(container.pop("run_dir"))
    rc = RunConfig.from_dict(container)
    if split_cpu:
        _set_cpu_flags(rc)
    target = find_resume_dir(resume, run_dir.parent, run_dir)
    if target is not None:
        run_dir = target
    return runner.train(rc, run_dir, resume=target is not None)


@hydra.main(version_base=None, config_path=CONF_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    try:
        summary = run(cfg, split_cpu=True)
    except (ConfigError, CheckpointError) as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        sys.exit(2)
    if summary["status"] == "diverged":
        sys.exit(1)
    # The return value lets Hydra sweepers (Optuna) maximise the final evaluation return.
    return summary["last"].get("eval/episode_return")


if __name__ == "__main__":
    main()
