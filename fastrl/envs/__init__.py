"""Functional environments with Gymnasium v5 semantics, and a batched Gymnasium vector API."""

from fastrl.envs.base import Env, Randomization, State, batch_mesh, over_devices
from fastrl.envs.registry import make, names, register
from fastrl.envs.vector import GymEnv, VectorEnv, make_gym, make_vec

__all__ = [
    "Env",
    "GymEnv",
    "Randomization",
    "State",
    "VectorEnv",
    "batch_mesh",
    "make",
    "make_gym",
    "make_vec",
    "names",
    "over_devices",
    "register",
]
