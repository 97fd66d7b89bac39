"""Proximal Policy Optimization (Schulman et al., 2017), fused with the simulator.

``update`` is one PPO iteration as a pure function of the whole training state: a rollout of
``unroll_length`` steps of ``num_envs`` environments (a ``lax.scan`` over ``vmap(env.step)``),
observation-normaliser update, generalised advantage estimation, then ``update_epochs`` passes
of ``num_minibatches`` clipped-objective SGD steps. Nothing leaves the device; the runner
loops ``update`` (``fori_loop``) inside one compiled program.

Departures from the paper, all common practice (CleanRL, Brax): a tanh-squashed Gaussian policy
with a state-dependent scale; truncation-aware bootstrapping, i.e. a time-limit cut adds
``gamma * V(final_obs)`` instead of treating the cut as a terminal state; optional value
clipping; advantage normalisation per minibatch; global gradient-norm clipping.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.sharding import Mesh

from fastrl.agents import normalizer
from fastrl.agents.base import Learner, PolicyParams, make_act, observation_normalizer
from fastrl.agents.networks import MLP, NetworkConfig, TanhGaussian
from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.physics.dataclass import pytree_dataclass
from fastrl.runtime.devices import DEVICE_AXIS, over_devices


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters (Hydra group ``algo``, ``algo=ppo``).

    Fields:
      num_envs                environments stepped in parallel
      unroll_length           steps per environment per iteration (batch = num_envs * unroll_length)
      num_minibatches         minibatches per epoch (must divide the batch)
      update_epochs           passes over the batch per iteration
      learning_rate           Adam step size (initial value if ``lr_schedule`` is linear)
      lr_schedule             "constant" or "linear" (decays to 0 over the run's updates)
      gamma                   discount
      gae_lambda              GAE lambda
      clip_eps                policy ratio clipping
      value_clip_eps          value clipping around the old value (None: off)
      entropy_cost            entropy bonus weight
      entropy_estimate        "gaussian": the pre-tanh Gaussian's entropy (closed form);
                              "squashed": the action's entropy after tanh, estimated at one
                              reparameterised sample per step (Brax's choice)
      init_std                the policy's pre-tanh scale at initialisation (None: 0.694, i.e.
                              softplus(0)); smaller starts with gentler exploration and smaller
                              control costs
      value_cost              value loss weight
      max_grad_norm           global gradient-norm clip
      reward_scaling          rewards are multiplied by this in the losses
      normalize_observations  learn running observation statistics and normalise inputs
      normalize_advantages    standardise advantages per minibatch
      recompute_advantages    recompute values and GAE with the current value network before
                              every epoch (Andrychowicz et al. 2021, "What matters in on-policy
                              RL"; Brax does it per minibatch), instead of once per iteration
                              from the network that collected the data. Costs one value-network
                              forward pass over the batch per epoch. Truncated steps keep the
                              bootstrap value computed at collection time.
    """

    num_envs: int = 1024
    unroll_length: int = 10
    num_minibatches: int = 32
    update_epochs: int = 4
    learning_rate: float = 3e-4
    lr_schedule: str = "constant"
    gamma: float = 0.97
    gae_lambda: float = 0.95
    clip_eps: float = 0.3
    value_clip_eps: float | None = None
    entropy_cost: float = 1e-2
    entropy_estimate: str = "gaussian"
    init_std: float | None = None
    value_cost: float = 0.5
    max_grad_norm: float = 1.0
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    normalize_advantages: bool = True
    recompute_advantages: bool = False

    def __post_init__(self):
        for name in ("num_envs", "unroll_length", "num_minibatches", "update_epochs"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"algo.{name}={getattr(self, name)} must be >= 1")
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"algo.num_envs * algo.unroll_length = {self.batch_size} is not divisible by "
                f"algo.num_minibatches={self.num_minibatches}; pick num_minibatches among the "
                f"divisors of {self.batch_size} or change num_envs/unroll_length"
            )
        if self.lr_schedule not in ("constant", "linear"):
            raise ValueError(f"algo.lr_schedule={self.lr_schedule!r}; choose 'constant' or 'linear'")
        if self.entropy_estimate not in ("gaussian", "squashed"):
            raise ValueError(
                f"algo.entropy_estimate={self.entropy_estimate!r}; choose 'gaussian' or 'squashed'"
            )
        if not 0.0 < self.gamma <= 1.0 or not 0.0 <= self.gae_lambda <= 1.0:
            raise ValueError("algo.gamma must be in (0, 1] and algo.gae_lambda in [0, 1]")
        if self.learning_rate <= 0:
            raise ValueError(f"algo.learning_rate={self.learning_rate} must be > 0")

    @property
    def batch_size(self) -> int:
        return int(self.num_envs) * int(self.unroll_length)

    def splits_evenly(self, devices: int) -> bool:
        """Whether the env batch and the minibatch divide evenly over ``devices`` devices."""
        return self.num_envs % devices == 0 and self.minibatch_size % devices == 0

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches


@pytree_dataclass
class PPOState:
    """The whole training state (a checkpoint is exactly this pytree).

    Fields:
      params      {"policy": ..., "value": ...} network weights
      opt_state   optax state of the joint optimiser
      obs_stats   observation normaliser
      env_state   batched env ``State`` (num_envs, ...)
      rng         (2,) key
      env_steps   () int32 environment steps so far
      updates     () int32 PPO iterations so far
    """

    params: dict
    opt_state: optax.OptState
    obs_stats: normalizer.RunningStats
    env_state: State
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array


class Transition(NamedTuple):
    obs: jax.Array
    raw_action: jax.Array
    log_prob: jax.Array
    reward: jax.Array
    terminated: jax.Array
    done: jax.Array
    final_obs: jax.Array
    episode_return: jax.Array


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimates over a time-major rollout.

    Args:
      rewards, values, terminated, done: (T, N) per step; ``done`` = terminated or truncated.
      next_values: (T, N) value of the observation that followed each step in the same episode
        (``final_obs``), so a truncated episode bootstraps from its true last state.
      gamma, lam: discount and GAE lambda.
    Returns:
      advantages (T, N) and value targets (T, N) = advantages + values.
    """
    not_term = 1.0 - terminated.astype(values.dtype)
    not_done = 1.0 - done.astype(values.dtype)
    deltas = rewards + gamma * not_term * next_values - values

    def back(carry, x):
        delta, cont = x
        adv = delta + gamma * lam * cont * carry
        return adv, adv

    _, adv = jax.lax.scan(back, jnp.zeros_like(values[0]), (deltas, not_done), reverse=True)
    return adv, adv + values


class _Parts(NamedTuple):
    """What the pieces of PPO share: networks, action distribution, optimiser, normaliser, the
    batched env functions and the device axis (None without a mesh)."""

    policy_net: MLP
    value_net: MLP
    dist: TanhGaussian
    optimizer: optax.GradientTransformation
    norm: Callable
    env_reset: Callable
    env_step: Callable
    axis: str | None
    policy_obs: int  # the observation's leading entries the policy reads (the critic reads all)


def env_steps_per_update(config: PPOConfig, env: Env) -> int:
    """Env steps one update takes: ``unroll_length`` steps of each of ``num_envs`` envs."""
    del env
    return config.batch_size


def make_ppo(
    config: PPOConfig, env: Env, network: NetworkConfig, total_updates: int = 1, mesh: Mesh | None = None
) -> Learner:
    """Builds PPO for ``env``.

    Args:
      config: hyperparameters.
      env: a fastrl env (batched here with vmap).
      network: network sizes.
      total_updates: iterations the run will take (sets the linear learning-rate decay).
      mesh: a one-axis mesh (``fastrl.runtime.devices.DEVICE_AXIS``) to split the work over: each
        device steps its slice of the environments and computes the gradient of its half of every minibatch;
        gradients are averaged, so the result is the one-device one up to summation order. The
        env batch and the minibatches must divide evenly. None: no explicit split.
    """
    if mesh is not None and not config.splits_evenly(mesh.devices.size):
        raise ValueError(
            f"algo.num_envs={config.num_envs} and the minibatch size {config.minibatch_size} must "
            f"divide evenly over {mesh.devices.size} devices"
        )
    obs_size = env.observation_size
    p = _parts(config, env, network, total_updates, mesh)
    rollout = _make_rollout(config, p)
    sgd = _make_sgd(config, p, _make_minibatch_grads(config, p, mesh), env.action_size)

    init = _make_init(config, p, obs_size)

    def update(state: PPOState) -> tuple[PPOState, dict]:
        rng, k_roll, k_sgd = jax.random.split(state.rng, 3)
        env_state, traj = rollout(state, k_roll)
        stats = state.obs_stats
        if config.normalize_observations:
            stats = normalizer.update(stats, traj.obs)
        state = state.replace(obs_stats=stats)
        # Values of the observations that ended episodes (final_obs where done), at collection.
        final_values = p.value_net.apply(state.params["value"], p.norm(stats, traj.final_obs))[..., 0]
        params, opt_state, info = sgd(state, traj, final_values, k_sgd)
        new = PPOState(
            params=params, opt_state=opt_state, obs_stats=stats, env_state=env_state, rng=rng,
            env_steps=state.env_steps + config.batch_size, updates=state.updates + 1,
        )  # fmt: skip
        return new, _metrics(info, traj, env_state)

    def policy_params(state: PPOState) -> PolicyParams:
        return PolicyParams(network=state.params["policy"], obs_stats=state.obs_stats)

    act = make_act(p.policy_net, p.dist, p.norm, policy_obs=p.policy_obs)

    return Learner(
        init=init, update=update, policy_params=policy_params, act=act,
        env_steps_per_update=env_steps_per_update(config, env), num_envs=config.num_envs,
    )  # fmt: skip


def _make_init(config: PPOConfig, p: _Parts, obs_size: int):
    """``init(key) -> PPOState``: fresh policy and value networks, optimiser state and
    observation statistics, and ``num_envs`` new episodes."""

    def init(key: jax.Array) -> PPOState:
        k_pol, k_val, k_env, k_rng = jax.random.split(key, 4)
        dummy = jnp.zeros((1, obs_size))
        params = {
            "policy": p.policy_net.init(k_pol, dummy[:, : p.policy_obs]),
            "value": p.value_net.init(k_val, dummy),
        }
        env_state = p.env_reset(jax.random.split(k_env, config.num_envs))
        zero = jnp.zeros((), jnp.int32)
        return PPOState(
            params=params, opt_state=p.optimizer.init(params), obs_stats=normalizer.init(obs_size),
            env_state=env_state, rng=k_rng, env_steps=zero, updates=zero,
        )  # fmt: skip

    return init


def _parts(
    config: PPOConfig, env: Env, network: NetworkConfig, total_updates: int, mesh: Mesh | None
) -> _Parts:
    """Networks, distribution, optimiser (with its learning-rate schedule) and env functions."""
    nu = env.action_size
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    steps_per_update = config.update_epochs * config.num_minibatches
    if config.lr_schedule == "linear":
        lr = optax.linear_schedule(config.learning_rate, 0.0, max(1, total_updates * steps_per_update))
    else:
        lr = config.learning_rate
    return _Parts(
        policy_net=MLP(network.policy_hidden, 2 * nu, network.activation),
        value_net=MLP(network.value_hidden, 1, network.activation, final_scale=1.0),
        dist=TanhGaussian(low, high, config.init_std),
        optimizer=optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(lr)),
        norm=observation_normalizer(config.normalize_observations),
        env_reset=jax.vmap(env.reset),
        env_step=over_devices(jax.vmap(env.step), mesh),
        axis=None if mesh is None else DEVICE_AXIS,
        policy_obs=env.policy_observation_size,
    )


def _make_rollout(config: PPOConfig, p: _Parts):
    """``rollout(state, key) -> (env_state, traj)``: ``unroll_length`` steps of the policy's samples."""

    def rollout(state: PPOState, key: jax.Array):
        def one(env_state, k):
            obs = p.norm(state.obs_stats, env_state.obs)
            out = p.policy_net.apply(state.params["policy"], obs[..., : p.policy_obs])
            raw = p.dist.sample_raw(out, k)
            nxt = p.env_step(env_state, p.dist.postprocess(raw))
            tr = Transition(
                obs=env_state.obs, raw_action=raw, log_prob=p.dist.log_prob(out, raw), reward=nxt.reward,
                terminated=nxt.terminated, done=nxt.done, final_obs=nxt.final_obs,
                episode_return=nxt.episode_return,
            )  # fmt: skip
            return nxt, tr

        return jax.lax.scan(one, state.env_state, jax.random.split(key, config.unroll_length))

    return rollout


def _make_loss(config: PPOConfig, p: _Parts):
    """``loss_fn(params, stats, batch, adv, targets, old_values, ent_noise) -> (total, stats)``:
    the clipped surrogate, value and entropy losses of a minibatch."""

    def global_mean(x):
        """Mean over the minibatch (all devices' shares of it, which are of equal size)."""
        m = jnp.mean(x)
        return m if p.axis is None else jax.lax.pmean(m, p.axis)

    def loss_fn(params, stats, batch, adv, targets, old_values, ent_noise):
        # Under a mesh this sees one device's share of the minibatch: its losses are means over
        # that share, and the gradients are averaged across devices (``minibatch_grads``).
        obs = p.norm(stats, batch.obs)
        out = p.policy_net.apply(params["policy"], obs[..., : p.policy_obs])
        log_prob = p.dist.log_prob(out, batch.raw_action)
        ratio = jnp.exp(log_prob - batch.log_prob)
        if config.normalize_advantages:
            mean = global_mean(adv)
            adv = (adv - mean) / (jnp.sqrt(global_mean((adv - mean) ** 2)) + 1e-8)
        clipped = jnp.clip(ratio, 1 - config.clip_eps, 1 + config.clip_eps)
        policy_loss = -jnp.mean(jnp.minimum(ratio * adv, clipped * adv))
        value = p.value_net.apply(params["value"], obs)[..., 0]
        v_loss = (value - targets) ** 2
        if config.value_clip_eps is not None:
            v_clip = old_values + jnp.clip(value - old_values, -config.value_clip_eps, config.value_clip_eps)
            v_loss = jnp.maximum(v_loss, (v_clip - targets) ** 2)
        value_loss = 0.5 * jnp.mean(v_loss)
        if config.entropy_estimate == "squashed":
            entropy = jnp.mean(p.dist.squashed_entropy_at(out, ent_noise))
        else:
            entropy = jnp.mean(p.dist.entropy(out))
        total = policy_loss + config.value_cost * value_loss - config.entropy_cost * entropy
        stats_out = {
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": entropy,
            "approx_kl": jnp.mean((ratio - 1) - jnp.log(ratio)),
            "clip_fraction": jnp.mean(jnp.abs(ratio - 1) > config.clip_eps),
        }
        return total, stats_out

    return loss_fn


def _make_minibatch_grads(config: PPOConfig, p: _Parts, mesh: Mesh | None):
    """``minibatch_grads(params, stats, batch, adv, targets, old_values, ent_noise) -> (grads,
    info)``; under a mesh each device takes its share of the minibatch and the gradients are
    averaged across devices."""
    loss_fn = _make_loss(config, p)

    def minibatch_grads(params, stats, batch, adv, targets, old_values, ent_noise):
        grads, info = jax.grad(loss_fn, has_aux=True)(
            params, stats, batch, adv, targets, old_values, ent_noise
        )
        if p.axis is not None:
            grads, info = jax.lax.pmean((grads, info), p.axis)
        return grads, info

    if mesh is None:
        return minibatch_grads
    replicated = jax.sharding.PartitionSpec()
    split = jax.sharding.PartitionSpec(DEVICE_AXIS)
    return jax.shard_map(
        minibatch_grads, mesh=mesh, in_specs=(replicated, replicated, split, split, split, split, split),
        out_specs=replicated, check_vma=False,
    )  # fmt: skip


def _make_estimate(config: PPOConfig, p: _Parts):
    def estimate(value_params, stats, traj: Transition, final_values: jax.Array):
        """Values, advantages and targets of a rollout under ``value_params``.

        ``final_values`` (T, N): values of each step's ``final_obs``. Where an episode went on,
        the next step's value is read from ``values`` instead, so only the last step of the
        rollout needs one more forward pass, made here.
        """
        value = lambda o: p.value_net.apply(value_params, p.norm(stats, o))[..., 0]  # noqa: E731
        values = value(jnp.concatenate([traj.obs, traj.final_obs[-1:]]))
        next_values = jnp.where(traj.done, final_values, values[1:])
        rewards = traj.reward * config.reward_scaling
        adv, targets = gae(
            rewards, values[:-1], next_values, traj.terminated, traj.done, config.gamma, config.gae_lambda
        )
        return adv, targets, values[:-1]

    return estimate


def _make_sgd(config: PPOConfig, p: _Parts, minibatch_grads, nu: int):
    """``sgd(state, traj, final_values, key) -> (params, opt_state, info)``: ``update_epochs``
    passes of shuffled minibatches over the rollout."""
    estimate = _make_estimate(config, p)

    def sgd(state: PPOState, traj: Transition, final_values: jax.Array, key):
        flatten = lambda x: x.reshape((config.batch_size,) + x.shape[2:])  # noqa: E731
        fixed = None
        if not config.recompute_advantages:
            fixed = estimate(state.params["value"], state.obs_stats, traj, final_values)

        def epoch(carry, k):
            params, opt_state = carry
            adv, targets, values = fixed or estimate(params["value"], state.obs_stats, traj, final_values)
            flat = jax.tree.map(flatten, (traj, adv, targets, values))
            perm = jax.random.permutation(k, config.batch_size)
            split = lambda x: x[perm].reshape((config.num_minibatches, -1) + x.shape[1:])  # noqa: E731
            shuffled = jax.tree.map(split, flat)

            def minibatch(carry, mb):
                params, opt_state = carry
                (batch, adv, targets, old_values), noise = mb
                grads, info = minibatch_grads(params, state.obs_stats, batch, adv, targets, old_values, noise)
                updates, opt_state = p.optimizer.update(grads, opt_state, params)
                info["grad_norm"] = optax.tree.norm(grads)
                return (optax.apply_updates(params, updates), opt_state), info

            return jax.lax.scan(minibatch, (params, opt_state), (shuffled, _entropy_noise(config, k, nu)))

        keys = jax.random.split(key, config.update_epochs)
        (params, opt_state), info = jax.lax.scan(epoch, (state.params, state.opt_state), keys)
        return params, opt_state, jax.tree.map(jnp.mean, info)

    return sgd


def _entropy_noise(config: PPOConfig, k: jax.Array, nu: int) -> jax.Array:
    """(num_minibatches, minibatch_size, nu) normal draws of an epoch (key ``k``), or zero-size.

    Only the squashed entropy estimate samples: one draw per sample of each minibatch, made here
    whole so that a split over devices draws the same numbers.
    """
    if config.entropy_estimate != "squashed":
        return jnp.zeros((config.num_minibatches, config.minibatch_size, 0))
    ent_keys = jax.random.split(jax.random.fold_in(k, 1), config.num_minibatches)
    shape = (config.minibatch_size, nu)
    return jax.vmap(lambda kk: jax.random.normal(kk, shape))(ent_keys)


def _metrics(info: dict, traj: Transition, env_state: State) -> dict[str, jax.Array]:
    """An update's metrics: losses (means over its minibatches), finished episodes, env metrics."""
    done = traj.done.astype(jnp.float32)
    n_done = jnp.sum(done)
    metrics = {f"loss/{k}": v for k, v in info.items()}
    metrics["train/episode_return_sum"] = jnp.sum(traj.episode_return * done)
    metrics["train/episodes"] = n_done
    metrics["train/reward_mean"] = jnp.mean(traj.reward)
    for k, v in env_state.metrics.items():
        metrics[f"env/{k}"] = jnp.mean(v)
    return metrics
