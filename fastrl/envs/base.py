"""Functional environments: ``reset(key) -> State`` and ``step(state, action) -> State``.

Every environment is a pure function pair over a pytree ``State``, written for ONE environment
and batched by the caller with ``jax.vmap``. ``step`` auto-resets: when an episode ends
(terminated, truncated by the time limit, or the physics diverged), the returned state already
holds a *fresh, randomised* episode (a new reset drawn from the state's own key, not a replay of
the first reset), while ``final_obs`` keeps the last observation of the finished episode so a
learner can bootstrap truncated episodes. All of it is branch-free (``jnp.where`` on the done
flag), so a batch of environments never diverges in control flow.

Gymnasium semantics are kept where users compare numbers with it: rewards, observations,
termination and reset noise follow Gymnasium's v5 MuJoCo environments, ``terminated`` and
``truncated`` are separate, and derived physics quantities read by rewards (``xpos``...) are
those MuJoCo's ``mjData`` holds after ``mj_step``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fastrl import physics
from fastrl.envs import episode, randomization, wrappers
from fastrl.envs.episode import State
from fastrl.envs.randomization import Randomization
from fastrl.physics import Data, Model

ASSETS = Path(__file__).resolve().parent.parent / "assets"


class Env:
    """Base class: a MuJoCo-style task over fastrl physics with Gymnasium v5 semantics.

    Subclasses set the class attributes and implement ``_observe`` and ``_reward``, and
    ``_reset_qpos_qvel`` unless Gymnasium's usual reset is theirs. Constructor arguments override
    the Gymnasium defaults.

    Args:
      episode_length: steps before ``truncated`` (Gymnasium's ``max_episode_steps``).
      frame_skip: physics steps per env step.
      reward_weights: overrides of ``default_weights`` by term name.
      reset_noise_scale: scale of the reset noise (meaning per env, as in Gymnasium).
      randomization: domain randomisation ranges, over the env's ``default_randomization``
        (off, except in the robot tasks).
      asset: MJCF file (name in ``fastrl/assets`` or a path); defaults to the env's own.
      solver_iterations: constraint-solver iterations (None: the model's default).
      integrator: ``"euler"``, ``"rk4"`` or ``"implicitfast"`` (None: the asset's).
      timestep: physics timestep override (None: the asset's).
      terminate_when_unhealthy: end the episode when the env's health check fails.
      nconmax: contact slots, the most contacts with constraint rows at once (None: the env's
        own, else the scene's or the loader's rule; ``physics.load_mjcf``).
    """

    name: str = ""
    asset: str = ""
    default_frame_skip: int = 1
    default_episode_length: int = 1000
    default_weights: Mapping[str, float] = {}
    default_reset_noise_scale: float = 0.0
    reset_qvel_normal: bool = False  # the usual reset's qvel: s N(0, 1), else U(-s, s)
    default_randomization: Mapping[str, float] = {}
    # The Newton solver's line search: "exact" for fastrl's own scenes (the budgets in
    # fastrl/assets/README.md were measured for it); "mujoco" steps a scene as MuJoCo C does.
    linesearch: str = "exact"
    # MJX's broad-phase caps (``physics.load_mjcf(mjx_caps=...)``), for scenes that set them
    mjx_caps: bool = False
    # contact slots (``physics.load_mjcf(nconmax=...)``); None: the scene's or the loader's rule
    nconmax: int | None = None
    # ``Data`` fields beyond the state and the kinematics (``episode.STATE_FIELDS``,
    # ``episode.KINEMATICS``) that the task's reward reads of the data a step starts from: an
    # auto-reset must carry them into the new episode (``carried_fields``)
    carried_at_reset: tuple[str, ...] = ()
    # Whether the training command line may split this env's batch over one CPU device per core
    # (``fastrl.training.layout.cpu_devices``); False where the step runs slower split than on one
    # device.
    splits_over_devices: bool = True
    # Whether gradients of the return through the physics are informative (smooth dynamics and
    # rewards); analytic policy gradients refuse envs without, explaining ``gradient_note``.
    smooth_gradients: bool = False
    gradient_note: str = ""

    def __init__(
        self,
        *,
        episode_length: int | None = None,
        frame_skip: int | None = None,
        reward_weights: Mapping[str, float] | None = None,
        reset_noise_scale: float | None = None,
        randomization: Randomization | Mapping | None = None,
        asset: str | None = None,
        solver_iterations: int | None = None,
        integrator: str | None = None,
        timestep: float | None = None,
        terminate_when_unhealthy: bool = True,
        nconmax: int | None = None,
    ):
        # ``None`` means the env's default; anything else, 0 included, is the user's value.
        self.episode_length = self.default_episode_length if episode_length is None else episode_length
        self.frame_skip = self.default_frame_skip if frame_skip is None else frame_skip
        for key in ("episode_length", "frame_skip"):
            value = getattr(self, key)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise ValueError(f"{self.name}: {key} must be an integer >= 1, got {value!r}")
            setattr(self, key, int(value))
        weights = dict(self.default_weights)
        for key, value in (reward_weights or {}).items():
            if key not in weights:
                raise ValueError(f"{self.name}: unknown reward term {key!r}; its terms are {sorted(weights)}")
            weights[key] = float(value)
        self.reward_weights = weights
        self.reset_noise_scale = float(
            self.default_reset_noise_scale if reset_noise_scale is None else reset_noise_scale
        )
        if randomization is None or isinstance(randomization, Mapping):  # over the env's defaults
            randomization = Randomization(**{**self.default_randomization, **(randomization or {})})
        self.randomization = randomization
        self.terminate_when_unhealthy = bool(terminate_when_unhealthy)
        path = Path(asset or self.asset)
        if not path.is_absolute() and not path.exists():
            path = ASSETS / path
        if not path.exists():
            raise FileNotFoundError(f"{self.name}: asset {path} does not exist")
        self.asset_path = path  # the MJCF file the model was loaded from
        kw = {} if solver_iterations is None else {"solver_iterations": int(solver_iterations)}
        if nconmax is not None:
            self.nconmax = nconmax
        if self.nconmax is not None:
            kw["nconmax"] = self.nconmax
        model = physics.load_mjcf(
            path, integrator=integrator, linesearch=self.linesearch, mjx_caps=self.mjx_caps, **kw
        )
        if timestep is not None:
            model = model.replace(timestep=jnp.asarray(timestep, model.timestep.dtype))
        self.model: Model = model

    # ---------------------------------------------------------------- subclass interface

    def _reset_qpos_qvel(self, key: jax.Array, model: Model) -> tuple[jax.Array, jax.Array]:
        """(nq,), (nv,) initial state of a new episode (Gymnasium's ``reset_model``); by default
        Gymnasium's usual one: qpos0 + U(-s, s), qvel U(-s, s) or s N(0, 1)
        (``reset_qvel_normal``), with s the ``reset_noise_scale``."""
        s = self.reset_noise_scale
        k1, k2 = jax.random.split(key)
        qpos = model.qpos0 + self.uniform(k1, (model.nq,), s)
        qvel = self.normal(k2, (model.nv,), s) if self.reset_qvel_normal else self.uniform(k2, (model.nv,), s)
        return qpos, qvel

    def _observe(self, model: Model, data: Data) -> jax.Array:
        """(obs_size,) observation of ``data`` (Gymnasium's ``_get_obs``)."""
        raise NotImplementedError

    def _reward(
        self, model: Model, before: Data, after: Data, action: jax.Array
    ) -> tuple[dict, jax.Array, dict]:
        """Weighted reward terms (their sum is the reward), the task's termination flag, and
        extra metrics of one step. Weights come from ``self.reward_weights`` by term name."""
        raise NotImplementedError

    def _control(self, action: jax.Array, task: dict) -> jax.Array:
        """(nu,) the controls an action sets (default: the action itself, as in Gymnasium)."""
        return action

    def _before_physics(self, data: Data, task: dict) -> Data:
        """The state a step's physics starts from (default: ``data`` itself; a task may push the
        robot here, e.g. a kick to its root velocity that ``task`` holds)."""
        return data

    # Goal-conditioned envs override these three instead of ``_observe``/``_reward``; the task
    # (a dict of arrays, e.g. a target position) lives in ``State.task``.

    def _sample_task(self, key: jax.Array, model: Model, data: Data) -> dict:
        """Task variables of a new episode (default: none)."""
        return {}

    def _observe_task(self, model: Model, data: Data, task: dict) -> jax.Array:
        return self._observe(model, data)

    def for_evaluation(self) -> Env:
        """The env a policy is scored on: this one, unless its episodes carry a training aid
        (easier targets in part of its episodes, say), which the returned copy leaves out. Evaluation
        (``agents.make_evaluator``), rollouts and loaded policies use it."""
        return self

    def markers(self, task: dict) -> jax.Array:
        """(M, 3) world positions a viewer should mark (a goal env's targets); (0, 3) by default."""
        return jnp.zeros((0, 3), self.model.qpos0.dtype)

    def _reward_task(
        self, model: Model, before: Data, after: Data, action: jax.Array, task: dict, key: jax.Array
    ) -> tuple[dict, jax.Array, dict, dict]:
        """Like ``_reward``, plus the task for the next step (e.g. a new target once reached,
        drawn from ``key``)."""
        terms, terminated, extra = self._reward(model, before, after, action)
        return terms, terminated, extra, task

    # ---------------------------------------------------------------- public API

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step."""
        return float(self.model.timestep) * self.frame_skip

    @property
    def action_size(self) -> int:
        return self.model.nu

    @property
    def observation_size(self) -> int:
        return self._reset_size(lambda data, task: self._observe_task(self.model, data, task))

    def _reset_size(self, observe: Callable[[Data, dict], jax.Array]) -> int:
        """The length of ``observe(data, task)`` at a reset state, traced abstractly (shapes
        only): run eagerly, the reset would compile every primitive."""

        def run():
            data = self._reset_data(jax.random.PRNGKey(0), self.model)
            return observe(data, self._sample_task(jax.random.PRNGKey(0), self.model, data))

        return int(jax.eval_shape(run).shape[0])

    @property
    def policy_observation_size(self) -> int:
        """The leading entries of the observation that a policy reads. Where an env is made to
        carry privileged state for a learner's critic (asymmetric actor-critic, as Playground's
        ``privileged_state``), the observation appends it after these; otherwise this is
        ``observation_size``."""
        return self.observation_size

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(nu,), (nu,) the ctrlrange of each actuator, as Gymnasium's action space."""
        rng = np.asarray(self.model.actuator_ctrlrange, np.float32)
        return rng[:, 0].copy(), rng[:, 1].copy()

    def reset(self, key: jax.Array) -> State:
        """A fresh episode drawn from ``key`` (one env; vmap over keys for a batch)."""
        key, reset_key, param_key = jax.random.split(key, 3)
        params = randomization.sample(self.randomization, self.model, param_key)
        model = randomization.apply(self.model, params)
        data = self._reset_data(reset_key, model)
        task = self._sample_task(jax.random.fold_in(reset_key, 7), model, data)
        obs = self._observe_task(model, data, task)
        zero = jnp.zeros((), obs.dtype)
        no = jnp.zeros((), bool)
        metrics = {k: zero for k in self.metric_names()}
        return State(
            data=data, obs=obs, reward=zero, terminated=no, truncated=no, final_obs=obs,
            metrics=metrics, episode_return=zero, episode_length=jnp.zeros((), jnp.int32),
            params=params, rng=key, task=task,
        )  # fmt: skip

    def reset_to(self, qpos: jax.Array, qvel: jax.Array, key: jax.Array | None = None) -> State:
        """A state at the given ``qpos``/``qvel`` (e.g. copied from another simulator).

        Args:
          qpos: (nq,) positions; qvel: (nv,) velocities.
          key: key for later auto-resets and randomised parameters (default: PRNGKey(0)).
        """
        state = self.reset(jax.random.PRNGKey(0) if key is None else key)
        model = randomization.apply(self.model, state.params)
        data = physics.make_data(model, qpos=qpos, qvel=qvel)
        data = physics.forward_forces(model, data)
        obs = self._observe_task(model, data, state.task)
        return state.replace(data=data, obs=obs, final_obs=obs)

    def step(self, state: State, action: jax.Array) -> State:
        """Advances one env step (``frame_skip`` physics steps) and auto-resets a done episode.

        Args:
          state: the current state.
          action: (nu,) controls; as in Gymnasium they are not clipped here (the physics clamps
            them to ``ctrlrange``; the control cost sees the raw action).
        Returns:
          The next state. If the episode ended, ``obs``/``data`` already belong to a new
          episode and ``final_obs`` is the finished episode's last observation; of the new
          episode's ``data``, the fields ``carried_fields`` names are filled, the other
          derived ones keep this step's values until the next step recomputes them.
        """
        action = jnp.asarray(action, state.obs.dtype)
        if action.shape != (self.action_size,):  # static: checked while tracing
            raise ValueError(
                f"{self.name}: step takes one env's action of shape ({self.action_size},), got "
                f"{action.shape}; for a batch, jax.vmap(env.step) over states and actions"
            )
        step = wrappers.guard_divergence(self.task_step, self.terminate_when_unhealthy)
        step = wrappers.count_episodes(step, self.episode_length)
        return wrappers.auto_reset(step, self.reset, self.carried_fields)(state, action)

    def task_step(self, state: State, action: jax.Array) -> State:
        """The physics and the task alone: ``frame_skip`` physics steps of the episode's model,
        then the task's reward, termination rule, metrics and observation. ``step`` wraps it
        (``envs.wrappers``); the episode's count, ``truncated``, ``rng`` and ``params`` come
        through unchanged, and ``final_obs`` is the new observation."""
        model = randomization.apply(self.model, state.params)
        before, after, overflow = self._physics(model, state, action)
        task_key = jax.random.fold_in(state.rng, 2)
        terms, terminated, extra, task = self._reward_task(model, before, after, action, state.task, task_key)
        obs = self._observe_task(model, after, task)
        metrics = {f"reward_{k}": v for k, v in terms.items()} | extra
        if physics.contact_budgeted(self.model):  # never silent: what the budgets dropped
            metrics["contact_overflow"] = jnp.max(overflow)
        metrics = {k: jnp.asarray(v, obs.dtype) for k, v in metrics.items()}
        return state.replace(data=after, obs=obs, reward=sum(terms.values()), terminated=terminated,
                             final_obs=obs, metrics=metrics, task=task)  # fmt: skip

    def _physics(self, model: Model, state: State, action: jax.Array) -> tuple[Data, Data, jax.Array]:
        """``frame_skip`` physics steps under the action's controls: the data they start from
        (after the task's ``_before_physics``), the data they end with, and the contacts each
        physics step's budgets dropped, (frame_skip,)."""
        before = self._before_physics(state.data, state.task)

        ctrl = self._control(action, state.task)

        def substep(data, _):
            data = physics.step(model, data, ctrl)
            return data, data.contact_overflow

        after, overflow = jax.lax.scan(substep, before, None, length=self.frame_skip)
        return before, after, overflow

    @property
    def carried_fields(self) -> tuple[str, ...]:
        """The ``Data`` fields an auto-reset takes from the new episode: the state, the
        kinematics, and the task's ``carried_at_reset``. The other derived fields keep the
        finished episode's values until the next step recomputes them (a step recomputes every
        derived field from the state before it reads one), so XLA leaves out the reset's
        computation of them, e.g. the mass matrix, which the step's own compile and run then
        skip."""
        always = episode.STATE_FIELDS + episode.KINEMATICS
        return always + tuple(f for f in self.carried_at_reset if f not in always)

    def metric_names(self) -> list[str]:
        """Names of ``State.metrics`` (fixed per env, so batches have a static structure)."""
        model, key = self.model, jax.random.PRNGKey(0)

        def reward():  # traced abstractly, as observation_size
            data = self._reset_data(key, model)
            action = jnp.zeros(model.nu, data.qpos.dtype)
            task = self._sample_task(key, model, data)
            return self._reward_task(model, data, data, action, task, key)

        terms, _, extra, _ = jax.eval_shape(reward)
        overflow = ["contact_overflow"] if physics.contact_budgeted(model) else []
        return [f"reward_{k}" for k in terms] + list(extra) + ["diverged"] + overflow

    # ---------------------------------------------------------------- helpers

    def _reset_data(self, key: jax.Array, model: Model) -> Data:
        """Data of a new episode with the derived fields ``mj_forward`` gives the observation.

        Smooth dynamics only: at a reset no constraint force acts yet in Gymnasium either
        (``cfrc_ext`` is zero until the first ``mj_step``), and skipping collision and the
        solver keeps the auto-reset cheap, since it is evaluated on every step.
        """
        qpos, qvel = self._reset_qpos_qvel(key, model)
        data = physics.make_data(model, qpos=qpos, qvel=qvel)
        return physics.forward_forces(model, data)

    def uniform(self, key: jax.Array, shape, scale: float) -> jax.Array:
        """Uniform noise in [-scale, scale] in the model's dtype."""
        return jax.random.uniform(key, shape, self.model.qpos0.dtype, -scale, scale)

    def normal(self, key: jax.Array, shape, scale: float) -> jax.Array:
        """Gaussian noise with standard deviation ``scale`` in the model's dtype."""
        return scale * jax.random.normal(key, shape, self.model.qpos0.dtype)

    def body_id(self, name: str) -> int:
        """Index of the body called ``name`` (static)."""
        try:
            return self.model.body_names.index(name)
        except ValueError:
            raise ValueError(f"{self.name}: the model has no body {name!r}") from None

    def __repr__(self) -> str:
        cls = type(self).__name__
        return f"{cls}({self.name!r}, frame_skip={self.frame_skip}, episode_length={self.episode_length})"
