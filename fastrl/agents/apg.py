"""Analytic policy gradients: the return differentiated through fastrl's physics.

Each ``update`` rolls the deterministic policy (plus optional exploration noise) forward for
``horizon`` steps from where the last update left the envs, and takes the gradient of the mean
discounted return over that window with respect to the policy's weights, straight through
``env.step`` (truncated backpropagation through time: the start state carries no gradient).

Failure modes, and what this implementation does about them:
- Exploding gradients over long horizons (the product of step Jacobians grows like the
  system's Lyapunov exponent): short horizons, gradient-norm clipping, and a ``grad_decay``
  that shrinks the gradient flowing back through each step (Xu et al.'s "SHAC"-style
  truncation).
- Contacts make the return piecewise smooth: gradients through impacts are large and
  uninformative. Envs declare ``smooth_gradients``; APG refuses envs without it unless
  ``allow_unsuitable=true``, with an explanation, rather than waste the user's time.
- Non-finite gradients (a diverged env): the update is skipped (masked) and counted.
- An open-loop gradient: cutting it at the observations (treating the policy's inputs as
  constants) hides how each action changes the later actions, so the policy cannot learn
  feedback; on inverted_pendulum it balanced the pole but let the cart drift into the end of its
  rail (best 361-675 of 1000). The window differentiates through the observations too, and a
  test checks its gradient against finite differences.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import optax

from fastrl.agents import normalizer
from fastrl.agents.base import Learner, PolicyParams, make_act, observation_normalizer
from fastrl.agents.networks import MLP, NetworkConfig, TanhGaussian
from fastrl.envs.base import Env
from fastrl.envs.episode import State
from fastrl.physics.dataclass import pytree_dataclass


class UnsuitableEnvError(ValueError):
    """APG asked to learn an env whose gradients are known to be useless."""


@dataclasses.dataclass(frozen=True)
class APGConfig:
    """APG hyperparameters (``algo=apg``).

    Fields:
      num_envs                environments differentiated in parallel
      horizon                 steps per gradient (truncation length)
      learning_rate           Adam step size
      max_grad_norm           global gradient-norm clip
      gamma                   discount inside the window
      grad_decay              factor on the gradient flowing back through each env step (1: exact)
      exploration_noise       std of Gaussian noise on the pre-tanh action (0: deterministic)
      normalize_observations  running observation statistics (not differentiated)
      allow_unsuitable        run even on envs whose gradients are known to be useless
    """

    num_envs: int = 64
    horizon: int = 32
    learning_rate: float = 1e-3
    max_grad_norm: float = 1.0
    gamma: float = 0.99
    grad_decay: float = 1.0
    exploration_noise: float = 0.0
    normalize_observations: bool = True
    allow_unsuitable: bool = False

    def __post_init__(self):
        if self.num_envs < 1 or self.horizon < 1:
            raise ValueError("algo.num_envs and algo.horizon must be >= 1")
        if not 0.0 <= self.grad_decay <= 1.0:
            raise ValueError(f"algo.grad_decay={self.grad_decay} must be in [0, 1]")


@pytree_dataclass
class APGState:
    """Fields: params, opt_state, obs_stats, env_state, rng, env_steps, updates, skipped."""

    params: dict
    opt_state: optax.OptState
    obs_stats: normalizer.RunningStats
    env_state: State
    rng: jax.Array
    env_steps: jax.Array
    updates: jax.Array
    skipped: jax.Array


def _decay_gradient(x, factor: float):
    """Identity forward; multiplies the cotangent by ``factor`` on the way back."""
    if factor == 1.0:
        return x

    def decay(a):
        if not jnp.issubdtype(a.dtype, jnp.floating):
            return a
        return a * factor + jax.lax.stop_gradient(a) * (1 - factor)

    return jax.tree.map(decay, x)


def make_window(config: APGConfig, env_step, policy_net, dist, norm):
    """``window(params, stats, env_state, key) -> (-return, (last_state, (obs, done, ep_return)))``.

    The discounted return of ``config.horizon`` steps from ``env_state`` (which carries no
    gradient), averaged over the batch and negated. The gradient flows through the whole closed
    loop: each action depends on the parameters directly *and* through the state the earlier
    actions led to (observation -> normaliser -> policy), which is what lets the policy learn
    feedback (e.g. to pull a drifting cart back); only the normaliser's statistics are constants.
    """

    def window(params, stats, env_state, key):
        def one(carry, k):
            s, ret, disc = carry
            raw = dist.mode_raw(policy_net.apply(params, norm(stats, s.obs)))
            raw = raw + config.exploration_noise * jax.random.normal(k, raw.shape)
            nxt = env_step(s, dist.postprocess(raw))
            ret = ret + disc * nxt.reward
            disc = disc * config.gamma * (1.0 - nxt.done.astype(ret.dtype)) + nxt.done.astype(ret.dtype)
            return (_decay_gradient(nxt, config.grad_decay), ret, disc), (s.obs, nxt.done, nxt.episode_return)

        ones = jnp.ones(config.num_envs)
        keys = jax.random.split(key, config.horizon)
        (last, ret, _), aux = jax.lax.scan(one, (env_state, 0.0 * ones, ones), keys)
        return -jnp.mean(ret), (last, aux)

    return window


def env_steps_per_update(config: APGConfig, env: Env) -> int:
    """Env steps one update takes: a window of ``horizon`` steps of each of ``num_envs`` envs."""
    del env
    return config.num_envs * config.horizon


def make_apg(config: APGConfig, env: Env, network: NetworkConfig, total_updates: int = 1) -> Learner:
    """Builds APG for ``env``; raises ``UnsuitableEnvError`` for envs without smooth gradients."""
    del total_updates
    _check_suitable(config, env)
    obs_size, nu = env.observation_size, env.action_size
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    dist = TanhGaussian(low, high)
    policy_net = MLP(network.policy_hidden, 2 * nu, network.activation)
    optimizer = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate))
    env_reset, env_step = jax.vmap(env.reset), jax.vmap(env.step)

    norm = observation_normalizer(config.normalize_observations)

    def init(key: jax.Array) -> APGState:
        k_pi, k_env, k_rng = jax.random.split(key, 3)
        params = policy_net.init(k_pi, jnp.zeros((1, obs_size)))
        zero = jnp.zeros((), jnp.int32)
        return APGState(
            params=params, opt_state=optimizer.init(params), obs_stats=normalizer.init(obs_size),
            env_state=env_reset(jax.random.split(k_env, config.num_envs)), rng=k_rng,
            env_steps=zero, updates=zero, skipped=zero,
        )  # fmt: skip

    window = make_window(config, env_step, policy_net, dist, norm)

    def update(state: APGState) -> tuple[APGState, dict]:
        rng, key = jax.random.split(state.rng)
        (loss, (env_state, (obs, done, ep_ret))), grads = jax.value_and_grad(window, has_aux=True)(
            state.params, state.obs_stats, state.env_state, key
        )
        finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
        grads = jax.tree.map(lambda g: jnp.where(finite, g, 0.0), grads)
        upd, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, upd)
        stats = normalizer.update(state.obs_stats, obs) if config.normalize_observations else state.obs_stats
        done = done.astype(jnp.float32)
        metrics = {
            "loss/neg_return": jnp.where(jnp.isfinite(loss), loss, 0.0),
            "loss/grad_norm": optax.tree.norm(grads),
            "train/episode_return_sum": jnp.sum(ep_ret * done),
            "train/episodes": jnp.sum(done),
            "train/skipped_updates": 1.0 - finite.astype(jnp.float32),
        }
        new = APGState(
            params=params, opt_state=opt_state, obs_stats=stats,
            env_state=jax.lax.stop_gradient(env_state), rng=rng,
            env_steps=state.env_steps + config.num_envs * config.horizon, updates=state.updates + 1,
            skipped=state.skipped + (~finite).astype(jnp.int32),
        )  # fmt: skip
        return new, metrics

    def policy_params(state: APGState) -> PolicyParams:
        return PolicyParams(network=state.params, obs_stats=state.obs_stats)

    act = make_act(policy_net, dist, norm)

    return Learner(init=init, update=update, policy_params=policy_params, act=act,
                   env_steps_per_update=env_steps_per_update(config, env),
                   num_envs=config.num_envs)  # fmt: skip


def _check_suitable(config: APGConfig, env: Env) -> None:
    """Raises ``UnsuitableEnvError`` for an env without smooth gradients (unless
    ``config.allow_unsuitable``), saying why and what to use instead."""
    if not env.smooth_gradients and not config.allow_unsuitable:
        raise UnsuitableEnvError(
            f"APG differentiates the return through the simulator, and on '{env.name}' "
            f"{env.gradient_note or 'contacts make those gradients discontinuous and explosive'}; "
            "it would waste your time. Use algo=ppo or algo=sac, or set algo.allow_unsuitable=true "
            "to try anyway."
        )
