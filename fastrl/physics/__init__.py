"""fastrl's branch-free JAX rigid-body engine in generalized coordinates, faithful to MuJoCo."""

from fastrl.physics.constraint import contact_budgeted
from fastrl.physics.forward import (
    DIVERGENCE_BOUND,
    euler,
    forward,
    forward_forces,
    implicitfast,
    integrate_pos,
    rk4,
    step,
)
from fastrl.physics.io import load_mjcf, make_data, model_from_mujoco
from fastrl.physics.io_checks import UnsupportedFeatureError
from fastrl.physics.sensor import cfrc_ext, contact_force
from fastrl.physics.types import Data, Integrator, JointType, Model

__all__ = [
    "DIVERGENCE_BOUND",
    "Data",
    "Integrator",
    "JointType",
    "Model",
    "UnsupportedFeatureError",
    "cfrc_ext",
    "contact_budgeted",
    "contact_force",
    "euler",
    "forward",
    "forward_forces",
    "implicitfast",
    "integrate_pos",
    "load_mjcf",
    "make_data",
    "model_from_mujoco",
    "rk4",
    "step",
]
