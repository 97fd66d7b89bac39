"""The Leap hand turning a cube to one target orientation after another
(``env=leap_cube_reorient``): MuJoCo Playground's ``LeapCubeReorient``."""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.robots.base import RobotTask
from fastrl.physics.math import quat_conj, quat_integrate, quat_mul, quat_to_mat


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
    # one device: the env step alone now runs faster split over 2 CPU devices (device_split.md),
    # but no training run split over 2 has been measured for this task yet
    splits_over_devices = False
    scene = "playground/manipulation/leap_hand/scene_mjx_cube"
    default_frame_skip = 5
    default_weights = {
        "orientation": 5.0, "position": 0.5, "termination": 100.0, "hand_pose": 0.5,
        "action_rate": 1e-3, "energy": 1e-3, "success": 100.0,
    }  # fmt: skip
    gradient_note = "the cube moves only through contacts, whose gradients are zero or explosive"
    eval_metrics = ("targets_reached",)
    mjx_caps = True
    uncapped_nconmax = 32
    capped_nconmax = 16  # the scene's max_contact_points is 30; see the class docstring
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
