"""Unitree Go1 following a commanded velocity, on flat ground (``env=go1_joystick``) and over a
height field (``env=go1_joystick_rough``): MuJoCo Playground's ``Go1Joystick`` tasks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.robots.base import JoystickTask


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
    default_weights = {
        "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "lin_vel_z": 0.5, "ang_vel_xy": 0.05,
        "orientation": 5.0, "torques": 2e-4, "action_rate": 0.01, "energy": 1e-3, "pose": 0.5,
        "stand_still": 1.0, "dof_pos_limits": 1.0, "feet_clearance": 2.0, "feet_slip": 0.1,
        "feet_air_time": 0.1, "feet_height": 0.2, "termination": 1.0,
    }  # fmt: skip
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
