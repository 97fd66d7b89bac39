"""conf/ holds only what differs from the config dataclasses and the envs' constructors, whose
defaults are the only ones."""

import dataclasses
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from fastrl import agents, envs
from fastrl.cli.conf import CONF_DIR
from fastrl.training.config import SECTIONS, RunConfig, defaults

CONF = Path(CONF_DIR)
GROUPS = (*SECTIONS, "algo")  # a file in conf/<group>/ is that section of the config
# Experiments pin their tuned settings: a value there that equals today's default is a choice
# the experiment was measured with, and must not follow a later change of the default.
PINNED = ("experiment",)


def _algo_class(section: dict, path: Path):
    """The learner's config class: the section's ``name``, else the file name's last word
    (``algo/<name>``, ``debug_algo/quick_<name>``, ``experiment/<env>_<name>``)."""
    name = section.get("name") or path.stem.rsplit("_", 1)[-1]
    return agents.config_class(name)


def _sections(path: Path):
    """(section, dataclass, mapping) for each part of ``path`` that a config dataclass types."""
    conf = OmegaConf.to_container(OmegaConf.load(path)) or {}
    conf.pop("defaults", None)
    group = path.parent.relative_to(CONF).as_posix()
    if group in GROUPS:  # the file is the section itself
        conf = {group: conf}
    elif group == ".":  # the primary config: seed, init_from at the top, sections below
        yield "", RunConfig, {k: v for k, v in conf.items() if k in defaults(RunConfig)}
    for section, values in conf.items():
        if section in SECTIONS:
            yield section, SECTIONS[section], values
        elif section == "algo":
            yield section, _algo_class(values, path), values


def _files():
    return sorted(CONF.rglob("*.yaml"))


@pytest.mark.parametrize("path", _files(), ids=lambda p: p.relative_to(CONF).as_posix())
def test_conf_files_set_only_fields_and_repeat_no_default(path):
    pinned = path.parent.name in PINNED
    for section, cls, values in _sections(path):
        fields = {f.name for f in dataclasses.fields(cls)} | ({"name"} if section == "algo" else set())
        unknown = sorted(set(values) - fields)
        assert not unknown, f"{path}: {section}.{unknown} are not fields of {cls.__name__}"
        if pinned:
            continue
        repeated = _repeated(values, defaults(cls))
        where = f"{section}." if section else ""
        assert not repeated, f"{path} repeats {cls.__name__}'s defaults of {where}{repeated}: drop them"
        if section == "env" and values.get("name") in envs.names():  # the env's own options
            repeated = _repeated(values.get("options") or {}, envs.options(values["name"]))
            assert not repeated, f"{path} repeats {values['name']}'s defaults of env.options.{repeated}"


def _repeated(values: dict, base: dict) -> list[str]:
    """The keys of ``values`` that hold ``base``'s value (a bool never equals a number)."""
    return sorted(
        k for k, v in values.items()
        if k in base and v == base[k] and isinstance(v, bool) == isinstance(base[k], bool)
    )  # fmt: skip


def test_every_env_is_a_choice_with_its_constructors_options():
    """``env=<name>`` works for every registered env without a file of its own: the env group is
    the registry, each option holding the env's name and its constructor's options with their
    defaults (``envs.options``), every one overridable as ``env.options.key=value``."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        for name in envs.names():
            # algo=sac: no experiment of SAC sets env options
            cfg = compose("train", overrides=[f"env={name}", "algo=sac", "run_dir=/unused"])
            assert cfg.env.name == name
            assert OmegaConf.to_container(cfg.env.options) == envs.options(name), name
            changed = [f"env.options.{key}=7" for key in envs.options(name)]
            cfg = compose("train", overrides=[f"env={name}", "algo=sac", *changed, "run_dir=/unused"])
            assert OmegaConf.to_container(cfg.env.options) == dict.fromkeys(envs.options(name), 7)


@pytest.mark.parametrize("algo", sorted(agents.ALGORITHMS))
def test_every_field_overrides_without_a_plus(algo):
    """Each dataclass field is in the composed config, so ``section.key=value`` overrides it
    (Hydra refuses a key the config lacks unless written ``+section.key=value``)."""
    classes = {**SECTIONS, "algo": agents.config_class(algo)}
    overrides = [f"algo={algo}", "env=hopper", "run_dir=/unused", "seed=3"]
    for section, cls in classes.items():
        for key, value in defaults(cls).items():
            overrides.append(f"{section}.{key}={_override_value(value)}")
    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        cfg = compose("train", overrides=overrides)
    assert cfg.seed == 3 and cfg.algo.name == algo
    for section, cls in classes.items():
        for key, value in defaults(cls).items():
            assert OmegaConf.to_container(cfg[section])[key] == value, f"{section}.{key}"


def _override_value(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict | list):
        return repr(value).replace("'", "")
    return repr(value)
