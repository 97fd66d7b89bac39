"""Functional environments with Gymnasium v5 semantics, and a batched Gymnasium vector API."""

from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.envs.randomization import Randomization
from fastrl.envs.registry import env_class, make, names, options, register
from fastrl.runtime.devices import batch_mesh, over_devices

_GYMNASIUM_ADAPTER = ("GymEnv", "VectorEnv", "make_gym", "make_vec")


def __getattr__(name):
    # PEP 562 lazy attributes: the Gymnasium adapter loads on first use, because importing
    # gymnasium writes PYGAME_HIDE_SUPPORT_PROMPT into os.environ, and ``import fastrl.envs`` must
    # leave the environment as it was.
    if name in _GYMNASIUM_ADAPTER:
        from fastrl.envs import vector

        return getattr(vector, name)
    raise AttributeError(f"module 'fastrl.envs' has no attribute {name!r}")


__all__ = [
    "Env",
    "GymEnv",
    "Randomization",
    "State",
    "VectorEnv",
    "batch_mesh",
    "env_class",
    "make",
    "make_gym",
    "make_vec",
    "names",
    "options",
    "over_devices",
    "register",
]
