"""Shared fixtures: the hand-written MJCF test models and a float64 switch."""

from __future__ import annotations

import os
import pathlib

import jax
import mujoco
import numpy as np
import pytest

import fastrl

# fastrl's XLA:CPU flags, as the command line uses them: set before JAX starts a backend (importing
# fastrl sets nothing; this is the library's one opt-in call).
fastrl.use_recommended_xla_flags()


def pytest_configure(config):
    """The default suite's programs compile for longer than they run: LLVM's cheapest
    optimisation level takes a third off a GJK/EPA gradient test (47.5 -> 31.0 s;
    tests/physics/test_mesh_hfield.py). Set in XLA_FLAGS (before any JAX backend starts), so the
    command-line runs that tests start inherit it; a level in XLA_FLAGS stays. The slow checks
    (``-m slow``: full training runs, some with a wall-time bar) keep XLA's own level, as users'
    runs do."""
    markexpr = config.getoption("markexpr", "") or ""
    slow = "slow" in markexpr and "not slow" not in markexpr
    if not slow and "--xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_backend_optimization_level=0".strip()


ASSETS = pathlib.Path(__file__).parent / "assets"
MODELS = sorted(p.stem for p in ASSETS.glob("*.xml"))


@pytest.fixture
def x64():
    """Runs the test with ``jax_enable_x64`` on, restoring the previous setting after."""
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", previous)


def asset(name: str) -> str:
    return str(ASSETS / f"{name}.xml")


def random_state(mj: mujoco.MjModel, seed: int, qpos_scale=0.3, qvel_scale=1.0):
    """A random (qpos, qvel, ctrl) with unit quaternions, as numpy float64."""
    rng = np.random.default_rng(seed)
    qpos = mj.qpos0 + qpos_scale * rng.standard_normal(mj.nq)
    for j in range(mj.njnt):
        if mj.jnt_type[j] in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            a = mj.jnt_qposadr[j] + (3 if mj.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE else 0)
            qpos[a : a + 4] /= np.linalg.norm(qpos[a : a + 4])
    qvel = qvel_scale * rng.standard_normal(mj.nv)
    ctrl = rng.uniform(-1, 1, mj.nu)
    return qpos, qvel, ctrl


# Tests build the same programs repeatedly (a run and its resumed twin compile identical
# chunks): JAX's persistent compilation cache turns the repeats into cache hits.
jax.config.update("jax_compilation_cache_dir", str(pathlib.Path(__file__).parent.parent / ".jax_cache"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
