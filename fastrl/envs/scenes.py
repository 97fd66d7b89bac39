"""Scenes beyond the standard suite: goal-conditioned tasks whose goal lives in ``State.task``.

These are fastrl's own tasks (no Gymnasium counterpart); each reports ``success`` per step, and
evaluation reads it at the end of every episode (``eval_metrics``).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.envs.base import Env
from fastrl.envs.locomotion import Ant
from fastrl.physics.math import quat_conj, quat_mul, quat_rotate


def _on_table(xy: jax.Array) -> jax.Array:
    """(1, 3) a marker at the horizontal goal ``xy``, on the ground (z = 0)."""
    return jnp.concatenate([xy, jnp.zeros(1, xy.dtype)])[None]


class ArmReach(Env):
    """A 6-joint UR5e-like arm moves its tool flange to a random target (``env=arm_reach``).

    Actions are the six servo targets (radians, within each actuator's ctrlrange). A target is
    drawn uniformly in azimuth (all 360 degrees around the base), horizontal distance and
    height from ``target_radius`` x ``target_height``, a region the arm reaches without
    stretching straight. An episode lasts 150 steps of 0.02 s; success means the flange is
    within ``success_tolerance`` (5 cm) of the target at the episode's last step.

    Observation (27): cos and sin of the six joint angles, joint velocities (6), flange
    position, target position, target minus flange (3 each; metres, table frame).
    Reward: ``dist`` -|target - flange| (1), ``bonus`` +1 while within the tolerance (0.5),
    ``velocity`` -|qvel|^2 (0.005): settle at the target rather than swing through it.
    """

    name = "arm_reach"
    asset = "arm.xml"
    default_frame_skip = 4
    default_episode_length = 150
    default_weights = {"dist": 1.0, "bonus": 0.5, "velocity": 0.005}
    default_reset_noise_scale = 0.1
    smooth_gradients = True
    eval_metrics = ("success",)
    success_tolerance = 0.05
    target_radius = (0.25, 0.6)
    target_height = (0.1, 0.6)

    def _reset_qpos_qvel(self, key, model):
        qpos = model.qpos0 + self.uniform(key, (model.nq,), self.reset_noise_scale)
        return qpos, jnp.zeros(model.nv, qpos.dtype)

    def _sample_task(self, key, model, data):
        dtype = data.qpos.dtype
        k1, k2, k3 = jax.random.split(key, 3)
        angle = jax.random.uniform(k1, (), dtype, 0.0, 2 * jnp.pi)
        radius = jax.random.uniform(k2, (), dtype, *self.target_radius)
        height = jax.random.uniform(k3, (), dtype, *self.target_height)
        return {"target": jnp.stack([radius * jnp.cos(angle), radius * jnp.sin(angle), height])}

    def markers(self, task):
        return task["target"][None]

    def _flange(self, data):
        return data.site_xpos[0]

    def _observe_task(self, model, data, task):
        ee, target = self._flange(data), task["target"]
        q = data.qpos
        return jnp.concatenate([jnp.cos(q), jnp.sin(q), data.qvel, ee, target, target - ee])

    def _reward_task(self, model, before, after, action, task, key):
        w = self.reward_weights
        dist = jnp.linalg.norm(task["target"] - self._flange(after))
        success = (dist < self.success_tolerance).astype(dist.dtype)
        terms = {
            "dist": -w["dist"] * dist,
            "bonus": w["bonus"] * success,
            "velocity": -w["velocity"] * jnp.sum(after.qvel**2),
        }
        return terms, jnp.zeros((), bool), {"distance": dist, "success": success}, task


class ArmPush(ArmReach):
    """The arm of ``arm_reach`` pushes a block to a goal on its table (``env=arm_push``).

    The block (a 10 cm cube, 0.5 kg) starts at a uniform angle within ``block_angle`` of the
    arm's +x side and a distance in ``block_radius`` from its base; the goal lies
    ``goal_offset`` (10-25 cm) from the block in any direction, kept within ``goal_radius`` of
    the base. Only the tool sphere at the flange touches the block (see ``arm_push.xml``). An
    episode lasts 200 steps of 0.02 s; success means the block's centre is within
    ``success_tolerance`` (5 cm, horizontally) of the goal at the episode's last step.

    Observation (38): cos and sin of the six joint angles, joint velocities (6), tool position
    (3), block position (3), block orientation (quaternion, 4), block velocity (3), goal (2),
    block minus tool (3), goal minus block (2).
    Reward: ``dist`` -|goal - block| (2), ``progress`` the block's speed towards the goal (2),
    ``near`` -|push point - tool| (0.5) where the push point is behind the block, on the far
    side from the goal at the block's mid-height (where the tool must be to push it there),
    ``bonus`` +1 while within the tolerance (1), ``velocity`` -|arm qvel|^2 (0.005).
    """

    name = "arm_push"
    asset = "arm_push.xml"
    default_episode_length = 200
    default_weights = {"dist": 2.0, "progress": 2.0, "near": 0.5, "bonus": 1.0, "velocity": 0.005}
    smooth_gradients = False
    gradient_note = "the block moves only while the tool touches it: contact switches the gradient on and off"
    block_radius = (0.35, 0.55)
    block_angle = 0.25 * jnp.pi
    goal_offset = (0.1, 0.25)
    goal_radius = (0.3, 0.7)

    def _reset_qpos_qvel(self, key, model):
        k_arm, k_angle, k_radius = jax.random.split(key, 3)
        dtype = model.qpos0.dtype
        arm = model.qpos0[:6] + self.uniform(k_arm, (6,), self.reset_noise_scale)
        angle = jax.random.uniform(k_angle, (), dtype, -self.block_angle, self.block_angle)
        radius = jax.random.uniform(k_radius, (), dtype, *self.block_radius)
        block = jnp.array([radius * jnp.cos(angle), radius * jnp.sin(angle)], dtype)
        qpos = jnp.concatenate([arm, block, model.qpos0[8:]])  # resting on the table, unrotated
        return qpos, jnp.zeros(model.nv, dtype)

    def _sample_task(self, key, model, data):
        k1, k2 = jax.random.split(key)
        dtype = data.qpos.dtype
        block = data.qpos[6:8]
        angle = jax.random.uniform(k1, (), dtype, 0.0, 2 * jnp.pi)
        offset = jax.random.uniform(k2, (), dtype, *self.goal_offset)
        goal = block + offset * jnp.stack([jnp.cos(angle), jnp.sin(angle)])
        norm = jnp.linalg.norm(goal)
        goal = goal * jnp.clip(norm, *self.goal_radius) / norm  # stays on the arm's side of reach
        return {"target": goal}

    def markers(self, task):
        return _on_table(task["target"])

    def _tool(self, data):
        return data.site_xpos[1]

    def _observe_task(self, model, data, task):
        q, tool, block, goal = data.qpos[:6], self._tool(data), data.qpos[6:9], task["target"]
        return jnp.concatenate([
            jnp.cos(q), jnp.sin(q), data.qvel[:6], tool, block, data.qpos[9:13], data.qvel[6:9],
            goal, block - tool, goal - block[:2],
        ])  # fmt: skip

    def _push_point(self, block, goal):
        """Where the tool's centre must be to push the block straight at the goal."""
        offset = goal - block[:2]
        heading = offset / jnp.maximum(jnp.linalg.norm(offset), 1e-6)
        reach = 0.05 + 0.03 + 0.01  # block half-size + tool radius + a centimetre's clearance
        return jnp.concatenate([block[:2] - reach * heading, block[2:3]])

    def _reward_task(self, model, before, after, action, task, key):
        w = self.reward_weights
        goal, block = task["target"], after.qpos[6:9]
        dist = jnp.linalg.norm(goal - block[:2])
        dist_before = jnp.linalg.norm(goal - before.qpos[6:8])
        near = jnp.linalg.norm(self._push_point(block, goal) - self._tool(after))
        success = (dist < self.success_tolerance).astype(dist.dtype)
        terms = {
            "dist": -w["dist"] * dist,
            "progress": w["progress"] * (dist_before - dist) / self.dt,
            "near": -w["near"] * near,
            "bonus": w["bonus"] * success,
            "velocity": -w["velocity"] * jnp.sum(after.qvel[:6] ** 2),
        }
        return terms, jnp.zeros((), bool), {"distance": dist, "success": success}, task


def _yaw_quat(yaw: jax.Array) -> jax.Array:
    return jnp.stack([jnp.cos(yaw / 2), jnp.zeros_like(yaw), jnp.zeros_like(yaw), jnp.sin(yaw / 2)])


def _rotation_angle(q: jax.Array) -> jax.Array:
    """Angle (0 to pi) of the rotation a unit quaternion makes; smooth where it is not zero."""
    return 2 * jnp.arctan2(jnp.linalg.norm(q[1:] + 1e-12), jnp.abs(q[0]))


def _cube_rotations() -> np.ndarray:
    """(24, 4) the rotations mapping a cube onto itself, as unit quaternions (w >= 0)."""
    found = []
    for axes in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            mat = np.zeros((3, 3))
            mat[range(3), axes] = signs
            if np.linalg.det(mat) > 0:
                quat = np.zeros(4)
                mujoco.mju_mat2Quat(quat, mat.reshape(-1))
                found.append(quat if quat[0] >= 0 else -quat)
    return np.array(found)


_CUBE_ROTATIONS = _cube_rotations()


class HandReorient(Env):
    """A four-fingered hand turns a cube in its palm to a target orientation (``env=hand_reorient``).

    The cube starts resting at the palm's centre at a random heading; the target is the cube
    turned about the vertical to a heading uniform within ``target_yaw`` (+-180 degrees) of the
    start, with its faces level (the cube's faces are distinct: a mark on one of them shows the
    heading). With ``target="faces"`` the target also has a random face up (one of the cube's
    24 rotations, then the turn): the fingers must roll the cube over, a far harder task. The
    cube is dropped (``terminated``) when its centre falls 1.5 cm below its resting height or
    leaves the palm's square. An episode lasts 150 steps of 0.04 s; success means the
    orientation error is below ``success_tolerance`` (0.4 rad, as in OpenAI's in-hand cube
    work) at the episode's last step.

    Observation (45): joint angles and velocities (12 each), cube position relative to its
    resting point (3), cube orientation (4), cube linear and angular velocity (3 each), target
    orientation (4), and the rotation from cube to target (4); quaternions with w >= 0.
    Reward: ``rotate`` the decrease of the orientation error this step (radians, weight 5),
    ``bonus`` +1 while within the tolerance (0.5), ``drop`` -1 when the cube is dropped (20).
    """

    name = "hand_reorient"
    asset = "hand.xml"
    default_frame_skip = 4
    default_episode_length = 150
    default_weights = {"rotate": 5.0, "bonus": 0.5, "drop": 20.0}
    default_reset_noise_scale = 0.05
    eval_metrics = ("success", "dropped")
    success_tolerance = 0.4
    target_yaw = jnp.pi
    rest_height = 0.135
    palm_half = 0.075
    drop_depth = 0.015

    TARGETS = ("yaw", "faces")

    def __init__(self, *, target: str = "yaw", **kwargs):
        if target not in self.TARGETS:
            raise ValueError(f"hand_reorient: target={target!r}; choose one of {list(self.TARGETS)}")
        self.target = target
        super().__init__(**kwargs)

    def _reset_qpos_qvel(self, key, model):
        k_hand, k_xy, k_yaw = jax.random.split(key, 3)
        dtype = model.qpos0.dtype
        hand = model.qpos0[:12] + self.uniform(k_hand, (12,), self.reset_noise_scale)
        xy = self.uniform(k_xy, (2,), 0.005)
        yaw = jax.random.uniform(k_yaw, (), dtype, -jnp.pi, jnp.pi)
        cube = jnp.concatenate([xy, jnp.full((1,), self.rest_height, dtype), _yaw_quat(yaw)])
        return jnp.concatenate([hand, cube]), jnp.zeros(model.nv, dtype)

    def _sample_task(self, key, model, data):
        k_turn, k_face = jax.random.split(key)
        turn = jax.random.uniform(k_turn, (), data.qpos.dtype, -self.target_yaw, self.target_yaw)
        target = quat_mul(_yaw_quat(turn), data.qpos[15:19])
        if self.target == "faces":  # any face up: one of the cube's 24 rotations, then the turn
            symmetries = jnp.asarray(_CUBE_ROTATIONS, data.qpos.dtype)
            target = quat_mul(target, symmetries[jax.random.randint(k_face, (), 0, 24)])
        return {"target": target}

    def _error(self, data, task):
        return _rotation_angle(quat_mul(quat_conj(data.qpos[15:19]), task["target"]))

    def markers(self, task):
        # where the cube's marked face should point, 3.2 cm out from the palm's resting point
        heading = quat_rotate(task["target"], jnp.array([0.032, 0.0, 0.0], task["target"].dtype))
        return (jnp.array([0.0, 0.0, self.rest_height], heading.dtype) + heading)[None]

    def _observe_task(self, model, data, task):
        up = lambda q: jnp.where(q[0] < 0, -q, q)  # noqa: E731
        cube_q = data.qpos[15:19]
        offset = data.qpos[12:15] - jnp.array([0.0, 0.0, self.rest_height], data.qpos.dtype)
        return jnp.concatenate([
            data.qpos[:12], data.qvel[:12], offset, up(cube_q), data.qvel[12:18], up(task["target"]),
            up(quat_mul(quat_conj(cube_q), task["target"])),
        ])  # fmt: skip

    def _reward_task(self, model, before, after, action, task, key):
        w = self.reward_weights
        err_before, err_after = self._error(before, task), self._error(after, task)
        pos = after.qpos[12:15]
        dropped = (pos[2] < self.rest_height - self.drop_depth) | jnp.any(jnp.abs(pos[:2]) > self.palm_half)
        success = (err_after < self.success_tolerance).astype(err_after.dtype)
        terms = {
            "rotate": w["rotate"] * (err_before - err_after),
            "bonus": w["bonus"] * success,
            "drop": -w["drop"] * dropped.astype(err_after.dtype),
        }
        extra = {"orientation_error": err_after, "success": success, "dropped": dropped.astype(success.dtype)}
        return terms, dropped, extra, task


class AntGoal(Ant):
    """The Ant runs to targets placed anywhere around it (``env=ant_goal``).

    A target is drawn at a uniform angle (all 360 degrees) and a distance uniform in
    ``target_radius`` (2-4 m) from the torso; once the torso comes within ``reach_radius``
    (0.5 m) of it, a new target is drawn around the torso's new position, so an episode can
    collect several. Physics, termination and reset are the Ant's (``env=ant``); the shipped
    training settings use Euler with 5 solver iterations like ``experiment/ant_ppo``.

    Observation (109): the Ant's 105, the target relative to the torso in the torso's frame (3),
    and its horizontal distance (1). Reward: ``progress`` the speed toward the target (1),
    ``reach`` +1 per target reached (10), and the Ant's ``healthy`` (1), ``ctrl`` (0.5) and
    ``contact`` (5e-4). Success: at least one target reached within the episode (500 steps).
    """

    name = "ant_goal"
    default_episode_length = 500
    default_weights = {"progress": 1.0, "reach": 10.0, "healthy": 1.0, "ctrl": 0.5, "contact": 5e-4}
    eval_metrics = ("success", "targets_reached")
    target_radius = (2.0, 4.0)
    reach_radius = 0.5

    def _new_target(self, key, torso_xy):
        k1, k2 = jax.random.split(key)
        angle = jax.random.uniform(k1, (), torso_xy.dtype, 0.0, 2 * jnp.pi)
        radius = jax.random.uniform(k2, (), torso_xy.dtype, *self.target_radius)
        return torso_xy + radius * jnp.stack([jnp.cos(angle), jnp.sin(angle)])

    def markers(self, task):
        return _on_table(task["target"])

    def _sample_task(self, key, model, data):
        target = self._new_target(key, data.xpos[self.main_body, :2])
        return {"target": target, "reached": jnp.zeros((), target.dtype)}

    def _observe_task(self, model, data, task):
        b = self.main_body
        offset = jnp.concatenate([task["target"] - data.xpos[b, :2], jnp.zeros(1, data.xpos.dtype)])
        local = data.xmat[b].T @ offset
        return jnp.concatenate([self._observe(model, data), local, jnp.linalg.norm(offset)[None]])

    def _reward_task(self, model, before, after, action, task, key):
        w = self.reward_weights
        b = self.main_body
        lo, hi = self.healthy_z_range
        finite = jnp.all(jnp.isfinite(after.qpos)) & jnp.all(jnp.isfinite(after.qvel))
        healthy = finite & (after.qpos[2] >= lo) & (after.qpos[2] <= hi)
        cfrc = self._contact_forces(model, after)
        dist_before = jnp.linalg.norm(task["target"] - before.xpos[b, :2])
        dist_after = jnp.linalg.norm(task["target"] - after.xpos[b, :2])
        reached = dist_after < self.reach_radius
        terms = {
            "progress": w["progress"] * (dist_before - dist_after) / self.dt,
            "reach": w["reach"] * reached.astype(dist_after.dtype),
            "healthy": w["healthy"] * healthy,
            "ctrl": -w["ctrl"] * jnp.sum(action**2),
            "contact": -w["contact"] * jnp.sum(cfrc**2),
        }
        count = task["reached"] + reached
        target = jnp.where(reached, self._new_target(key, after.xpos[b, :2]), task["target"])
        extra = {"distance": dist_after, "targets_reached": count, "success": (count > 0).astype(count.dtype)}
        return terms, ~healthy, extra, {"target": target, "reached": count}
