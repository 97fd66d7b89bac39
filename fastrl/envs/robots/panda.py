"""A Franka Panda picking a cube and holding it at a target (``env=panda_pick_cube``): MuJoCo
Playground's ``PandaPickCube``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.robots.base import RobotTask


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
    # one device: the env step alone now runs faster split over 2 CPU devices (device_split.md),
    # but no training run split over 2 has been measured for this task yet
    splits_over_devices = False
    scene = "playground/manipulation/franka_emika_panda/mjx_single_cube"
    default_frame_skip = 4
    default_episode_length = 150
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
