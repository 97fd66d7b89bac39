"""Scenes beyond the standard suite: goal-conditioned tasks whose goal lives in ``State.task``.

These are fastrl's own tasks (no Gymnasium counterpart); each reports ``success`` per step, and
evaluation reads it at the end of every episode (``eval_metrics``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.envs.base import Env
from fastrl.envs.locomotion import Ant


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
        return jnp.concatenate([task["target"], jnp.zeros(1, task["target"].dtype)])[None]

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
