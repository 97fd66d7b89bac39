"""The training configuration's Hydra side: ``conf/`` (``CONF_DIR``), the dataclasses' and envs'
defaults stored as the configs it extends (``register_defaults``, done on import), and the
composition of a command line into a resolved config (``compose_container``)."""

from __future__ import annotations

from pathlib import Path

from hydra.core.config_store import ConfigStore
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from fastrl import agents, envs
from fastrl.training.config import SECTIONS, ConfigError, RunConfig, defaults

__all__ = [
    "CONF_DIR",
    "LAUNCH_KEYS",
    "compose_container",
    "merge_overrides",
    "override_key",
    "register_defaults",
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
LAUNCH_KEYS = ("resume", "resume_step", "run_dir", "distributed")


def override_key(override: str) -> str:
    """The config key a ``key=value`` override sets (without Hydra's ``+``/``~`` prefixes)."""
    return override.split("=", 1)[0].lstrip("+~")


def merge_overrides(saved: list[str], new: list[str]) -> list[str]:
    """``saved`` then ``new`` command-line overrides, a later one replacing an earlier one of the
    same key (``env=...``, ``algo.learning_rate=...``); launch keys (``resume`` ...) dropped."""
    out: dict[str, str] = {}
    for o in [*saved, *new]:
        key = override_key(o)
        if key not in LAUNCH_KEYS:
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
    for key in LAUNCH_KEYS:
        container.pop(key, None)
    return container
