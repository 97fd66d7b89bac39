"""Gymnasium adapters: a batched ``VectorEnv`` (EnvPool-style) and a single ``gymnasium.Env``.

For learners outside fastrl (Stable-Baselines3, CleanRL): numpy in, numpy out, the whole batch
stepped by one compiled call. Autoreset follows Gymnasium's ``SAME_STEP`` mode: when an env's
episode ends, the returned observation is already the new episode's first one, and
``infos["final_obs"]`` (an object array, ``None`` where not done, with the ``"_final_obs"``
mask) holds the finished episode's last observation; ``infos["episode"]`` carries ``r``
(return) and ``l`` (length) of finished episodes with mask ``"_episode"``, as Gymnasium's
``RecordEpisodeStatistics`` does. ``infos["diverged"]`` flags the envs whose physics diverged
on this step (NaN or inf actions, say): they end with reward 0 and restart. Observations are
float64 and actions float32, as in Gymnasium's MuJoCo spaces.

``send(actions, env_ids)`` / ``recv()`` is EnvPool's asynchronous pair: ``send`` dispatches the
compiled step and returns at once (JAX dispatch is asynchronous), so the caller's own work
overlaps the simulation; ``recv`` waits and returns the results of the envs sent.

With several JAX devices that divide ``num_envs`` (GPUs, or on a CPU
``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>`` set before JAX starts), each device
steps its slice of the envs: on 2 cores that runs the physics about 1.4x faster than one device.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.envs.registry import make
from fastrl.runtime.devices import DEVICE_AXIS, batch_mesh, over_devices


def _spaces(env: Env) -> tuple[gymnasium.spaces.Box, gymnasium.spaces.Box]:
    obs = gymnasium.spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float64)
    low, high = env.action_bounds
    return obs, gymnasium.spaces.Box(low, high, dtype=np.float32)


def _batched_fns(env: Env, num_envs: int):
    def reset(keys):
        return jax.vmap(env.reset)(keys)

    def step(state: State, actions: jax.Array, mask: jax.Array) -> State:
        new = jax.vmap(env.step)(state, actions)
        keep = lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
        return jax.tree.map(keep, new, state)

    # Several devices (e.g. XLA_FLAGS=--xla_force_host_platform_device_count=2 on a 2-core CPU):
    # each steps its slice of the envs, and reset lays the state out that way from the start
    # (else the first step's input layout differs from the later ones' and it compiles twice).
    mesh = batch_mesh(num_envs)
    if mesh is None:
        return jax.jit(reset), jax.jit(step, donate_argnums=0)
    split = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(DEVICE_AXIS))
    return jax.jit(reset, out_shardings=split), jax.jit(over_devices(step, mesh), donate_argnums=0)


class VectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` copies of a fastrl env stepped together (see the module docstring)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, env: Env, num_envs: int, seed: int | None = None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.env = env
        self.num_envs = int(num_envs)
        self.single_observation_space, self.single_action_space = _spaces(env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._reset_fn, self._step_fn = _batched_fns(env, self.num_envs)
        self._seed_rng = np.random.default_rng(seed)
        self._state: State | None = None
        self._pending: np.ndarray | None = None
        self._all = jnp.ones(self.num_envs, bool)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Starts every env afresh; the same ``seed`` gives the same episodes."""
        super().reset(seed=seed)
        if seed is None:
            seed = int(self._seed_rng.integers(2**31))
        keys = jax.random.split(jax.random.PRNGKey(seed), self.num_envs)
        self._state = self._reset_fn(keys)
        self._pending = None
        return np.asarray(self._state.obs, np.float64), {}

    def step(self, actions):
        """Steps every env with ``actions`` (num_envs, nu); see the module docstring for infos."""
        self.send(actions)
        return self.recv()

    def send(self, actions, env_ids=None) -> None:
        """Dispatches a step of the envs ``env_ids`` (all by default) and returns at once.

        Args:
          actions: (len(env_ids), nu) actions of those envs, in order.
          env_ids: indices of the envs to step; the others keep their state.
        """
        if self._state is None:
            raise RuntimeError("call reset() before send()/step()")
        if self._pending is not None:
            raise RuntimeError("send() called twice without recv()")
        actions = np.asarray(actions, np.float32)
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids, np.int64).ravel()
        if actions.shape != (ids.size, self.env.action_size):
            expected = (ids.size, self.env.action_size)
            raise ValueError(f"actions have shape {actions.shape}; expected {expected}")
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_envs or np.unique(ids).size != ids.size):
            raise ValueError(f"env_ids must be distinct indices in [0, {self.num_envs}); got {ids}")
        if env_ids is None:
            full, mask = actions, self._all
        else:
            full = np.zeros((self.num_envs, self.env.action_size), np.float32)
            full[ids] = actions
            mask = np.zeros(self.num_envs, bool)
            mask[ids] = True
        self._state = self._step_fn(self._state, jnp.asarray(full), jnp.asarray(mask))
        self._pending = ids

    def recv(self):
        """Waits for the last ``send`` and returns (obs, rewards, terminations, truncations, infos)
        of the envs it stepped, in the order given."""
        if self._pending is None:
            raise RuntimeError("recv() called without a pending send()")
        ids, self._pending = self._pending, None
        s = jax.device_get(self._state)
        obs = np.asarray(s.obs, np.float64)[ids]
        term = np.asarray(s.terminated)[ids]
        trunc = np.asarray(s.truncated)[ids]
        # A step whose physics diverged (e.g. NaN or inf actions) ends and resets that env with
        # reward 0; the flag says so, as make_gym's info["diverged"] and the functional env do.
        diverged = np.asarray(s.metrics["diverged"])[ids] > 0
        infos: dict[str, Any] = {"env_id": ids, "diverged": diverged, "_diverged": np.ones_like(diverged)}
        done = term | trunc
        if done.any():
            final = np.full(ids.size, None, dtype=object)
            last = np.asarray(s.final_obs, np.float64)[ids]
            for i in np.flatnonzero(done):
                final[i] = last[i]
            infos["final_obs"], infos["_final_obs"] = final, done
            infos["episode"] = {
                "r": np.where(done, np.asarray(s.episode_return)[ids], 0.0),
                "l": np.where(done, np.asarray(s.episode_length)[ids], 0),
                "_r": done,
                "_l": done,
            }
            infos["_episode"] = done
        return obs, np.asarray(s.reward, np.float64)[ids], term, trunc, infos

    def close_extras(self, **kwargs):
        self._state = None


class GymEnv(gymnasium.Env):
    """One fastrl env as a plain ``gymnasium.Env`` (for tools that want a single env).

    Episodes end by ``terminated`` or ``truncated`` (the time limit is built in); the next
    ``step`` after either must be preceded by ``reset``, as Gymnasium requires.
    """

    metadata = {"render_modes": []}

    def __init__(self, env: Env):
        self.env = env
        self.observation_space, self.action_space = _spaces(env)
        self._reset_fn = jax.jit(env.reset)
        self._step_fn = jax.jit(env.step)
        self._state: State | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        key = jax.random.PRNGKey(int(self.np_random.integers(2**31)))
        self._state = self._reset_fn(key)
        return np.asarray(self._state.obs, np.float64), {}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, np.float32)
        if action.shape != (self.env.action_size,):
            raise ValueError(f"action has shape {action.shape}; expected ({self.env.action_size},)")
        self._state = self._step_fn(self._state, jnp.asarray(action))
        s = jax.device_get(self._state)
        obs = np.asarray(s.final_obs, np.float64)  # the episode's own last observation
        info = {k: float(v) for k, v in s.metrics.items()}
        return obs, float(s.reward), bool(s.terminated), bool(s.truncated), info


def make_vec(name: str, num_envs: int, seed: int | None = None, **overrides) -> VectorEnv:
    """A batched Gymnasium ``VectorEnv`` of ``num_envs`` copies of env ``name``.

    Args:
      name: a registered env name (see ``fastrl.envs.names()``).
      num_envs: batch size.
      seed: seeds the first ``reset()`` when it is called without a seed.
      **overrides: passed to the env's constructor (``frame_skip``, ``reward_weights``...).
    """
    return VectorEnv(make(name, **overrides), num_envs, seed)


def make_gym(name: str, **overrides) -> GymEnv:
    """One env ``name`` as a ``gymnasium.Env``."""
    return GymEnv(make(name, **overrides))
