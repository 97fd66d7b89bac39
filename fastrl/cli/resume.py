"""Resuming a run from its folder: which folder (``find_resume_dir``), and the config it
continues with, from its own record of itself (``resumed_config``), each file of which is read as
untrusted input."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from omegaconf import OmegaConf

from fastrl.cli.conf import LAUNCH_KEYS, compose_container, merge_overrides, override_key
from fastrl.training.checkpoint import CHECKPOINT_DIR, CheckpointError, EarlierLayout
from fastrl.training.config import ConfigError, RunConfig, identity_diff, missing_identity_keys

__all__ = ["OVERRIDES_FILE", "find_resume_dir", "has_checkpoints", "resumed_config", "yaml_value"]

OVERRIDES_FILE = ".hydra/overrides.yaml"


def find_resume_dir(resume, runs_root: Path, current: Path) -> Path | None:
    """The run folder to continue: None (a new run), a given path, or for ``resume=true`` the
    current run folder when it holds checkpoints (``hydra.run.dir=X resume=true``), else the
    newest run with checkpoints under ``runs_root`` (the env/algo's folder of runs)."""
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        if has_checkpoints(current):
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


def has_checkpoints(run_dir: Path) -> bool:
    ckpts = run_dir / CHECKPOINT_DIR
    return ckpts.is_dir() and any(p.is_dir() and p.name.isdigit() for p in ckpts.iterdir())


def resumed_config(run_dir: Path, overrides: list[str]) -> tuple[dict, list[str]]:
    """The config a resumed run continues with, and its command line, from the run's own record.

    ``overrides`` (the resume command's own ``key=value`` arguments) are applied on top of the
    run's saved command line (``.hydra/overrides.yaml``), so ``resume=RUN_DIR`` alone continues
    the run as it was started, and ``resume=RUN_DIR train.total_env_steps=2e7`` extends it. A run
    without a saved command line (started from Python) continues from its saved config with
    dotted overrides applied. Raises ``ConfigError`` naming each identity setting (env, algo,
    network, seed, agent batch) that the overrides would change, and ``EarlierLayout`` naming
    those a saved config of an earlier layout lacks.
    """
    saved = _saved_config(run_dir)
    if missing := missing_identity_keys(saved):
        raise EarlierLayout(f"{run_dir}'s config lacks {', '.join(missing)}: {EarlierLayout.hint}")
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
            OmegaConf.update(container, key, yaml_value(value), merge=False)
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
        key = override_key(entry)
        if key in LAUNCH_KEYS or key.split(".")[0] == "hydra":
            raise ConfigError(f"{record} holds {entry!r}: a run's recorded command line never sets {key}")
        if key == "init_from" and yaml_value(entry.partition("=")[2]) != saved.get("init_from"):
            raise ConfigError(
                f"{record} holds {entry!r}, but the run's config says init_from="
                f"{saved.get('init_from')!r}: the record does not belong to this run"
            )
    return line


def yaml_value(text: str):
    """A command-line value as Hydra reads it (numbers, booleans, lists, null)."""
    return OmegaConf.create({"v": text})["v"] if text else text
