"""Locomotion tasks with Gymnasium v5's definitions: ant, halfcheetah, hopper, walker2d,
humanoid, humanoidstandup, swimmer.

Each class's docstring lists its observation, its reward terms (weights overridable by name)
and its termination rule; the defaults equal Gymnasium's ``*-v5`` keyword defaults.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl import physics
from fastrl.envs.base import Env
from fastrl.physics import Data, Model


def _forward_velocity(env: Env, before: jax.Array, after: jax.Array) -> jax.Array:
    return (after - before) / env.dt


class Ant(Env):
    """Quadruped running forward (+x). Gymnasium ``Ant-v5``.

    Observation (105): qpos[2:] (13), qvel (14), cfrc_ext of the 13 bodies clipped to
    ``contact_force_range`` (78); with ``include_cfrc_ext_in_observation=False`` (Gymnasium's
    keyword of the same name, and Brax's Ant default) only the first 27. Reward: ``forward``
    x-velocity of the torso (weight 1), ``healthy`` 1 while healthy (weight 1), ``ctrl`` -|a|^2
    (0.5), ``contact`` -|clipped cfrc_ext|^2 (5e-4). Terminates when the state is non-finite or
    torso z leaves [0.2, 1].
    """

    name = "ant"
    asset = "ant.xml"
    default_frame_skip = 5
    default_weights = {"forward": 1.0, "healthy": 1.0, "ctrl": 0.5, "contact": 5e-4}
    default_reset_noise_scale = 0.1
    reset_qvel_normal = True
    healthy_z_range = (0.2, 1.0)
    contact_force_range = (-1.0, 1.0)
    main_body = 1

    def __init__(self, *, include_cfrc_ext_in_observation: bool = True, **kwargs):
        self.include_cfrc_ext_in_observation = bool(include_cfrc_ext_in_observation)
        super().__init__(**kwargs)

    def _contact_forces(self, model: Model, data: Data) -> jax.Array:
        lo, hi = self.contact_force_range
        return jnp.clip(physics.cfrc_ext(model, data), lo, hi)

    def _observe(self, model, data):
        if not self.include_cfrc_ext_in_observation:
            return jnp.concatenate([data.qpos[2:], data.qvel])
        cfrc = self._contact_forces(model, data)[1:].ravel()
        return jnp.concatenate([data.qpos[2:], data.qvel, cfrc])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        b = self.main_body
        vel = _forward_velocity(self, before.xpos[b, :2], after.xpos[b, :2])
        state = jnp.concatenate([after.qpos, after.qvel])
        lo, hi = self.healthy_z_range
        healthy = jnp.all(jnp.isfinite(state)) & (after.qpos[2] >= lo) & (after.qpos[2] <= hi)
        cfrc = self._contact_forces(model, after)
        terms = {
            "forward": w["forward"] * vel[0],
            "healthy": w["healthy"] * healthy,
            "ctrl": -w["ctrl"] * jnp.sum(action**2),
            "contact": -w["contact"] * jnp.sum(cfrc**2),
        }
        return terms, ~healthy, {"x_velocity": vel[0], "y_velocity": vel[1]}


class HalfCheetah(Env):
    """Planar cheetah running forward. Gymnasium ``HalfCheetah-v5``.

    Observation (17): qpos[1:] (8), qvel (9). Reward: ``forward`` x-velocity (weight 1),
    ``ctrl`` -|a|^2 (0.1). Never terminates.
    """

    name = "halfcheetah"
    asset = "half_cheetah.xml"
    default_frame_skip = 5
    default_weights = {"forward": 1.0, "ctrl": 0.1}
    default_reset_noise_scale = 0.1
    reset_qvel_normal = True

    def _observe(self, model, data):
        return jnp.concatenate([data.qpos[1:], data.qvel])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        vel = _forward_velocity(self, before.qpos[0], after.qpos[0])
        terms = {"forward": w["forward"] * vel, "ctrl": -w["ctrl"] * jnp.sum(action**2)}
        return terms, jnp.zeros((), bool), {"x_velocity": vel}


class Hopper(Env):
    """Planar one-legged hopper. Gymnasium ``Hopper-v5``.

    Observation (11): qpos[1:] (5), qvel clipped to [-10, 10] (6). Reward: ``forward``
    x-velocity (1), ``healthy`` 1 while healthy (1), ``ctrl`` -|a|^2 (1e-3). Healthy: every
    entry of (qpos[2:], qvel) in (-100, 100), torso z > 0.7, torso angle in (-0.2, 0.2).
    """

    name = "hopper"
    asset = "hopper.xml"
    default_frame_skip = 4
    default_weights = {"forward": 1.0, "healthy": 1.0, "ctrl": 1e-3}
    default_reset_noise_scale = 5e-3
    healthy_state_range = (-100.0, 100.0)
    healthy_z_range = (0.7, float("inf"))
    healthy_angle_range = (-0.2, 0.2)

    def _observe(self, model, data):
        return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -10.0, 10.0)])

    def _healthy(self, data: Data) -> jax.Array:
        z, angle = data.qpos[1], data.qpos[2]
        state = jnp.concatenate([data.qpos[2:], data.qvel])
        lo, hi = self.healthy_state_range
        ok = jnp.all((state > lo) & (state < hi))
        ok &= (z > self.healthy_z_range[0]) & (z < self.healthy_z_range[1])
        return ok & (angle > self.healthy_angle_range[0]) & (angle < self.healthy_angle_range[1])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        vel = _forward_velocity(self, before.qpos[0], after.qpos[0])
        healthy = self._healthy(after)
        terms = {
            "forward": w["forward"] * vel,
            "healthy": w["healthy"] * healthy,
            "ctrl": -w["ctrl"] * jnp.sum(action**2),
        }
        return terms, ~healthy, {"x_velocity": vel}


class Walker2d(Hopper):
    """Planar biped. Gymnasium ``Walker2d-v5``.

    Observation (17): qpos[1:] (8), qvel clipped to [-10, 10] (9). Reward as the hopper's.
    Healthy: torso z in (0.8, 2), torso angle in (-1, 1).
    """

    name = "walker2d"
    asset = "walker2d.xml"
    healthy_z_range = (0.8, 2.0)
    healthy_angle_range = (-1.0, 1.0)

    def _healthy(self, data: Data) -> jax.Array:
        z, angle = data.qpos[1], data.qpos[2]
        ok = (z > self.healthy_z_range[0]) & (z < self.healthy_z_range[1])
        return ok & (angle > self.healthy_angle_range[0]) & (angle < self.healthy_angle_range[1])


def _mass_center(model: Model, data: Data) -> jax.Array:
    mass = model.body_mass
    return jnp.sum(mass[:, None] * data.xipos, axis=0) / jnp.sum(mass)


class Humanoid(Env):
    """3D humanoid running forward. Gymnasium ``Humanoid-v5``.

    Observation (348): qpos[2:] (22), qvel (23), cinert[1:] (130), cvel[1:] (78),
    qfrc_actuator[6:] (17), cfrc_ext[1:] (78). Reward: ``forward`` x-velocity of the centre of
    mass (1.25), ``healthy`` (5), ``ctrl`` -|ctrl|^2 (0.1), ``contact`` -min(w |cfrc_ext|^2, 10)
    (5e-7). Terminates when torso z leaves (1, 2).
    """

    name = "humanoid"
    asset = "humanoid.xml"
    default_frame_skip = 5
    default_weights = {"forward": 1.25, "healthy": 5.0, "ctrl": 0.1, "contact": 5e-7}
    default_reset_noise_scale = 1e-2
    healthy_z_range = (1.0, 2.0)
    contact_cost_max = 10.0

    def _observe(self, model, data):
        return jnp.concatenate(
            [
                data.qpos[2:],
                data.qvel,
                data.cinert[1:].ravel(),
                data.cvel[1:].ravel(),
                data.qfrc_actuator[6:],
                physics.cfrc_ext(model, data)[1:].ravel(),
            ]
        )

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        vel = _forward_velocity(self, _mass_center(model, before)[:2], _mass_center(model, after)[:2])
        z = after.qpos[2]
        healthy = (z > self.healthy_z_range[0]) & (z < self.healthy_z_range[1])
        contact = w["contact"] * jnp.sum(physics.cfrc_ext(model, after) ** 2)
        terms = {
            "forward": w["forward"] * vel[0],
            "healthy": w["healthy"] * healthy,
            "ctrl": -w["ctrl"] * jnp.sum(after.ctrl**2),
            "contact": -jnp.minimum(contact, self.contact_cost_max),
        }
        return terms, ~healthy, {"x_velocity": vel[0], "y_velocity": vel[1]}


class HumanoidStandup(Humanoid):
    """The humanoid lying down must stand up. Gymnasium ``HumanoidStandup-v5``.

    Observation as ``humanoid``. Reward: ``uph`` torso height / timestep (1), ``ctrl``
    -|ctrl|^2 (0.1), ``impact`` -min(w |cfrc_ext|^2, 10) (5e-7), ``alive`` 1 (1). Never
    terminates.
    """

    name = "humanoidstandup"
    asset = "humanoidstandup.xml"
    default_weights = {"uph": 1.0, "ctrl": 0.1, "impact": 5e-7, "alive": 1.0}

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        impact = w["impact"] * jnp.sum(physics.cfrc_ext(model, after) ** 2)
        terms = {
            "uph": w["uph"] * after.qpos[2] / model.timestep,
            "ctrl": -w["ctrl"] * jnp.sum(after.ctrl**2),
            "impact": -jnp.minimum(impact, self.contact_cost_max),
            "alive": w["alive"] * jnp.ones((), after.qpos.dtype),
        }
        return terms, jnp.zeros((), bool), {"z": after.qpos[2]}


class Swimmer(Env):
    """Three-link swimmer in a viscous fluid. Gymnasium ``Swimmer-v5``.

    Observation (8): qpos[2:] (3), qvel (5). Reward: ``forward`` x-velocity (1), ``ctrl``
    -|a|^2 (1e-4). Never terminates.
    """

    name = "swimmer"
    asset = "swimmer.xml"
    default_frame_skip = 4
    default_weights = {"forward": 1.0, "ctrl": 1e-4}
    default_reset_noise_scale = 0.1
    smooth_gradients = True  # no contacts: viscous fluid forces only

    def _observe(self, model, data):
        return jnp.concatenate([data.qpos[2:], data.qvel])

    def _reward(self, model, before, after, action):
        w = self.reward_weights
        vel = _forward_velocity(self, before.qpos[:2], after.qpos[:2])
        terms = {"forward": w["forward"] * vel[0], "ctrl": -w["ctrl"] * jnp.sum(action**2)}
        return terms, jnp.zeros((), bool), {"x_velocity": vel[0], "y_velocity": vel[1]}
