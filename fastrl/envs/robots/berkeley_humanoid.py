"""The Berkeley Humanoid following a commanded velocity on flat ground (``env=humanoid_joystick``):
MuJoCo Playground's ``BerkeleyHumanoidJoystickFlatTerrain``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.robots.base import JoystickTask


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
    # one device: the env step alone now runs faster split over 2 CPU devices (device_split.md),
    # but no training run split over 2 has been measured for this task yet
    splits_over_devices = False
    scene = "playground/locomotion/berkeley_humanoid/scene_mjx_feetonly_flat_terrain"
    default_frame_skip = 10
    default_weights = {
        "tracking_lin_vel": 1.0, "tracking_ang_vel": 0.5, "ang_vel_xy": 0.15, "orientation": 1.0,
        "torques": 2.5e-5, "action_rate": 0.01, "feet_air_time": 2.0, "feet_slip": 0.25,
        "feet_phase": 1.0, "termination": 1.0, "joint_deviation_knee": 0.1, "joint_deviation_hip": 0.25,
        "dof_pos_limits": 1.0, "pose": 1.0,
    }  # fmt: skip
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
