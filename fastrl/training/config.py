"""Typed run configuration, built from Hydra's composed config at the edge (train.py).

Library code never sees OmegaConf: ``RunConfig.from_dict`` turns the plain nested dict into
frozen dataclasses, checking every leaf's type and the learner's batch arithmetic, so a bad
config fails before anything is compiled, with a message naming the key and the fix.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping
from typing import Any

from fastrl import agents, envs
from fastrl.agents.networks import NetworkConfig

__all__ = [
    "CheckpointConfig",
    "ConfigError",
    "EnvConfig",
    "IDENTITY_SECTIONS",
    "IDENTITY_TRAIN_KEYS",
    "LoggerConfig",
    "RunConfig",
    "SECTIONS",
    "TrainConfig",
    "build",
    "defaults",
    "identity_diff",
    "missing_identity_keys",
]


class ConfigError(ValueError):
    """A configuration value that cannot work; the message names the key and the fix."""


def _convert(value: Any, annotation: Any, key: str) -> Any:
    """Checks/converts one leaf against a dataclass annotation (str, already resolved)."""
    ann = annotation.replace(" ", "") if isinstance(annotation, str) else annotation
    optional = isinstance(ann, str) and ann.endswith("|None")
    if optional:
        if value is None:
            return None
        ann = ann[: -len("|None")]
    base = ann.split("[")[0] if isinstance(ann, str) else ann
    fail = ConfigError(f"{key}={value!r} should be of type {annotation}")
    if isinstance(value, float) and not math.isfinite(value) and base in ("int", int, "float", float):
        raise ConfigError(f"{key}={value!r} should be a finite number")
    if base in ("int", int):
        if isinstance(value, bool) or not isinstance(value, int | float) or int(value) != value:
            raise fail
        return int(value)
    if base in ("float", float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise fail
        return float(value)
    if base in ("bool", bool):
        if not isinstance(value, bool):
            raise fail
        return value
    if base in ("str", str):
        if not isinstance(value, str):
            raise fail
        return value
    if base in ("dict", dict):
        if not isinstance(value, Mapping):
            raise fail
        return dict(value)
    if base in ("tuple", tuple):
        if not isinstance(value, list | tuple):
            raise fail
        return tuple(value)
    return value


def build(cls: type, values: Mapping[str, Any], prefix: str, ignore: tuple[str, ...] = ()):
    """Instantiates the frozen dataclass ``cls`` from ``values``, checking names and types."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in values.items():
        if key in ignore:
            continue
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f"; did you mean {prefix}.{close[0]}?" if close else f"; valid keys: {sorted(fields)}"
            raise ConfigError(f"{prefix}.{key} is not an option of {cls.__name__}{hint}")
        kwargs[key] = _convert(value, fields[key].type, f"{prefix}.{key}")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as e:
        raise ConfigError(str(e)) from None


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Budget and cadence of a run (``train.*``).

    Fields:
      total_env_steps     environment steps of the whole run
      updates_per_chunk   learner updates per chunk, the logging cadence (None: sized by time,
                          about ``chunk_seconds`` of training each, measured on the run's chunks)
      chunk_seconds       with updates_per_chunk=None, the training time a chunk aims at
      num_evals           evaluations over the run, evenly spaced in updates, the last at the end
                          (used when eval_every is None)
      eval_every          evaluate every this many chunks and after chunk 1 (0: only at the end;
                          None: the num_evals schedule)
      eval_envs           episodes per evaluation (one per env, deterministic policy)
      stop_after_chunks   stop this invocation after this many chunks (resume continues it)
      max_seconds         stop this invocation once this many seconds have passed since it
                          started, compile, evaluations and saves included: the chunk that
                          reaches it is shortened to end there, then the run is saved (resume
                          continues it). None: no time limit
      stop_at_return      stop the run once every agent's deterministic evaluation return has
                          reached this (status "reached"; None: train the whole budget)
      num_seeds           independent agents (seeds seed, seed+1, ...) trained in ONE program
      vmap_sweep          {float algo option: [values]}: every value x every seed, in one program
                          (see fastrl/training/scale.py); total_env_steps counts per agent
    """

    total_env_steps: int = 10_000_000
    updates_per_chunk: int | None = None
    chunk_seconds: float = 10.0
    num_evals: int = 10
    eval_every: int | None = None
    eval_envs: int = 128
    stop_after_chunks: int | None = None
    max_seconds: float | None = None
    stop_at_return: float | None = None
    num_seeds: int = 1
    vmap_sweep: dict | None = None

    def __post_init__(self):
        if self.total_env_steps < 1 or self.eval_envs < 1 or self.num_evals < 1:
            raise ConfigError("train.total_env_steps, train.eval_envs and train.num_evals must be >= 1")
        if self.updates_per_chunk is not None and self.updates_per_chunk < 1:
            raise ConfigError("train.updates_per_chunk must be >= 1 (or null: chunks sized by time)")
        if not self.chunk_seconds > 0:
            raise ConfigError(f"train.chunk_seconds={self.chunk_seconds} must be > 0")
        if self.eval_every is not None and self.eval_every < 0:
            raise ConfigError("train.eval_every must be >= 0 (or null: the train.num_evals schedule)")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise ConfigError(f"train.max_seconds={self.max_seconds} must be > 0 (or null: no time limit)")
        if self.num_seeds < 1:
            raise ConfigError(f"train.num_seeds={self.num_seeds} must be >= 1")
        only_at_end = self.eval_every == 0 or (self.eval_every is None and self.num_evals == 1)
        if self.stop_at_return is not None and only_at_end:
            which = "train.eval_every=0" if self.eval_every == 0 else "train.num_evals=1"
            raise ConfigError(
                f"train.stop_at_return={self.stop_at_return} is checked at evaluations, but "
                f"{which} evaluates only at the end; set train.eval_every >= 1 or train.num_evals >= 2"
            )


@dataclasses.dataclass(frozen=True)
class LoggerConfig:
    """Outputs (``logger.*``).

    Fields:
      tensorboard   write TensorBoard event files under RUN_DIR/tb
      csv           append a row per chunk to RUN_DIR/metrics.csv
      plot          draw RUN_DIR/curve.png (return vs env steps and vs seconds)
      progress      print a progress line per chunk
      viewer_every  every this many chunks (and at the last), write a rollout's 3D viewer page to
                    RUN_DIR/viewer/chunk_<n>.html and RUN_DIR/viewer.html (0: never)
    """

    tensorboard: bool = True
    csv: bool = True
    plot: bool = True
    progress: bool = True
    viewer_every: int = 0

    def __post_init__(self):
        if self.viewer_every < 0:
            raise ConfigError("logger.viewer_every must be >= 0 (0 writes no viewer pages)")


@dataclasses.dataclass(frozen=True)
class CheckpointConfig:
    """Checkpointing (``checkpoint.*``).

    Fields:
      every     save every this many chunks (None: by time, see ``seconds``); the last chunk, a
                stop and Ctrl-C always save
      seconds   with every=None, save after the first chunk that ends this many seconds of
                training after the last save
      keep      checkpoints kept (older ones are deleted)
    """

    every: int | None = None
    seconds: float = 60.0
    keep: int = 3

    def __post_init__(self):
        if (self.every is not None and self.every < 1) or self.keep < 1:
            raise ConfigError("checkpoint.every (or null: by time) and checkpoint.keep must be >= 1")
        if not self.seconds > 0:
            raise ConfigError(f"checkpoint.seconds={self.seconds} must be > 0")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Which env and its overrides (``env.*``); ``None`` keeps the env's Gymnasium default.

    Fields:
      name                registered env name
      episode_length      steps before truncation
      frame_skip          physics steps per env step
      reward_weights      {term: weight} overrides
      reset_noise_scale   reset noise scale
      randomization       {mass, friction, damping, gain} half-widths of domain randomisation
                          (each over the env's default)
      solver_iterations   constraint solver iterations
      integrator          "euler", "rk4" or "implicitfast"
      timestep            physics timestep
      options             env-specific constructor options (e.g. hand_reorient's ``target``)
    """

    name: str
    episode_length: int | None = None
    frame_skip: int | None = None
    reward_weights: dict = dataclasses.field(default_factory=dict)
    reset_noise_scale: float | None = None
    randomization: dict = dataclasses.field(default_factory=dict)
    solver_iterations: int | None = None
    integrator: str | None = None
    timestep: float | None = None
    options: dict = dataclasses.field(default_factory=dict)

    def make(self):
        skip = ("name", "options")
        kwargs = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in skip}
        kwargs = {k: v for k, v in kwargs.items() if v is not None and v != {}}
        clash = sorted(set(self.options) & {f.name for f in dataclasses.fields(self)})
        if clash:
            raise ConfigError(f"env.options.{clash[0]}: set it as env.{clash[0]}, not among the options")
        try:
            return envs.make(self.name, **kwargs, **self.options)
        except (ValueError, FileNotFoundError) as e:  # an unknown option value, a missing asset file
            raise ConfigError(f"env: {e}") from None
        except TypeError as e:
            raise ConfigError(f"env.options of {self.name}: {e}") from None


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The whole typed configuration of a training run."""

    env: EnvConfig
    algo_name: str
    algo: Any
    network: NetworkConfig
    train: TrainConfig
    logger: LoggerConfig
    checkpoint: CheckpointConfig
    seed: int = 0
    # A run folder whose newest learned weights a new run starts from (``init_from``: policy,
    # value function and observation statistics; optimiser, envs and counters fresh), e.g.
    # go1_joystick_rough from a go1_joystick run. Same algo, network and observation size
    # needed; ignored when resuming. None: a fresh start.
    init_from: str | None = None

    @classmethod
    def from_dict(cls, cfg: Mapping[str, Any]) -> RunConfig:
        """Builds and validates the config from Hydra's resolved container."""
        algo = dict(cfg["algo"])
        name = algo.pop("name", None)
        if name not in agents.ALGORITHMS:
            raise ConfigError(f"algo.name={name!r}; available algorithms: {sorted(agents.ALGORITHMS)}")
        seed = cfg.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ConfigError(f"seed={seed!r} should be an int")
        init_from = cfg.get("init_from")
        if init_from is not None and (isinstance(init_from, bool) or not isinstance(init_from, str)):
            raise ConfigError(f"init_from={init_from!r} should be a run folder's path (or null)")
        return cls(
            env=build(EnvConfig, cfg["env"], "env"),
            algo_name=name,
            algo=build(agents.config_class(name), algo, "algo"),
            network=build(NetworkConfig, cfg.get("network", {}), "network"),
            train=build(TrainConfig, cfg.get("train", {}), "train"),
            logger=build(LoggerConfig, cfg.get("logger", {}), "logger"),
            checkpoint=build(CheckpointConfig, cfg.get("checkpoint", {}), "checkpoint"),
            seed=seed,
            init_from=init_from,
        )

    def to_dict(self) -> dict:
        """A JSON-able dict (stored with every checkpoint)."""
        out = {
            "env": dataclasses.asdict(self.env),
            "algo": {"name": self.algo_name, **dataclasses.asdict(self.algo)},
            "network": dataclasses.asdict(self.network),
            "train": dataclasses.asdict(self.train),
            "logger": dataclasses.asdict(self.logger),
            "checkpoint": dataclasses.asdict(self.checkpoint),
            "seed": self.seed,
            "init_from": self.init_from,
        }
        return _jsonable(out)


# The config dataclass of each section of the composed config; ``algo`` has one per learner
# (``agents.config_class``). Their defaults are the only ones: conf/ files hold what differs.
SECTIONS = {
    "env": EnvConfig,
    "network": NetworkConfig,
    "train": TrainConfig,
    "logger": LoggerConfig,
    "checkpoint": CheckpointConfig,
}


def defaults(cls: type) -> dict:
    """The defaults of config dataclass ``cls`` as a JSON-able dict (fields without one left out)."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return _jsonable(out)


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    return x


# Sections that define what a training state *is*: a checkpoint made under different values
# cannot be continued (shapes, dynamics or the RNG stream would differ).
IDENTITY_SECTIONS = ("env", "algo", "network", "seed")


IDENTITY_TRAIN_KEYS = ("num_seeds", "vmap_sweep")


def identity_diff(saved: Mapping, current: Mapping) -> list[str]:
    """Keys in ``IDENTITY_SECTIONS`` whose values differ, as ``key: saved -> current``."""
    diffs: list[str] = []

    def walk(a, b, path):
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b)):
                walk(a.get(k), b.get(k), f"{path}.{k}" if path else k)
        elif a != b:
            diffs.append(f"{path}: {a!r} -> {b!r}")

    for section in IDENTITY_SECTIONS:
        walk(saved.get(section), current.get(section), section)
    for key in IDENTITY_TRAIN_KEYS:  # the agent batch sets the state's leading axis
        walk(saved.get("train", {}).get(key), current.get("train", {}).get(key), f"train.{key}")
    return diffs


def missing_identity_keys(saved: Mapping) -> list[str]:
    """The identity settings every saved config of this fastrl holds that ``saved`` lacks: a
    config of an earlier layout, which ``identity_diff`` cannot compare."""
    train = saved.get("train")
    missing = [s for s in (*IDENTITY_SECTIONS, "train") if s not in saved]
    return missing + [
        f"train.{k}" for k in IDENTITY_TRAIN_KEYS if isinstance(train, Mapping) and k not in train
    ]
