"""Environment registry: ``make(name, **overrides)``."""

from __future__ import annotations

import inspect
from typing import Any

from fastrl.envs import locomotion, manipulation, robots, scenes
from fastrl.envs.base import Env

_REGISTRY: dict[str, type[Env]] = {}


def register(cls: type[Env]) -> type[Env]:
    """Adds an ``Env`` subclass under its ``name`` (usable as a class decorator)."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name to register under")
    _REGISTRY[cls.name] = cls
    return cls


for _cls in (
    locomotion.Ant,
    locomotion.HalfCheetah,
    locomotion.Hopper,
    locomotion.Walker2d,
    locomotion.Humanoid,
    locomotion.HumanoidStandup,
    locomotion.Swimmer,
    manipulation.Reacher,
    manipulation.Pusher,
    manipulation.InvertedPendulum,
    manipulation.InvertedDoublePendulum,
    scenes.ArmReach,
    scenes.ArmPush,
    scenes.HandReorient,
    scenes.AntGoal,
    robots.Go1Joystick,
    robots.Go1JoystickRough,
    robots.PandaPickCube,
    robots.BerkeleyHumanoidJoystick,
    robots.LeapCubeReorient,
):
    register(_cls)


def names() -> list[str]:
    """Registered environment names, sorted."""
    return sorted(_REGISTRY)


def env_class(name: str) -> type[Env]:
    """The ``Env`` class registered as ``name``.

    Raises:
      ValueError: for an unknown name, listing the registered ones.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown environment {name!r}; choose one of: {', '.join(names())}") from None


def make(name: str, **overrides) -> Env:
    """Builds the environment ``name``; keyword overrides go to its constructor.

    Raises:
      ValueError: for an unknown name, listing the registered ones.
    """
    return env_class(name)(**overrides)


def options(name: str) -> dict[str, Any]:
    """The keyword options env ``name``'s task adds to ``Env``'s own, with their defaults.

    They are the env's ``env.options`` in the training config, so the constructors' defaults are
    the only ones; base classes' options come first.

    Raises:
      ValueError: for an unknown name, listing the registered ones.
    """
    common = set(inspect.signature(Env.__init__).parameters)
    out: dict[str, Any] = {}
    for cls in reversed(env_class(name).__mro__):
        if "__init__" not in vars(cls) or not issubclass(cls, Env):
            continue
        for p in inspect.signature(vars(cls)["__init__"]).parameters.values():
            if p.kind is p.KEYWORD_ONLY and p.name not in common:
                out[p.name] = p.default
    return out
