"""Soft Actor-Critic (Haarnoja et al., 2018, with the learned temperature of the 2019 version),
fused with the simulator.

``update`` steps all ``num_envs`` envs ``env_steps_per_update`` times with the current policy
(uniform random actions during the first ``learning_starts`` env steps), writes the transitions
into the on-device replay buffer, then takes ``grad_updates_per_update`` gradient steps on twin
critics, the actor and the temperature, with Polyak-averaged target critics. The buffer lives
in the training state, so it is checkpointed and a resumed run is exact. Targets bootstrap from
``final_obs`` with ``1 - terminated`` (time-limit truncation is not a terminal state).
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
from fastrl.agents.networks import MLP, NetworkConfig, TanhGaussian
from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.physics.dataclass import pytree_dataclass


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """SAC hyperparameters (``algo=sac``).

    Fields:
      num_envs                 environments stepped in parallel
      env_steps_per_update     steps of every env per update (num_envs * this transitions)
      grad_updates_per_update  gradient steps per update (the replay ratio)
      batch_size               transitions per gradient step
      buffer_size              replay capacity (transitions)
      learning_starts          env steps of uniform random actions before learning
      learning_rate            Adam step size of actor, critics and temperature
      gamma                    discount
      tau                      Polyak rate of the target critics
      init_alpha               initial temperature
      target_entropy           None: -action_size
      reward_scaling           rewards are multiplied by this in the critic target
      normalize_observations   learn running observation statistics and normalise inputs
      max_grad_norm            global gradient-norm clip (None: off)
    """

    num_envs: int = 128
    env_steps_per_update: int = 1
    grad_updates_per_update: int = 16
    batch_size: int = 256
    buffer_size: int = 1_000_000
    learning_starts: int = 10_000
    learning_rate: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    init_alpha: float = 1.0
    target_entropy: float | None = None
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    max_grad_norm: float | None = None

    def __post_init__(self):
        for name in (
            "num_envs",
            "env_steps_per_update",
            "grad_updates_per_update",
            "batch_size",
            "buffer_size",
        ):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"algo.{name}={getattr(self, name)} must be >= 1")
        if self.buffer_size < self.num_envs * self.env_steps_per_update:
            raise ValueError(
                f"algo.buffer_size={self.buffer_size} is smaller than one update's transitions "
                f"(num_envs * env_steps_per_update = {self.num_envs * self.env_steps_per_update})"
            )
        if not 0.0 < self.tau <= 1.0 or not 0.0 < self.gamma <= 1.0:
            raise ValueError("algo.tau and algo.gamma must be in (0, 1]")


@pytree_dataclass
class SACState:
    """The whole SAC training state.

    Fields:
      params       {"policy", "q", "target_q", "log_alpha"}
      opt_state    {"policy", "q", "alpha"} optax states
      obs_stats    observation normaliser
      buffer       replay buffer (obs, action in [-1, 1], reward, discount, next_obs)
      env_state    batched env ``State``
      rng          (2,) key
      env_steps    () int32
      updates      () int32
    """

    params: dict
    opt_state: dict
    obs_stats: normalizer.RunningStats
    buffer: replay.ReplayBuffer
    env_state: State
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array


class _QPair:
    """Two independent Q networks evaluated together: (obs, action) -> (2, batch)."""

    def __init__(self, hidden, activation):
        self.net = MLP(hidden, 1, activation, final_scale=1.0)

    def init(self, key, obs, act):
        k1, k2 = jax.random.split(key)
        x = jnp.concatenate([obs, act], -1)
        return {"q1": self.net.init(k1, x), "q2": self.net.init(k2, x)}

    def apply(self, params, obs, act):
        x = jnp.concatenate([obs, act], -1)
        return jnp.stack([self.net.apply(params["q1"], x)[..., 0], self.net.apply(params["q2"], x)[..., 0]])


class _Parts(NamedTuple):
    """What the pieces of SAC share: networks, the [-1, 1] action distribution and its scaling to
    the env's bounds, normaliser, optimisers, batched env functions and the target entropy."""

    policy_net: MLP
    q_net: _QPair
    dist: TanhGaussian
    to_env: Callable
    norm: Callable
    opt: dict
    env_reset: Callable
    env_step: Callable
    target_entropy: float


def make_sac(config: SACConfig, env: Env, network: NetworkConfig, total_updates: int = 1) -> Learner:
    """Builds SAC for ``env`` (``total_updates`` is unused: SAC keeps a constant step size)."""
    del total_updates
    p = _parts(config, env, network)
    n_new = off_policy.env_steps_per_update(config, env)
    collect, grad_step = _make_collect(config, p), _make_grad_step(config, p)

    def update(state: SACState) -> tuple[SACState, dict]:
        rng, k_collect, k_grad = jax.random.split(state.rng, 3)
        env_state, (tr, done, ep_ret) = collect(state, k_collect)
        flat = jax.tree.map(lambda x: x.reshape((n_new,) + x.shape[2:]), tr)
        buf = replay.insert(state.buffer, flat)
        stats = (
            normalizer.update(state.obs_stats, tr["obs"])
            if config.normalize_observations
            else state.obs_stats
        )
        env_steps = state.env_steps + n_new
        keys = jax.random.split(k_grad, config.grad_updates_per_update)
        (params, opt_state, _, _), info = jax.lax.scan(
            grad_step, (state.params, state.opt_state, stats, buf), keys
        )
        ready = (env_steps >= config.learning_starts) & (buf.size >= config.batch_size)
        params, opt_state = off_policy.unless_warming_up(
            ready, (params, opt_state), (state.params, state.opt_state)
        )
        metrics = off_policy.update_metrics(info, done, ep_ret, tr["reward"])
        metrics["train/buffer_size"] = buf.size.astype(jnp.float32)
        new = SACState(
            params=params, opt_state=opt_state, obs_stats=stats, buffer=buf, env_state=env_state, rng=rng,
            env_steps=env_steps, updates=state.updates + 1,
        )  # fmt: skip
        return new, metrics

    def policy_params(state: SACState) -> PolicyParams:
        return PolicyParams(network=state.params["policy"], obs_stats=state.obs_stats)

    act = make_act(p.policy_net, p.dist, p.norm, p.to_env)

    return Learner(
        init=_make_init(config, p, env.observation_size, env.action_size), update=update,
        policy_params=policy_params, act=act, env_steps_per_update=n_new, num_envs=config.num_envs,
    )  # fmt: skip


def _parts(config: SACConfig, env: Env, network: NetworkConfig) -> _Parts:
    """Networks, distribution, optimisers and env functions."""
    nu = env.action_size

    def optimizer():
        return off_policy.optimizer(config.learning_rate, config.max_grad_norm)

    return _Parts(
        policy_net=MLP(network.policy_hidden, 2 * nu, network.activation),
        q_net=_QPair(network.value_hidden, network.activation),
        dist=TanhGaussian(jnp.full(nu, -1.0), jnp.full(nu, 1.0)),  # actions in [-1, 1], then scaled
        to_env=off_policy.to_env_bounds(env),
        norm=observation_normalizer(config.normalize_observations),
        opt={"policy": optimizer(), "q": optimizer(), "alpha": optax.adam(config.learning_rate)},
        env_reset=jax.vmap(env.reset),
        env_step=jax.vmap(env.step),
        target_entropy=-float(nu) if config.target_entropy is None else config.target_entropy,
    )


def _make_init(config: SACConfig, p: _Parts, obs_size: int, nu: int):
    """``init(key) -> SACState``: networks, optimisers, an empty replay buffer and fresh envs."""

    def init(key: jax.Array) -> SACState:
        k_pi, k_q, k_env, k_rng = jax.random.split(key, 4)
        dummy_obs, dummy_act = jnp.zeros((1, obs_size)), jnp.zeros((1, nu))
        q = p.q_net.init(k_q, dummy_obs, dummy_act)
        params = {
            "policy": p.policy_net.init(k_pi, dummy_obs),
            "q": q,
            "target_q": jax.tree.map(jnp.array, q),
            "log_alpha": jnp.log(jnp.asarray(config.init_alpha, jnp.float32)),
        }
        opt_state = {
            "policy": p.opt["policy"].init(params["policy"]),
            "q": p.opt["q"].init(params["q"]),
            "alpha": p.opt["alpha"].init(params["log_alpha"]),
        }
        example = {"obs": jnp.zeros(obs_size), "action": jnp.zeros(nu), "reward": 0.0, "discount": 0.0,
                   "next_obs": jnp.zeros(obs_size)}  # fmt: skip
        zero = jnp.zeros((), jnp.int32)
        return SACState(
            params=params, opt_state=opt_state, obs_stats=normalizer.init(obs_size),
            buffer=replay.init(config.buffer_size, example),
            env_state=p.env_reset(jax.random.split(k_env, config.num_envs)), rng=k_rng,
            env_steps=zero, updates=zero,
        )  # fmt: skip

    return init


def _make_collect(config: SACConfig, p: _Parts):
    """``collect(state, key) -> (env_state, (transitions, done, episode_return))``: the policy's
    samples (uniform random actions before ``learning_starts``) for ``env_steps_per_update`` steps."""

    def collect(state: SACState, key: jax.Array):
        random_phase = state.env_steps < config.learning_starts

        def one(env_state, k):
            k1, k2 = jax.random.split(k)
            out = p.policy_net.apply(state.params["policy"], p.norm(state.obs_stats, env_state.obs))
            u = p.dist.postprocess(p.dist.sample_raw(out, k1))
            u = jnp.where(random_phase, jax.random.uniform(k2, u.shape, u.dtype, -1.0, 1.0), u)
            nxt = p.env_step(env_state, p.to_env(u))
            discount = 1.0 - nxt.terminated.astype(jnp.float32)
            tr = {"obs": env_state.obs, "action": u, "reward": nxt.reward, "discount": discount,
                  "next_obs": nxt.final_obs}  # fmt: skip
            return nxt, (tr, nxt.done, nxt.episode_return)

        keys = jax.random.split(key, config.env_steps_per_update)
        return jax.lax.scan(one, state.env_state, keys)

    return collect


def _make_losses(config: SACConfig, p: _Parts):
    """``critic_loss(q_params, params, stats, batch, key) -> (loss, mean q)`` and
    ``actor_loss(pi_params, params, stats, batch, key) -> (loss, log_prob)``."""

    def critic_loss(q_params, params, stats, batch, key):
        obs, next_obs = p.norm(stats, batch["obs"]), p.norm(stats, batch["next_obs"])
        out = p.policy_net.apply(params["policy"], next_obs)
        raw = p.dist.sample_raw(out, key)
        next_u = p.dist.postprocess(raw)
        next_q = jnp.min(p.q_net.apply(params["target_q"], next_obs, next_u), axis=0)
        alpha = jnp.exp(params["log_alpha"])
        soft = next_q - alpha * p.dist.log_prob(out, raw)
        target = batch["reward"] * config.reward_scaling + config.gamma * batch["discount"] * soft
        q = p.q_net.apply(q_params, obs, batch["action"])
        loss = jnp.mean((q - jax.lax.stop_gradient(target)[None]) ** 2)
        return loss, jnp.mean(q)

    def actor_loss(pi_params, params, stats, batch, key):
        obs = p.norm(stats, batch["obs"])
        out = p.policy_net.apply(pi_params, obs)
        raw = p.dist.sample_raw(out, key)
        log_prob = p.dist.log_prob(out, raw)
        q = jnp.min(p.q_net.apply(params["q"], obs, p.dist.postprocess(raw)), axis=0)
        alpha = jnp.exp(params["log_alpha"])
        return jnp.mean(alpha * log_prob - q), log_prob

    return critic_loss, actor_loss


def _make_grad_step(config: SACConfig, p: _Parts):
    """``grad_step((params, opt_state, stats, buffer), key) -> (carry, info)``: one critic, actor,
    temperature and target-network update from a replayed batch."""
    critic_loss, actor_loss = _make_losses(config, p)
    opt = p.opt

    def grad_step(carry, key):
        params, opt_state, stats, buf = carry
        k_batch, k_q, k_pi = jax.random.split(key, 3)
        batch = replay.sample(buf, k_batch, config.batch_size)
        (q_loss, q_mean), g = jax.value_and_grad(critic_loss, has_aux=True)(
            params["q"], params, stats, batch, k_q
        )
        upd, opt_q = opt["q"].update(g, opt_state["q"], params["q"])
        q = optax.apply_updates(params["q"], upd)
        params = {**params, "q": q}
        (pi_loss, log_prob), g = jax.value_and_grad(actor_loss, has_aux=True)(
            params["policy"], params, stats, batch, k_pi
        )
        upd, opt_pi = opt["policy"].update(g, opt_state["policy"], params["policy"])
        policy = optax.apply_updates(params["policy"], upd)
        entropy_gap = jax.lax.stop_gradient(-jnp.mean(log_prob) - p.target_entropy)
        a_grad = entropy_gap  # d/dlog_alpha of -log_alpha * (log_prob + target) averaged
        upd, opt_a = opt["alpha"].update(a_grad, opt_state["alpha"], params["log_alpha"])
        log_alpha = optax.apply_updates(params["log_alpha"], upd)
        target_q = optax.incremental_update(q, params["target_q"], config.tau)
        params = {"policy": policy, "q": q, "target_q": target_q, "log_alpha": log_alpha}
        info = {"critic": q_loss, "actor": pi_loss, "alpha": jnp.exp(log_alpha), "q_mean": q_mean,
                "entropy": -jnp.mean(log_prob)}  # fmt: skip
        return (params, {"policy": opt_pi, "q": opt_q, "alpha": opt_a}, stats, buf), info

    return grad_step
