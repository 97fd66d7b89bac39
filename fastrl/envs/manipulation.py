"""Arm and balance tasks with Gymnasium v5's definitions: reacher, pusher, inverted_pendulum,
inverted_double_pendulum.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.envs.base import Env


class Reacher(Env):
    """Two-link arm reaching a random target in the plane. Gymnasium ``Reacher-v5``.

    Observation (10): cos and sin of the two joint angles, target xy, joint velocities,
    fingertip minus target (xy). Reward: ``dist`` -|fingertip - target| (1), ``ctrl`` -|a|^2
    (1). Episodes last 50 steps; the target is uniform in the disc of radius 0.2 (Gymnasium
    draws it by rejection from the square; polar sampling gives the same distribution
    without a data-dependent loop).
    """

    name = "reacher"
    asset = "reacher.xml"
    default_frame_skip = 2
    default_episode_length = 50
    default_weights = {"dist": 1.0, "ctrl": 1.0}
    goal_radius = 0.2
    smooth_gradients = True

    def _reset_qpos_qvel(self, key, model):
        k1, k2, k3, k4 = jax.random.split(key, 4)
        qpos = model.qpos0 + self.uniform(k1, (model.nq,), 0.1)
        radius = self.goal_radius * jnp.sqrt(jax.random.uniform(k2, (), qpos.dtype))
        angle = jax.random.uniform(k3, (), qpos.dtype, 0.0, 2 * jnp.pi)
        goal = radius * jnp.stack([jnp.cos(angle), jnp.sin(angle)])
        qpos = qpos.at[-2:].set(goal)
        qvel = self.uniform(k4, (model.nv,), 0.005).at[-2:].set(0.0)
        return qpos, qvel

    def _observe(self, model, data):
        theta = data.qpos[:2]
        tip = data.xpos[self.body_id("fingertip")] - data.xpos[self.body_id("target")]
        return jnp.concatenate([jnp.cos(theta), jnp.sin(theta), data.qpos[2:], data.qvel[:2], tip[:2]])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        dist = jnp.linalg.norm(after.xpos[self.body_id("fingertip")] - after.xpos[self.body_id("target")])
        terms = {"dist": -w["dist"] * dist, "ctrl": -w["ctrl"] * jnp.sum(action**2)}
        return terms, jnp.zeros((), bool), {"distance": dist}


class Pusher(Env):
    """Seven-joint arm pushing a cylinder to a goal on a table. Gymnasium ``Pusher-v5``.

    Observation (23): arm qpos (7), arm qvel (7), xyz of the fingertip body, the object and
    the goal. Reward: ``near`` -|object - tips| (0.5), ``dist`` -|object - goal| (1), ``ctrl``
    -|a|^2 (0.1). Episodes last 100 steps. The object starts uniform in
    [-0.3, 0] x [-0.2, 0.2] at least 0.17 from the goal: Gymnasium rejects until it is; here the
    first acceptable of ``reset_candidates`` draws is kept (all are rejected with probability
    below 1e-13, in which case the last is used).
    """

    name = "pusher"
    asset = "pusher.xml"
    default_frame_skip = 5
    default_episode_length = 100
    default_weights = {"near": 0.5, "dist": 1.0, "ctrl": 0.1}
    gradient_note = "the object only moves through contacts, whose gradients are zero or explosive"
    reset_candidates = 32
    min_goal_distance = 0.17

    def _reset_qpos_qvel(self, key, model):
        k1, k2 = jax.random.split(key)
        dtype = model.qpos0.dtype
        low = jnp.array([-0.3, -0.2], dtype)
        high = jnp.array([0.0, 0.2], dtype)
        cand = jax.random.uniform(k1, (self.reset_candidates, 2), dtype, low, high)
        ok = jnp.linalg.norm(cand, axis=1) > self.min_goal_distance  # the goal is at the origin
        first = jnp.where(jnp.any(ok), jnp.argmax(ok), self.reset_candidates - 1)
        qpos = model.qpos0.at[-4:-2].set(cand[first]).at[-2:].set(0.0)
        qvel = self.uniform(k2, (model.nv,), 0.005).at[-4:].set(0.0)
        return qpos, qvel

    def _bodies(self, data):
        return (
            data.xpos[self.body_id("tips_arm")],
            data.xpos[self.body_id("object")],
            data.xpos[self.body_id("goal")],
        )

    def _observe(self, model, data):
        tips, obj, goal = self._bodies(data)
        return jnp.concatenate([data.qpos[:7], data.qvel[:7], tips, obj, goal])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        tips, obj, goal = self._bodies(after)
        dist = jnp.linalg.norm(obj - goal)
        terms = {
            "near": -w["near"] * jnp.linalg.norm(obj - tips),
            "dist": -w["dist"] * dist,
            "ctrl": -w["ctrl"] * jnp.sum(action**2),
        }
        return terms, jnp.zeros((), bool), {"distance": dist}


class InvertedPendulum(Env):
    """Cart-pole balance. Gymnasium ``InvertedPendulum-v5``.

    Observation (4): qpos, qvel. Reward: ``survive`` 1 per step while the pole is within 0.2
    rad of upright. Terminates when it leaves that range (or the state is non-finite). Two
    smooth shaping terms, off by default (weight 0), give gradient-based learners a signal the
    0/1 survival reward lacks: ``upright`` -angle^2 and ``centered`` -cart position^2.
    """

    name = "inverted_pendulum"
    asset = "inverted_pendulum.xml"
    default_frame_skip = 2
    default_weights = {"survive": 1.0, "upright": 0.0, "centered": 0.0}
    default_reset_noise_scale = 0.01
    smooth_gradients = True

    def _observe(self, model, data):
        return jnp.concatenate([data.qpos, data.qvel])

    def _reward(self, model, before, after, action):
        obs = self._observe(model, after)
        terminated = ~jnp.all(jnp.isfinite(obs)) | (jnp.abs(after.qpos[1]) > 0.2)
        w = self.reward_weights
        terms = {
            "survive": w["survive"] * ~terminated,
            "upright": -w["upright"] * after.qpos[1] ** 2,
            "centered": -w["centered"] * after.qpos[0] ** 2,
        }
        return terms, terminated, {}


class InvertedDoublePendulum(Env):
    """Cart with a two-link pole to balance. Gymnasium ``InvertedDoublePendulum-v5``.

    Observation (9): cart position, sin and cos of the two hinge angles, qvel clipped to
    [-10, 10], the cart's constraint force clipped to [-10, 10]. Reward: ``alive`` (10) while
    the pole tip is above z = 1, ``distance`` -(0.01 x^2 + (z - 2)^2) of the tip (1),
    ``velocity`` -(0.001 w1^2 + 0.005 w2^2) (1). Terminates when the tip drops to z <= 1.
    """

    name = "inverted_double_pendulum"
    asset = "inverted_double_pendulum.xml"
    default_frame_skip = 5
    default_weights = {"alive": 10.0, "distance": 1.0, "velocity": 1.0}
    default_reset_noise_scale = 0.1
    reset_qvel_normal = True
    smooth_gradients = True

    def _observe(self, model, data):
        q = data.qpos
        return jnp.concatenate(
            [
                q[:1],
                jnp.sin(q[1:]),
                jnp.cos(q[1:]),
                jnp.clip(data.qvel, -10.0, 10.0),
                jnp.clip(data.qfrc_constraint, -10.0, 10.0)[:1],
            ]
        )

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        x, y = after.site_xpos[0, 0], after.site_xpos[0, 2]
        terminated = y <= 1.0
        v1, v2 = after.qvel[1], after.qvel[2]
        terms = {
            "alive": w["alive"] * ~terminated,
            "distance": -w["distance"] * (0.01 * x**2 + (y - 2.0) ** 2),
            "velocity": -w["velocity"] * (1e-3 * v1**2 + 5e-3 * v2**2),
        }
        return terms, terminated, {}
