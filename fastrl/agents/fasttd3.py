"""FastTD3 (Seo et al., 2025): TD3 for many parallel envs, with a distributional critic, fused
with the simulator.

``update`` steps all ``num_envs`` envs ``env_steps_per_update`` times with the deterministic
policy plus Gaussian exploration noise (each env draws its own noise scale, uniformly in
``[exploration_std_min, exploration_std_max]``, anew at every episode start; uniform random
actions during the first ``learning_starts`` env steps). It appends the steps to an on-device
trajectory ring, then takes ``grad_updates_per_update`` critic steps, and an actor step after
every ``policy_delay`` of them.

The two critics are categorical (C51, Bellemare et al., 2017): each outputs a distribution over
``num_atoms`` returns evenly spaced in ``[v_min, v_max]``, learned by cross-entropy against the
n-step target distribution projected back onto the atoms. With ``clipped_double_q`` both critics
learn the target of whichever target critic expects less (TD3's clipped double Q, applied to
distributions), and the actor maximises the smaller expected value; without it each critic learns
its own target and the actor maximises their mean. Target actions carry clipped Gaussian noise
(TD3's target-policy smoothing). Targets bootstrap through time limits, not through terminations.

On envs whose observation appends privileged state (``Env.policy_observation_size``), the critics
read all of it and the actor only its leading part.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from fastrl.agents import normalizer, off_policy, replay
from fastrl.agents.base import Learner, PolicyParams, make_act, observation_normalizer
from fastrl.agents.networks import MLP, NetworkConfig
from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.physics.dataclass import pytree_dataclass


@dataclasses.dataclass(frozen=True)
class FastTD3Config:
    """FastTD3 hyperparameters (``algo=fasttd3``).

    Fields:
      num_envs                 environments stepped in parallel
      env_steps_per_update     steps of every env per update (num_envs * this transitions)
      grad_updates_per_update  critic steps per update
      policy_delay             an actor step after every this many critic steps (counted over
                               the whole run)
      batch_size               n-step transitions per gradient step
      buffer_size              replay capacity in transitions (buffer_size // num_envs steps of
                               each env)
      learning_starts          env steps (all envs together) of uniform random actions before
                               learning
      n_step                   steps summed in each return before bootstrapping
      gamma                    discount
      tau                      Polyak rate of the target critics (per critic step)
      actor_learning_rate      AdamW step size of the actor
      critic_learning_rate     AdamW step size of the critics
      weight_decay             AdamW decoupled weight decay of both
      exploration_std_min      lower end of the per-env exploration noise scales (actions in
                               [-1, 1])
      exploration_std_max      upper end
      target_noise             scale of the target policy's smoothing noise
      noise_clip               the smoothing noise is clipped to [-noise_clip, noise_clip]
      num_atoms                atoms of each critic's return distribution
      v_min                    lowest return the critics can represent (after reward_scaling)
      v_max                    highest
      clipped_double_q         learn the smaller target critic's distribution (see above)
      reward_scaling           rewards are multiplied by this before they enter the returns
      normalize_observations   learn running observation statistics and normalise inputs
      max_grad_norm            global gradient-norm clip (None: off)
    """

    num_envs: int = 128
    env_steps_per_update: int = 1
    grad_updates_per_update: int = 2
    policy_delay: int = 2
    batch_size: int = 1024
    buffer_size: int = 1_048_576
    learning_starts: int = 5_120
    n_step: int = 3
    gamma: float = 0.99
    tau: float = 0.1
    actor_learning_rate: float = 3e-4
    critic_learning_rate: float = 3e-4
    weight_decay: float = 0.1
    exploration_std_min: float = 0.001
    exploration_std_max: float = 0.4
    target_noise: float = 0.1
    noise_clip: float = 0.5
    num_atoms: int = 101
    v_min: float = -250.0
    v_max: float = 250.0
    clipped_double_q: bool = True
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    max_grad_norm: float | None = None

    def __post_init__(self):
        positive = ("num_envs", "env_steps_per_update", "grad_updates_per_update", "policy_delay",
                    "batch_size", "n_step")  # fmt: skip
        for name in positive:
            if int(getattr(self, name)) < 1:
                raise ValueError(f"algo.{name}={getattr(self, name)} must be >= 1")
        if self.buffer_size // self.num_envs < max(self.n_step, self.env_steps_per_update) + 1:
            raise ValueError(
                f"algo.buffer_size={self.buffer_size} holds {self.buffer_size // self.num_envs} steps "
                f"of each of the {self.num_envs} envs; it needs more than "
                f"max(n_step, env_steps_per_update) = {max(self.n_step, self.env_steps_per_update)}"
            )
        if not 0.0 < self.tau <= 1.0 or not 0.0 < self.gamma <= 1.0:
            raise ValueError("algo.tau and algo.gamma must be in (0, 1]")
        if self.num_atoms < 2 or not self.v_min < self.v_max:
            raise ValueError(
                f"algo.num_atoms={self.num_atoms}, v_min={self.v_min}, v_max={self.v_max}: the critic "
                "needs at least 2 atoms and v_min < v_max"
            )
        if not 0.0 <= self.exploration_std_min <= self.exploration_std_max:
            raise ValueError("algo.exploration_std_min must be in [0, exploration_std_max]")
        if self.target_noise < 0.0 or self.noise_clip < 0.0:
            raise ValueError("algo.target_noise and algo.noise_clip must be >= 0")

    @property
    def steps_per_env(self) -> int:
        """The replay ring's length in steps of each env."""
        return self.buffer_size // self.num_envs


@pytree_dataclass
class FastTD3State:
    """The whole FastTD3 training state.

    Fields:
      params       {"policy", "q", "target_q"}; "q" and "target_q" stack the two critics
      opt_state    {"policy", "q"} optax states
      obs_stats    observation normaliser (of the whole observation)
      buffer       trajectory ring (obs, action in [-1, 1], reward, terminated, done, next_obs)
      env_state    batched env ``State``
      noise_std    (num_envs,) each env's exploration noise scale for its current episode
      rng          (2,) key
      env_steps    () int32
      updates      () int32
    """

    params: dict
    opt_state: dict
    obs_stats: normalizer.RunningStats
    buffer: replay.TrajectoryBuffer
    env_state: State
    noise_std: jax.Array
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array


class DeterministicTanh:
    """A deterministic policy's output squashed by tanh into (-1, 1): the interface ``make_act``
    expects of a distribution. A deterministic policy has no samples, so ``sample_raw`` is its
    mode; exploration noise is added by the learner."""

    @staticmethod
    def mode_raw(out: jax.Array) -> jax.Array:
        return out

    @staticmethod
    def sample_raw(out: jax.Array, key: jax.Array) -> jax.Array:
        del key
        return out

    @staticmethod
    def postprocess(raw: jax.Array) -> jax.Array:
        return jnp.tanh(raw)


class CategoricalCriticPair:
    """Two independent critics evaluated together, each a distribution over fixed atoms:
    ``apply(params, obs, action) -> logits (2, batch, num_atoms)``."""

    def __init__(self, hidden, activation, atoms: jax.Array):
        self.net = MLP(hidden, atoms.shape[0], activation, final_scale=0.01)
        self.atoms = atoms

    def init(self, key, obs, act):
        x = jnp.concatenate([obs, act], -1)
        return jax.vmap(lambda k: self.net.init(k, x))(jax.random.split(key, 2))

    def apply(self, params, obs, act):
        x = jnp.concatenate([obs, act], -1)
        return jax.vmap(lambda p: self.net.apply(p, x))(params)

    def value(self, probs: jax.Array) -> jax.Array:
        """The expected return of distributions (..., num_atoms)."""
        return probs @ self.atoms


def project(probs: jax.Array, reward: jax.Array, discount: jax.Array, atoms: jax.Array) -> jax.Array:
    """The distribution of ``reward + discount * Z`` (Z distributed as ``probs`` over ``atoms``,
    shaped (..., batch, num_atoms)) projected onto the same evenly spaced atoms: each shifted atom's
    mass is split between its two nearest atoms in proportion to closeness, and mass beyond the
    ends lands on the end atoms."""
    v_min, v_max, n = atoms[0], atoms[-1], atoms.shape[0]
    shifted = jnp.clip(reward[:, None] + discount[:, None] * atoms[None], v_min, v_max)
    position = (shifted - v_min) / ((v_max - v_min) / (n - 1))  # (batch, n) in [0, n - 1]
    share = jnp.clip(1.0 - jnp.abs(position[:, :, None] - jnp.arange(n)[None, None]), 0.0, 1.0)
    return jnp.einsum("...bj,bji->...bi", probs, share)


class _Parts(NamedTuple):
    """What FastTD3's pieces share: networks, the action scaling to the env's bounds, normaliser,
    optimisers, batched env functions, and the policy's share of the observation."""

    policy_net: MLP
    q_net: CategoricalCriticPair
    to_env: Callable
    norm: Callable
    opt: dict
    env_reset: Callable
    env_step: Callable
    policy_obs: int


def make_fasttd3(config: FastTD3Config, env: Env, network: NetworkConfig, total_updates: int = 1) -> Learner:
    """Builds FastTD3 for ``env`` (``total_updates`` is unused: the step sizes are constant)."""
    del total_updates
    p = _parts(config, env, network)
    n_new = off_policy.env_steps_per_update(config, env)
    collect, grad_step = _make_collect(config, p), _make_grad_step(config, p)

    def update(state: FastTD3State) -> tuple[FastTD3State, dict]:
        rng, k_collect, k_grad = jax.random.split(state.rng, 3)
        (env_state, noise_std), (steps, done, ep_ret) = collect(state, k_collect)
        buf = replay.append(state.buffer, steps)
        stats = state.obs_stats
        if config.normalize_observations:
            stats = normalizer.update(stats, steps["obs"])
        env_steps = state.env_steps + n_new
        first = state.updates * config.grad_updates_per_update
        counts = first + jnp.arange(config.grad_updates_per_update, dtype=jnp.int32)
        keys = jax.random.split(k_grad, config.grad_updates_per_update)
        (params, opt_state, _, _), info = jax.lax.scan(
            grad_step, (state.params, state.opt_state, stats, buf), (keys, counts)
        )
        ready = (env_steps >= config.learning_starts) & (buf.size >= config.n_step)
        params, opt_state = off_policy.unless_warming_up(
            ready, (params, opt_state), (state.params, state.opt_state)
        )
        actor_steps = info.pop("actor_steps")
        metrics = off_policy.update_metrics(info, done, ep_ret, steps["reward"])
        metrics["loss/actor"] = jnp.sum(info["actor"]) / jnp.maximum(jnp.sum(actor_steps), 1.0)
        metrics["train/buffer_size"] = (buf.size * config.num_envs).astype(jnp.float32)
        new = FastTD3State(
            params=params, opt_state=opt_state, obs_stats=stats, buffer=buf, env_state=env_state,
            noise_std=noise_std, rng=rng, env_steps=env_steps, updates=state.updates + 1,
        )  # fmt: skip
        return new, metrics

    def policy_params(state: FastTD3State) -> PolicyParams:
        return PolicyParams(network=state.params["policy"], obs_stats=state.obs_stats)

    act = make_act(p.policy_net, DeterministicTanh, p.norm, p.to_env, policy_obs=p.policy_obs)

    return Learner(
        init=_make_init(config, p, env.observation_size, env.action_size), update=update,
        policy_params=policy_params, act=act, env_steps_per_update=n_new, num_envs=config.num_envs,
    )  # fmt: skip


def _parts(config: FastTD3Config, env: Env, network: NetworkConfig) -> _Parts:
    """Networks, optimisers and env functions."""

    def optimizer(learning_rate):
        return off_policy.optimizer(learning_rate, config.max_grad_norm, config.weight_decay)

    atoms = jnp.linspace(config.v_min, config.v_max, config.num_atoms, dtype=jnp.float32)
    return _Parts(
        policy_net=MLP(network.policy_hidden, env.action_size, network.activation),
        q_net=CategoricalCriticPair(network.value_hidden, network.activation, atoms),
        to_env=off_policy.to_env_bounds(env),
        norm=observation_normalizer(config.normalize_observations),
        opt={"policy": optimizer(config.actor_learning_rate), "q": optimizer(config.critic_learning_rate)},
        env_reset=jax.vmap(env.reset),
        env_step=jax.vmap(env.step),
        policy_obs=env.policy_observation_size,
    )


def _draw_noise_std(config: FastTD3Config, key: jax.Array) -> jax.Array:
    lo, hi = config.exploration_std_min, config.exploration_std_max
    return jax.random.uniform(key, (config.num_envs,), jnp.float32, lo, hi)


def _make_init(config: FastTD3Config, p: _Parts, obs_size: int, nu: int):
    """``init(key) -> FastTD3State``: networks, optimisers, an empty ring and fresh envs."""

    def init(key: jax.Array) -> FastTD3State:
        k_pi, k_q, k_env, k_noise, k_rng = jax.random.split(key, 5)
        dummy_obs, dummy_act = jnp.zeros((1, obs_size)), jnp.zeros((1, nu))
        q = p.q_net.init(k_q, dummy_obs, dummy_act)
        params = {
            "policy": p.policy_net.init(k_pi, dummy_obs[:, : p.policy_obs]),
            "q": q,
            "target_q": jax.tree.map(jnp.array, q),
        }
        opt_state = {"policy": p.opt["policy"].init(params["policy"]), "q": p.opt["q"].init(params["q"])}
        example = {"obs": jnp.zeros(obs_size), "action": jnp.zeros(nu), "reward": 0.0,
                   "terminated": False, "done": False, "next_obs": jnp.zeros(obs_size)}  # fmt: skip
        zero = jnp.zeros((), jnp.int32)
        return FastTD3State(
            params=params, opt_state=opt_state, obs_stats=normalizer.init(obs_size),
            buffer=replay.init_trajectories(config.steps_per_env, config.num_envs, example),
            env_state=p.env_reset(jax.random.split(k_env, config.num_envs)),
            noise_std=_draw_noise_std(config, k_noise), rng=k_rng, env_steps=zero, updates=zero,
        )  # fmt: skip

    return init


def _make_collect(config: FastTD3Config, p: _Parts):
    """``collect(state, key) -> ((env_state, noise_std), (steps, done, episode_return))``: the
    policy's actions plus each env's exploration noise (uniform random actions before
    ``learning_starts``) for ``env_steps_per_update`` steps, stacked along a leading time axis."""

    def collect(state: FastTD3State, key: jax.Array):
        random_phase = state.env_steps < config.learning_starts

        def one(carry, k):
            env_state, noise_std = carry
            k_noise, k_random, k_std = jax.random.split(k, 3)
            obs = p.norm(state.obs_stats, env_state.obs)[..., : p.policy_obs]
            u = jnp.tanh(p.policy_net.apply(state.params["policy"], obs))
            u = u + noise_std[:, None] * jax.random.normal(k_noise, u.shape, u.dtype)
            u = jnp.where(random_phase, jax.random.uniform(k_random, u.shape, u.dtype, -1.0, 1.0), u)
            u = jnp.clip(u, -1.0, 1.0)
            nxt = p.env_step(env_state, p.to_env(u))
            step = {"obs": env_state.obs, "action": u, "reward": nxt.reward, "terminated": nxt.terminated,
                    "done": nxt.done, "next_obs": nxt.final_obs}  # fmt: skip
            noise_std = jnp.where(nxt.done, _draw_noise_std(config, k_std), noise_std)
            return (nxt, noise_std), (step, nxt.done, nxt.episode_return)

        keys = jax.random.split(key, config.env_steps_per_update)
        return jax.lax.scan(one, (state.env_state, state.noise_std), keys)

    return collect


def _make_losses(config: FastTD3Config, p: _Parts):
    """``critic_loss(q_params, params, batch, key) -> (loss, mean q)`` and
    ``actor_loss(pi_params, params, batch) -> loss``, on batches with normalised observations."""
    atoms = p.q_net.atoms

    def critic_loss(q_params, params, batch, key):
        next_obs = batch["next_obs"]
        next_u = jnp.tanh(p.policy_net.apply(params["policy"], next_obs[..., : p.policy_obs]))
        noise = config.target_noise * jax.random.normal(key, next_u.shape, next_u.dtype)
        next_u = jnp.clip(next_u + jnp.clip(noise, -config.noise_clip, config.noise_clip), -1.0, 1.0)
        next_probs = jax.nn.softmax(p.q_net.apply(params["target_q"], next_obs, next_u), axis=-1)
        target = project(next_probs, batch["reward"] * config.reward_scaling, batch["discount"], atoms)
        if config.clipped_double_q:
            values = p.q_net.value(target)  # (2, batch)
            smaller = jnp.where((values[0] < values[1])[:, None], target[0], target[1])
            target = jnp.broadcast_to(smaller, target.shape)
        logits = p.q_net.apply(q_params, batch["obs"], batch["action"])
        log_probs = jax.nn.log_softmax(logits, axis=-1)
        loss = -jnp.sum(jnp.mean(jnp.sum(jax.lax.stop_gradient(target) * log_probs, -1), -1))
        return loss, jnp.mean(p.q_net.value(jnp.exp(log_probs)))

    def actor_loss(pi_params, params, batch):
        obs = batch["obs"]
        u = jnp.tanh(p.policy_net.apply(pi_params, obs[..., : p.policy_obs]))
        values = p.q_net.value(jax.nn.softmax(p.q_net.apply(params["q"], obs, u), axis=-1))
        q = jnp.min(values, axis=0) if config.clipped_double_q else jnp.mean(values, axis=0)
        return -jnp.mean(q)

    return critic_loss, actor_loss


def _make_grad_step(config: FastTD3Config, p: _Parts):
    """``grad_step((params, opt_state, stats, buffer), (key, count)) -> (carry, info)``: one
    critic step and target update from a replayed n-step batch, plus an actor step when ``count``
    (the run's critic steps so far) ends a ``policy_delay`` group."""
    critic_loss, actor_loss = _make_losses(config, p)
    opt = p.opt

    def actor_step(params, opt_state, batch):
        loss, g = jax.value_and_grad(actor_loss)(params["policy"], params, batch)
        upd, opt_pi = opt["policy"].update(g, opt_state["policy"], params["policy"])
        return optax.apply_updates(params["policy"], upd), opt_pi, loss

    def grad_step(carry, xs):
        params, opt_state, stats, buf = carry
        key, count = xs
        k_batch, k_q = jax.random.split(key)
        batch = replay.sample_n_step(buf, k_batch, config.batch_size, config.n_step, config.gamma)
        batch = {**batch, "obs": p.norm(stats, batch["obs"]), "next_obs": p.norm(stats, batch["next_obs"])}
        (q_loss, q_mean), g = jax.value_and_grad(critic_loss, has_aux=True)(params["q"], params, batch, k_q)
        upd, opt_q = opt["q"].update(g, opt_state["q"], params["q"])
        q = optax.apply_updates(params["q"], upd)
        params = {**params, "q": q}
        skip = lambda params, opt_state, batch: (params["policy"], opt_state["policy"], jnp.zeros(()))  # noqa: E731
        act_now = count % config.policy_delay == config.policy_delay - 1
        policy, opt_pi, pi_loss = jax.lax.cond(act_now, actor_step, skip, params, opt_state, batch)
        target_q = optax.incremental_update(q, params["target_q"], config.tau)
        params = {"policy": policy, "q": q, "target_q": target_q}
        took = act_now.astype(jnp.float32)
        info = {"critic": q_loss, "actor": pi_loss, "q_mean": q_mean, "actor_steps": took}
        return (params, {"policy": opt_pi, "q": opt_q}, stats, buf), info

    return grad_step
