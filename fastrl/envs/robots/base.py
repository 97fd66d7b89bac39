"""The robot tasks' base classes: ``RobotTask`` (a task on a scene of the asset wheels, stepped
as MuJoCo C steps it) and ``JoystickTask`` (a legged robot following a commanded velocity)."""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.base import Env
from fastrl.envs.robots import assets
from fastrl.physics.collision_driver import contact_layout, dynamic_candidates
from fastrl.physics.math import cross


class RobotTask(Env):
    """A task on a robot scene of the asset wheels (``scene``, an ``assets.scene_path`` name),
    stepped as MuJoCo C steps it. Actions are in [-1, 1]: each subclass maps them onto servo
    targets in units of its ``action_scale`` (``_control``)."""

    scene: str = ""
    linesearch = "mujoco"
    # Domain randomisation on by default, as Playground's tasks train: contact friction +-20%,
    # masses +-10%, servo gains +-10% (each over the scene's own)
    default_randomization = {"friction": 0.2, "mass": 0.1, "gain": 0.1}
    action_scale = 0.5  # an action of 1 moves a servo's target this far from its reference

    def __init__(self, *, asset: str | None = None, **kwargs):
        """Arguments as ``Env``'s (``asset`` defaults to the Playground scene)."""
        super().__init__(asset=asset or str(assets.scene_path(self.scene)), **kwargs)

    def _mujoco_model(self) -> mujoco.MjModel:
        """MuJoCo's own model of the scene (its keyframes, names and addresses)."""
        return mujoco.MjModel.from_xml_path(str(self.asset_path))

    def _pair_slots(self, geom1: str, geom2: str) -> np.ndarray:
        """The contact slots (indices into ``data.contact_dist``) of the two named geoms' pair."""
        m = self.model
        want = {m.geom_names.index(geom1), m.geom_names.index(geom2)}
        both = zip(m.pair_geom1, m.pair_geom2, strict=True)
        pairs = [i for i, ab in enumerate(both) if set(map(int, ab)) == want]
        if not pairs:
            raise ValueError(f"{self.name}: geoms {geom1!r} and {geom2!r} never collide in {self.asset_path}")
        slots = np.flatnonzero(np.isin(contact_layout(m), pairs))
        if dynamic_candidates(m)[slots].any():
            raise ValueError(
                f"{self.name}: the pair of geoms {geom1!r} and {geom2!r} is in a group that MJX's "
                "broad-phase cap (max_geom_pairs) compacts, so its contacts have no fixed slots; "
                "watch Data.contact_pair"
            )
        return slots

    def _point_velocity(self, data, body, point):
        """World linear velocity of ``point`` fixed to ``body`` (from its com-based velocity);
        ``body`` a static index or array of them, ``point`` (..., 3) to match."""
        root = np.asarray(self.model.body_rootid)[body]
        vel = data.cvel[body]
        return vel[..., 3:] + cross(vel[..., :3], point - data.subtree_com[root])

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """[-1, 1] per actuator: an action is an offset in units of ``action_scale``, not a servo
        target, so the actuators' ctrlrange does not bound it (a learner mapping its squashed
        output onto the ctrlrange would centre each target half-way across its joint's range).
        The physics clamps the resulting target to the ctrlrange, as in Playground."""
        one = np.ones(self.action_size, np.float32)
        return -one, one.copy()


class JoystickTask(RobotTask):
    """A legged robot following a commanded planar velocity (forward m/s, sideways m/s, yaw
    rad/s), drawn at reset (each task's ``_draw_command``) and redrawn during the episode by
    each task's schedule.

    ``command=(forward, sideways, yaw)`` holds that command instead, at every reset and for the
    whole episode (``env.options.command=[0.5,0,0]``): to evaluate a policy under a chosen
    command, or to drive it in the viewer. ``observation_noise`` scales the observation noise
    (0: none)."""

    default_randomization = {"friction": 0.3, "mass": 0.1, "gain": 0.1}  # floor friction +-30%
    gradient_note = "the robot moves only through foot contacts, whose gradients are zero or explosive"

    def __init__(self, *, observation_noise: float = 1.0, command=None, **kwargs):
        """Arguments as ``RobotTask``'s, and ``observation_noise`` and ``command`` above."""
        super().__init__(**kwargs)
        self.observation_noise = float(observation_noise)
        if command is not None:
            command = tuple(float(c) for c in command)
            if len(command) != 3 or not all(np.isfinite(command)):
                raise ValueError(
                    f"{self.name}: command={command!r} should be three finite numbers (forward "
                    "m/s, sideways m/s, yaw rad/s)"
                )
        self.command = command

    def _first_command(self, key, dtype):
        """The command at reset: a draw, or the held ``command``."""
        if self.command is None:
            return self._draw_command(key, dtype)
        return jnp.asarray(self.command, dtype)

    def _next_command(self, redrawn, command):
        """The next step's command: the task's redraw, unless the command is held."""
        return redrawn if self.command is None else command

    @staticmethod
    def _motion(command, local, gyro, fell):
        """The step's metrics of motion: commanded and achieved planar speed, the achieved
        velocity the tracking terms score (the IMU's, in its own frame, and the yaw rate) and
        whether the robot fell."""
        return {
            "command_speed": jnp.linalg.norm(command[:2]), "speed": jnp.linalg.norm(local[:2]),
            "forward_velocity": local[0], "sideways_velocity": local[1], "yaw_rate": gyro[2],
            "fell": fell.astype(local.dtype),
        }  # fmt: skip

    def _marker(self, data, command):
        """The viewer marker: where the commanded planar velocity would carry the
        trunk (``self._trunk``) in half a second, 0.3 m above it."""
        heading = data.xmat[self._trunk][:, 0] * jnp.array([1.0, 1.0, 0.0], data.xmat.dtype)
        heading = heading / jnp.maximum(jnp.linalg.norm(heading), 1e-9)
        side = jnp.stack([-heading[1], heading[0], 0.0 * heading[2]])
        lift = jnp.array([0.0, 0.0, 0.3], data.xmat.dtype)
        return data.xpos[self._trunk] + 0.5 * (command[0] * heading + command[1] * side) + lift

    def markers(self, task):
        return task["marker"][None]
