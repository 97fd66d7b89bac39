"""``python -m fastrl.train env=ant algo=ppo [key=value ...]``: the training front door.

Hydra composes ``conf/`` (see conf/train.yaml); this module turns the result into a typed
``RunConfig`` (failing before any compilation on a bad value) and hands it to the runner, with
the callbacks that look at the run (``fastrl.tools.callbacks.standard()``: viewer pages, the
physics note, learning curves).
``resume=PATH`` continues a given run with its own saved command line (further ``key=value``
arguments apply on top; ``resume_step=N`` picks a checkpoint), ``resume=true`` the run in
``hydra.run.dir`` or else the latest run of the same env/algo.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import signal
import sys
from pathlib import Path

import hydra
import jax
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from fastrl import agents, envs
from fastrl.runtime import compile_cache, xla_flags
from fastrl.tools import callbacks
from fastrl.training import files, layout, runner
from fastrl.training.checkpoint import CHECKPOINT_DIR, CheckpointError
from fastrl.training.config import SECTIONS, ConfigError, RunConfig, defaults, identity_diff
from fastrl.training.files import WriteError

__all__ = [
    "CONF_DIR",
    "OVERRIDES_FILE",
    "compose_container",
    "cpu_devices",
    "find_resume_dir",
    "init_distributed",
    "main",
    "merge_overrides",
    "register_defaults",
    "resumed_config",
    "run",
]

CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")


def register_defaults() -> None:
    """Stores the config dataclasses' defaults in Hydra's ConfigStore, as the configs that
    conf/ extends: ``dataclass/<section>`` (``dataclass/run``: ``seed``, ``init_from``) and
    ``dataclass/algo/<learner>``; and the ``env`` group, one option per registered env (its
    name and options, ``envs.options``). A default is written once, in its dataclass or
    constructor; a conf/ file holds only what differs, and every key stays overridable as
    ``section.key=value``."""
    store = ConfigStore.instance()
    for name in envs.names():
        store.store(group="env", name=name, node={"name": name, "options": envs.options(name)})
    store.store(group="dataclass", name="run", node=defaults(RunConfig))
    named = {"name": "???"}  # Hydra's mandatory value: the file that extends it names the env or learner
    for section, cls in SECTIONS.items():
        node = {**named, **defaults(cls)} if section == "env" else defaults(cls)
        store.store(group="dataclass", name=section, node=node)
    for name in agents.ALGORITHMS:
        store.store(group="dataclass/algo", name=name, node={**named, **defaults(agents.config_class(name))})


# Done on import, as conf/ cannot be composed without it (importing CONF_DIR brings it along).
register_defaults()

# Command-line keys that say how to start, not what the run is: never part of a run's record.
_LAUNCH_KEYS = ("resume", "resume_step", "run_dir", "distributed")
OVERRIDES_FILE = ".hydra/overrides.yaml"
# The exit status of a run ended by a failed write (a full disk, a read-only folder): EX_IOERR.
EXIT_WRITE_FAILED = 74


def find_resume_dir(resume, runs_root: Path, current: Path) -> Path | None:
    """The run folder to continue: None (a new run), a given path, or for ``resume=true`` the
    current run folder when it holds checkpoints (``hydra.run.dir=X resume=true``), else the
    newest run with checkpoints under ``runs_root`` (the env/algo's folder of runs)."""
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        if _has_checkpoints(current):
            return current
        candidates = [
            p.parent.parent
            for p in runs_root.glob(f"*/{CHECKPOINT_DIR}/*")
            if p.is_dir() and p.name.isdigit()
        ]
        if not candidates:
            raise CheckpointError(f"resume=true but no run with checkpoints under {runs_root}")
        return max(candidates, key=lambda p: (p / CHECKPOINT_DIR).stat().st_mtime)
    path = Path(str(resume)).expanduser()
    if not (path / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"resume={resume}: {path} is not a run folder (no {CHECKPOINT_DIR}/ inside)")
    return path


def _has_checkpoints(run_dir: Path) -> bool:
    ckpts = run_dir / CHECKPOINT_DIR
    return ckpts.is_dir() and any(p.is_dir() and p.name.isdigit() for p in ckpts.iterdir())


def _override_key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def merge_overrides(saved: list[str], new: list[str]) -> list[str]:
    """``saved`` then ``new`` command-line overrides, a later one replacing an earlier one of the
    same key (``env=...``, ``algo.learning_rate=...``); launch keys (``resume`` ...) dropped."""
    out: dict[str, str] = {}
    for o in [*saved, *new]:
        key = _override_key(o)
        if key not in _LAUNCH_KEYS:
            out.pop(key, None)
            out[key] = o
    return list(out.values())


def compose_container(overrides: list[str]) -> dict:
    """The resolved config of ``conf/train.yaml`` under ``overrides``, without launch keys."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    overrides = [*overrides, "run_dir=/unused"]
    try:
        if GlobalHydra.instance().is_initialized():  # inside the command-line app
            cfg = compose("train", overrides=overrides)
        else:
            with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
                cfg = compose("train", overrides=overrides)
    except (HydraException, OmegaConfBaseException) as e:  # a recorded line replayed on resume
        raise ConfigError(f"the command line {overrides[:-1]} cannot be composed: {e}") from None
    container = OmegaConf.to_container(cfg, resolve=True)
    for key in _LAUNCH_KEYS:
        container.pop(key, None)
    return container


def resumed_config(run_dir: Path, overrides: list[str]) -> tuple[dict, list[str]]:
    """The config a resumed run continues with, and its command line, from the run's own record.

    ``overrides`` (the resume command's own ``key=value`` arguments) are applied on top of the
    run's saved command line (``.hydra/overrides.yaml``), so ``resume=RUN_DIR`` alone continues
    the run as it was started, and ``resume=RUN_DIR train.total_env_steps=2e7`` extends it. A run
    without a saved command line (started from Python) continues from its saved config with
    dotted overrides applied. Raises ``ConfigError`` naming each identity setting (env, algo,
    network, seed, agent batch) that the overrides would change.
    """
    saved = _saved_config(run_dir)
    record = run_dir / OVERRIDES_FILE
    if record.is_file():
        line = merge_overrides(_saved_command_line(record, saved), overrides)
        container = compose_container(line)
    else:
        line = merge_overrides([], overrides)
        container = OmegaConf.create(saved)
        for o in line:
            key, _, value = o.partition("=")
            key = key.lstrip("+")
            if OmegaConf.select(container, key, default=None) is None and "." not in key:
                raise ConfigError(
                    f"{run_dir} has no saved command line ({OVERRIDES_FILE}), so {o!r} cannot be applied "
                    "to it; resume it with dotted keys only, e.g. train.total_env_steps=..."
                )
            OmegaConf.update(container, key, _yaml_value(value), merge=False)
        container = OmegaConf.to_container(container, resolve=True)
    diffs = identity_diff(saved, RunConfig.from_dict(container).to_dict())
    if diffs:
        raise ConfigError(
            f"resume={run_dir}: the command line changes what the run is; resume it without these "
            "overrides, or start a new run. Differences (saved -> asked):\n  " + "\n  ".join(diffs)
        )
    return container, line


def _saved_config(run_dir: Path) -> dict:
    """The run's config: its ``config.json`` (written only once a run is valid); when that is
    damaged, the copy in the newest checkpoint that holds a readable one. Both are read as plain
    JSON files, without starting JAX, so that the CPU device count can still be chosen."""
    path = run_dir / "config.json"
    config = _json_object(path)
    if config is not None:
        return config
    steps = [p for p in (run_dir / CHECKPOINT_DIR).iterdir() if p.name.isdigit()]
    for step in sorted(steps, key=lambda p: -int(p.name)):
        meta = _json_object(step / "meta" / "metadata")
        if meta is not None and isinstance(meta.get("config"), dict):
            if path.exists():
                print(f"[fastrl] warning: {path} is damaged; using the copy in {step}", file=sys.stderr)
            return meta["config"]
    raise ConfigError(f"{run_dir} holds no readable config: neither config.json nor a checkpoint's")


def _json_object(path: Path) -> dict | None:
    """The JSON object in ``path``; None when the file is missing, unreadable, or not an object."""
    try:
        value = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return value if isinstance(value, dict) else None


# What a recorded command line may hold: ``key=value`` with a dotted config key (``+`` / ``~``
# prefixes as Hydra allows), and a value of printable characters.
_OVERRIDE = re.compile(r"[+~]{0,2}[A-Za-z_]\w*(\.\w+)*(@[\w.]+)?(=[^\x00-\x1f\x7f]*)?", re.ASCII)


def _saved_command_line(record: Path, saved: dict) -> list[str]:
    """The command line a run folder recorded, checked as untrusted input: a YAML list of
    ``key=value`` strings with config keys, no launch or Hydra keys, and an ``init_from`` that
    the run's own config holds (a resume never starts from other weights). Raises
    ``ConfigError`` naming the record and the offending entry."""
    try:
        line = OmegaConf.to_container(OmegaConf.load(record)) or []
    except Exception as e:  # YAML's and OmegaConf's parse errors have many types
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"{record} cannot be read (invalid YAML: {first}); restore or remove it") from None
    if not isinstance(line, list):
        raise ConfigError(f"{record} should be a list of key=value overrides, not {type(line).__name__}")
    for entry in line:
        if not isinstance(entry, str) or not _OVERRIDE.fullmatch(entry) or len(entry) > 4096:
            raise ConfigError(f"{record} holds {entry!r}, which is not a command line's key=value override")
        key = _override_key(entry)
        if key in _LAUNCH_KEYS or key.split(".")[0] == "hydra":
            raise ConfigError(f"{record} holds {entry!r}: a run's recorded command line never sets {key}")
        if key == "init_from" and _yaml_value(entry.partition("=")[2]) != saved.get("init_from"):
            raise ConfigError(
                f"{record} holds {entry!r}, but the run's config says init_from="
                f"{saved.get('init_from')!r}: the record does not belong to this run"
            )
    return line


def _yaml_value(text: str):
    """A command-line value as Hydra reads it (numbers, booleans, lists, null)."""
    return OmegaConf.create({"v": text})["v"] if text else text


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
    if leftovers <= {"train.log", ".lock", CHECKPOINT_DIR} and not _has_checkpoints(output_dir):
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
