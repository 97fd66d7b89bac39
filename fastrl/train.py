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

from fastrl import runner
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


def run(cfg: DictConfig) -> dict:
    """Runs the composed config (also used in-process by tests)."""
    container = OmegaConf.to_container(cfg, resolve=True)
    container.pop("hydra", None)
    resume = container.pop("resume", False)
    if container.pop("distributed", False):
        init_distributed()
    run_dir = Path(container.pop("run_dir"))
    rc = RunConfig.from_dict(container)
    target = find_resume_dir(resume, run_dir.parent, run_dir)
    if target is not None:
        run_dir = target
    return runner.train(rc, run_dir, resume=target is not None)


@hydra.main(version_base=None, config_path=CONF_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    try:
        summary = run(cfg)
    except (ConfigError, CheckpointError) as e:
        print(f"[fastrl] error: {e}", file=sys.stderr)
        sys.exit(2)
    if summary["status"] == "diverged":
        sys.exit(1)
    # The return value lets Hydra sweepers (Optuna) maximise the final evaluation return.
    return summary["last"].get("eval/episode_return")


if __name__ == "__main__":
    main()
