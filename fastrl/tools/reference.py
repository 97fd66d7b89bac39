"""Reference evaluation: a policy scored in MuJoCo C, next to fastrl's own score.

fastrl's evaluation (``agents.make_evaluator``) steps fastrl's JAX physics at the env's settings,
which for training are often cheaper than the asset's (the Ant trains with Euler and 5 solver
iterations where Gymnasium's Ant uses RK4 and MuJoCo's converged solver). A reference score says
what the same policy earns where users compare numbers:

- ``"gymnasium"``: Gymnasium's own ``*-v5`` env (its XML, MuJoCo C, float64) for the standard
  suite, built with the fastrl env's frame skip, episode length, reward weights, reset noise and
  observation options, so the observation layout is the one the policy was trained on.
- ``"mujoco"``: the env's own MJCF stepped by MuJoCo C at the asset's integrator and timestep,
  with fastrl's observation and reward functions evaluated on MuJoCo's state. This is how
  fastrl's own scenes (``fastrl/envs/scenes.py``, no Gymnasium counterpart) are scored, and it
  works for every env.

Each reference episode starts from the very state (and goal) fastrl's evaluation draws for the
same episode from the same key, so the two scores are paired episode by episode. The reference
uses the nominal model: domain randomisation is not reproduced.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl import agents, physics
from fastrl.envs.base import ASSETS, Env
from fastrl.envs.episode import State


@dataclasses.dataclass(frozen=True)
class GymnasiumSpec:
    """How a fastrl env maps onto Gymnasium's v5 env of the same task.

    Fields:
      env_id      Gymnasium id, e.g. ``"Ant-v5"``
      weights     fastrl reward term -> Gymnasium keyword of its weight; a term left out has a
                  fixed weight in Gymnasium (its fastrl weight must stay at the default)
      noise       whether Gymnasium takes ``reset_noise_scale``
      health      whether Gymnasium takes ``terminate_when_unhealthy``
      options     fastrl constructor options passed on under the same name
    """

    env_id: str
    weights: Mapping[str, str]
    noise: bool = True
    health: bool = False
    options: tuple[str, ...] = ()


_FORWARD = {"forward": "forward_reward_weight", "ctrl": "ctrl_cost_weight"}
_HEALTHY = {**_FORWARD, "healthy": "healthy_reward"}

GYMNASIUM: dict[str, GymnasiumSpec] = {
    "ant": GymnasiumSpec(
        "Ant-v5", {**_HEALTHY, "contact": "contact_cost_weight"}, health=True,
        options=("include_cfrc_ext_in_observation",),
    ),
    "halfcheetah": GymnasiumSpec("HalfCheetah-v5", _FORWARD),
    "hopper": GymnasiumSpec("Hopper-v5", _HEALTHY, health=True),
    "walker2d": GymnasiumSpec("Walker2d-v5", _HEALTHY, health=True),
    "humanoid": GymnasiumSpec("Humanoid-v5", {**_HEALTHY, "contact": "contact_cost_weight"}, health=True),
    "humanoidstandup": GymnasiumSpec(
        "HumanoidStandup-v5",
        {"uph": "uph_cost_weight", "ctrl": "ctrl_cost_weight", "impact": "impact_cost_weight"},
    ),
    "swimmer": GymnasiumSpec("Swimmer-v5", _FORWARD),
    "reacher": GymnasiumSpec(
        "Reacher-v5", {"dist": "reward_dist_weight", "ctrl": "reward_control_weight"}, noise=False
    ),
    "pusher": GymnasiumSpec(
        "Pusher-v5",
        {"near": "reward_near_weight", "dist": "reward_dist_weight", "ctrl": "reward_control_weight"},
        noise=False,
    ),
    "inverted_pendulum": GymnasiumSpec("InvertedPendulum-v5", {}),
    "inverted_double_pendulum": GymnasiumSpec("InvertedDoublePendulum-v5", {"alive": "healthy_reward"}),
}  # fmt: skip
SIMULATORS = ("gymnasium", "mujoco")


class Scores(NamedTuple):
    """Per-episode results of an evaluation.

    Fields:
      returns     (episodes,) undiscounted return of each episode
      lengths     (episodes,) its steps (the episode length unless it terminated)
      simulator   which simulator produced them (``"fastrl"``, ``"gymnasium"`` or ``"mujoco"``)
    """

    returns: np.ndarray
    lengths: np.ndarray
    simulator: str

    def summary(self) -> str:
        """``mean +- std (length L)``, as ``python -m fastrl.evaluate`` prints it."""
        return f"{self.returns.mean():.2f} +- {self.returns.std():.2f} (length {self.lengths.mean():.0f})"


def default_simulator(env: Env) -> str:
    """``"gymnasium"`` for the standard suite, else ``"mujoco"``."""
    return "gymnasium" if env.name in GYMNASIUM else "mujoco"


def start_states(env: Env, episodes: int, key: jax.Array) -> State:
    """The (episodes,)-batched initial states fastrl's evaluator draws from ``key``."""
    return jax.jit(jax.vmap(env.reset))(jax.random.split(key, episodes))


def evaluate(
    env: Env,
    policy: Callable[[jax.Array], jax.Array],
    episodes: int,
    key: jax.Array,
    simulator: str | None = None,
    integrator: str | None = None,
) -> Scores:
    """Scores a deterministic policy in the reference simulator.

    Args:
      env: the fastrl env the policy was trained on (its settings define the task).
      policy: ``(batch, obs_size) -> (batch, nu)`` deterministic actions, e.g. ``load_policy``'s.
      episodes: episodes to run, each from the initial state fastrl's evaluator draws for it.
      key: the evaluation key (``jax.random.PRNGKey(seed)``, as ``make_evaluator`` takes).
      simulator: ``"gymnasium"`` or ``"mujoco"`` (default: ``default_simulator(env)``).
      integrator: for ``"mujoco"``, MuJoCo's integrator (``"euler"`` or ``"rk4"``) instead of
        the asset's: MuJoCo C at a run's training physics.
    Returns:
      ``Scores`` of the ``episodes`` episodes, each run until it terminates or reaches
      ``env.episode_length`` steps.
    """
    simulator = simulator or default_simulator(env)
    if simulator not in SIMULATORS:
        raise ValueError(f"simulator={simulator!r}; choose one of {list(SIMULATORS)}")
    start = start_states(env, episodes, key)
    if simulator == "gymnasium" and integrator is not None:
        raise ValueError("Gymnasium's envs keep their own integrator; use simulator='mujoco'")
    sim = GymnasiumBatch(env, start) if simulator == "gymnasium" else MujocoBatch(env, start, integrator)
    policy = jax.jit(policy)
    obs = np.asarray(start.obs)
    returns = np.zeros(episodes)
    lengths = np.zeros(episodes, np.int64)
    alive = np.ones(episodes, bool)
    for _ in range(env.episode_length):
        action = np.asarray(policy(jnp.asarray(obs, start.obs.dtype)), np.float64)
        obs, reward, terminated = sim.step(action, alive)
        returns += np.where(alive, reward, 0.0)
        lengths += alive
        alive &= ~terminated
        if not alive.any():
            break
    return Scores(returns, lengths, simulator)


def fastrl_evaluate(
    env: Env, policy: Callable[[jax.Array], jax.Array], episodes: int, key: jax.Array
) -> Scores:
    """``Scores`` of fastrl's own evaluation (``agents.make_evaluator``) of the same policy."""
    evaluate_fn = jax.jit(agents.make_evaluator(env, lambda _, obs: policy(obs), episodes))
    ret, length, _ = jax.device_get(evaluate_fn(None, key))
    return Scores(np.asarray(ret, np.float64), np.asarray(length), "fastrl")


def physics_label(env: Env) -> str:
    """``"rk4, 7 solver iterations"``: the integrator and solver fastrl steps ``env`` with."""
    integrator = physics.Integrator(env.model.integrator).name.lower()
    return f"{integrator}{_substeps_label(env)}, {env.model.solver_iterations} solver iterations"


def _substeps_label(env: Env) -> str:
    """``" at 0.00375 s x 4"`` where the env's timestep is not the asset's, else ``""``."""
    dt = _timestep_override(env, _compile_asset(env))
    return "" if dt is None else f" at {dt:.6g} s x {env.frame_skip}"


def reference_label(env: Env, simulator: str | None = None, integrator: str | None = None) -> str:
    """What the reference simulator is, e.g. ``"Gymnasium Ant-v5, MuJoCo 3.3.0 C, rk4"``."""
    simulator = simulator or default_simulator(env)
    mj_integrator = _asset_model(env, integrator).opt.integrator
    integrator = mujoco.mjtIntegrator(mj_integrator).name.removeprefix("mjINT_").lower()
    where = f"Gymnasium {GYMNASIUM[env.name].env_id}" if simulator == "gymnasium" else f"{env.name}'s MJCF"
    return f"{where}, MuJoCo {mujoco.__version__} C, {integrator}{_substeps_label(env)}"


def _asset_substeps(env_config, env: Env) -> Env | None:
    """The env at the asset's physics when ``env_config`` only splits the same control step into
    other substeps (the Humanoid's 0.00375 s x 4 for 0.003 s x 5), else None."""
    if env_config.timestep is None and env_config.frame_skip is None:
        return None
    asset = dataclasses.replace(
        env_config, integrator=None, solver_iterations=None, timestep=None, frame_skip=None
    )
    asset_env = asset.make()
    return asset_env if np.isclose(env.dt, asset_env.dt, rtol=1e-6) else None


def reference_env(env_config) -> Env:
    """The env whose reference score stands for a run's (``evaluate``'s ``env`` argument): the
    run's own, or the asset's substeps for a run that splits the same control step differently
    (Gymnasium's envs take no timestep override), as ``compare`` scores it."""
    env = env_config.make()
    resampled = _asset_substeps(env_config, env)
    return env if resampled is None else resampled


def compare(
    env_config,
    policy: Callable[[jax.Array], jax.Array],
    episodes: int,
    seed: int,
    fastrl_scores: Scores | None = None,
) -> dict[str, tuple[str, Scores]]:
    """fastrl's score and the reference score of the same policy over the same episodes.

    When the run's env overrides the asset's physics settings (cheaper ones for training, e.g.
    the Ant's Euler with 5 solver iterations where the asset has RK4), two more scores pair
    each simulator with the other at equal physics: MuJoCo C at the run's integrator, and
    fastrl at the asset's settings. They tell a difference of physics settings from a
    difference of simulators. A run at another timestep with the same control step (the
    Humanoid's Euler at 0.00375 s x 4 for the asset's 0.003 s x 5) is scored at the asset's
    physics in the reference simulator, and by MuJoCo C at the run's.

    Args:
      env_config: the run's ``fastrl.training.config.EnvConfig``.
      policy: ``(batch, obs_size) -> (batch, nu)`` deterministic actions.
      episodes: episodes per score.
      seed: the evaluation seed (``jax.random.PRNGKey(seed)``, as ``python -m fastrl.evaluate``).
      fastrl_scores: fastrl's evaluation at the run's settings if already run (else it is).
    Returns:
      ``{"fastrl": (label, scores), ["mujoco_run": ..., "fastrl_asset": ...,] "reference": ...}``
      in that order, labels naming simulator and physics.
    """
    env, key = env_config.make(), jax.random.PRNGKey(seed)
    if fastrl_scores is None:
        fastrl_scores = fastrl_evaluate(env, policy, episodes, key)
    rows = {"fastrl": (f"fastrl ({physics_label(env)}: the run's)", fastrl_scores)}
    resampled = _asset_substeps(env_config, env)  # the same control step in other substeps
    asset_config = dataclasses.replace(env_config, integrator=None, solver_iterations=None)
    asset_env = resampled
    if resampled is None and asset_config != env_config:
        asset_env = asset_config.make()
    if asset_env is not None:
        integrator = physics.Integrator(env.model.integrator).name.lower()
        if env.model.integrator != asset_env.model.integrator or resampled is not None:
            scores = evaluate(env, policy, episodes, key, "mujoco", integrator)
            rows["mujoco_run"] = (f"MuJoCo C ({reference_label(env, 'mujoco', integrator)})", scores)
        label = f"fastrl ({physics_label(asset_env)}: the asset's)"
        rows["fastrl_asset"] = (label, fastrl_evaluate(asset_env, policy, episodes, key))
    ref_env = env if resampled is None else resampled
    ref = evaluate(ref_env, policy, episodes, key)
    rows["reference"] = (f"reference ({reference_label(ref_env, ref.simulator)})", ref)
    return rows


def side_by_side(rows: dict[str, tuple[str, Scores]]) -> str:
    """``compare``'s scores as aligned lines, then the ratios of their means."""
    width = max(len(label) for label, _ in rows.values())
    lines = [f"{label:<{width}}  {scores.summary()}" for label, scores in rows.values()]
    mean = {key: scores.returns.mean() for key, (_, scores) in rows.items()}
    ratio = lambda a, b: f"{mean[a] / mean[b]:.3f}" if mean[b] else "nan"  # noqa: E731
    episodes = len(rows["reference"][1].returns)
    parts = [f"fastrl / reference {ratio('fastrl', 'reference')}"]
    if "mujoco_run" in rows:
        parts.append(f"at the run's integrator, fastrl / MuJoCo C {ratio('fastrl', 'mujoco_run')}")
    if "fastrl_asset" in rows:
        parts.append(f"at the asset's physics, fastrl / reference {ratio('fastrl_asset', 'reference')}")
    lines.append("; ".join(parts) + f" ({episodes} episodes each, the same initial states)")
    return "\n".join(lines)


# ---------------------------------------------------------------- Gymnasium's own envs


def gymnasium_kwargs(env: Env) -> dict:
    """Keyword arguments for ``gymnasium.make`` that define ``env``'s task in Gymnasium.

    Raises:
      ValueError: for an env outside the standard suite, or a reward weight Gymnasium fixes.
    """
    if env.name not in GYMNASIUM:
        raise ValueError(f"{env.name} has no Gymnasium counterpart; use simulator='mujoco'")
    spec = GYMNASIUM[env.name]
    kwargs = {"max_episode_steps": env.episode_length, "frame_skip": env.frame_skip}
    for term, weight in env.reward_weights.items():
        if term in spec.weights:
            kwargs[spec.weights[term]] = weight
        elif weight != type(env).default_weights[term]:
            raise ValueError(
                f"{env.name}: Gymnasium's {spec.env_id} has no weight for the reward term {term!r} "
                f"(set to {weight}); use simulator='mujoco'"
            )
    if spec.noise:
        kwargs["reset_noise_scale"] = env.reset_noise_scale
    if spec.health:
        kwargs["terminate_when_unhealthy"] = env.terminate_when_unhealthy
    elif not env.terminate_when_unhealthy:
        raise ValueError(f"{env.name}: Gymnasium's {spec.env_id} always terminates; use simulator='mujoco'")
    for option in spec.options:
        kwargs[option] = getattr(env, option)
    return kwargs


class GymnasiumBatch:
    """A batch of Gymnasium v5 envs started from fastrl's initial states; stepped in lockstep."""

    def __init__(self, env: Env, start: State):
        import gymnasium

        spec, kwargs = GYMNASIUM.get(env.name), gymnasium_kwargs(env)
        if _timestep_override(env, _compile_asset(env)) is not None:
            raise ValueError(
                f"{env.name}: Gymnasium's env cannot take a timestep override; use simulator='mujoco'"
            )
        qpos, qvel = np.asarray(start.data.qpos, np.float64), np.asarray(start.data.qvel, np.float64)
        self.envs = []
        for i in range(qpos.shape[0]):
            genv = gymnasium.make(spec.env_id, **kwargs)
            genv.reset(seed=i)  # the state is replaced next; this only starts the episode
            genv.unwrapped.set_state(qpos[i], qvel[i])
            self.envs.append(genv)

    def step(self, action: np.ndarray, alive: np.ndarray):
        """Steps the live envs; returns (E, obs_size) obs, (E,) rewards and terminated flags."""
        obs, reward, terminated = [], np.zeros(len(self.envs)), np.zeros(len(self.envs), bool)
        for i, genv in enumerate(self.envs):
            if alive[i]:
                o, reward[i], terminated[i], _, _ = genv.step(action[i])
                obs.append(o)
            else:
                obs.append(np.zeros_like(obs[-1]) if obs else genv.unwrapped._get_obs())
        return np.stack(obs), reward, terminated


# ---------------------------------------------------------------- the env's MJCF in MuJoCo C


_MJ_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}


def _compile_asset(env: Env) -> mujoco.MjModel:
    """The env's MJCF compiled by MuJoCo, as written."""
    path = Path(env.asset)
    if not path.is_absolute() and not path.exists():
        path = ASSETS / path
    m = mujoco.MjModel.from_xml_path(str(path))
    if (m.nq, m.nv, m.nu) != (env.model.nq, env.model.nv, env.model.nu):
        raise ValueError(f"{env.name}: {path} does not compile to the env's model")
    return m


def _timestep_override(env: Env, m: mujoco.MjModel) -> float | None:
    """The env's timestep where it is not the asset's (beyond float32 rounding), else None."""
    dt = float(env.model.timestep)
    return None if np.isclose(dt, m.opt.timestep, rtol=1e-6, atol=0.0) else dt


def _asset_model(env: Env, integrator: str | None = None) -> mujoco.MjModel:
    """The env's MJCF compiled by MuJoCo, with the env's timestep (and the asset's integrator
    unless ``integrator`` names another)."""
    m = _compile_asset(env)
    m.opt.timestep = _timestep_override(env, m) or m.opt.timestep
    if integrator is not None:
        m.opt.integrator = _MJ_INTEGRATORS[integrator]
    return m


def _observe_reward(env: Env, model: physics.Model, carry: dict, q_last, v_last, q_new, v_new, action):
    """One env step's observation and reward from MuJoCo's states, by fastrl's own functions.

    fastrl's ``Data`` after a step holds the new ``qpos``/``qvel`` and the derived quantities of
    the last substep (its start for Euler, RK4's last stage), contacts and ``efc_force``
    included. Those are rebuilt by one fastrl physics step from MuJoCo's state before its last
    substep; positions and velocities are MuJoCo's.
    """
    data = physics.make_data(model, qpos=q_last, qvel=v_last)
    after = physics.step(model, data, action).replace(qpos=q_new, qvel=v_new)
    task_key = jax.random.fold_in(carry["rng"], 2)
    terms, terminated, _, task = env._reward_task(
        model, carry["data"], after, action, carry["task"], task_key
    )
    obs = env._observe_task(model, after, task)
    carry = {"data": after, "task": task, "rng": jax.random.fold_in(carry["rng"], 1)}
    return carry, obs, sum(terms.values()), terminated & env.terminate_when_unhealthy


class MujocoBatch:
    """A batch of MuJoCo C simulations of the env's MJCF, scored by the env's own functions."""

    def __init__(self, env: Env, start: State, integrator: str | None = None):
        self.mjm = _asset_model(env, integrator)
        self.datas = []
        qpos, qvel = np.asarray(start.data.qpos, np.float64), np.asarray(start.data.qvel, np.float64)
        for i in range(qpos.shape[0]):
            d = mujoco.MjData(self.mjm)
            d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_forward(self.mjm, d)
            self.datas.append(d)
        self.frame_skip = env.frame_skip
        self.dtype = start.obs.dtype
        model = physics.model_from_mujoco(self.mjm)
        fn = lambda carry, *a: _observe_reward(env, model, carry, *a)  # noqa: E731
        self._observe_reward = jax.jit(jax.vmap(fn))
        self.carry = {"data": start.data, "task": start.task, "rng": start.rng}

    def step(self, action: np.ndarray, alive: np.ndarray):
        """Steps every simulation (finished ones too: their results are masked by the caller)."""
        n = len(self.datas)
        q_last, v_last = np.zeros((n, self.mjm.nq)), np.zeros((n, self.mjm.nv))
        q_new, v_new = np.zeros_like(q_last), np.zeros_like(v_last)
        for i, d in enumerate(self.datas):
            d.ctrl[:] = action[i]
            if alive[i]:
                for _ in range(self.frame_skip - 1):
                    mujoco.mj_step(self.mjm, d)
            q_last[i], v_last[i] = d.qpos, d.qvel
            if alive[i]:
                mujoco.mj_step(self.mjm, d)
            q_new[i], v_new[i] = d.qpos, d.qvel
        cast = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
        self.carry, obs, reward, terminated = self._observe_reward(
            self.carry, cast(q_last), cast(v_last), cast(q_new), cast(v_new), cast(action)
        )
        return np.asarray(obs), np.asarray(reward, np.float64), np.asarray(terminated)
