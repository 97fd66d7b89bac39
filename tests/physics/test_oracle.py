"""Stage-by-stage and trajectory agreement with MuJoCo C (the oracle) on hand-written models."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from tests.conftest import MODELS, asset, random_state

STAGE_FIELDS = [
    "xpos", "xquat", "xmat", "xipos", "ximat", "xanchor", "xaxis", "geom_xpos", "geom_xmat",
    "site_xpos", "site_xmat", "subtree_com", "cinert", "cdof", "cvel", "cdof_dot", "qfrc_bias",
    "qfrc_spring", "qfrc_damper", "qfrc_passive", "actuator_length",
    "actuator_velocity",
    "actuator_force", "qfrc_actuator", "qacc",
]  # fmt: skip


def _rel_err(ours, ref) -> float:
    ours, ref = np.asarray(ours), np.asarray(ref)
    if ref.size == 0:
        return 0.0
    return float(np.max(np.abs(ours - ref)) / (np.max(np.abs(ref)) + 1e-12))


@pytest.mark.parametrize("name", MODELS)
def test_forward_stages_match_mujoco(name, x64):
    mj = mujoco.MjModel.from_xml_path(asset(name))
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    forward = jax.jit(physics.forward)
    for seed in range(3):
        qpos, qvel, ctrl = random_state(mj, seed)
        md.qpos[:], md.qvel[:], md.ctrl[:] = qpos, qvel, ctrl
        mujoco.mj_forward(mj, md)
        d = forward(m, physics.make_data(m, qpos=qpos, qvel=qvel, ctrl=ctrl))
        for field in STAGE_FIELDS:
            ours = getattr(d, field)
            ref = getattr(md, field).reshape(ours.shape)
            assert _rel_err(ours, ref) < 1e-5, f"{name}: {field} differs from MuJoCo"
        full_m = np.zeros((mj.nv, mj.nv))
        mujoco.mj_fullM(mj, md, full_m)
        assert _rel_err(d.qM, full_m) < 1e-5, f"{name}: mass matrix differs from MuJoCo"


def _mujoco_trajectory(mj, qpos, qvel, ctrls):
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = qpos, qvel
    out = []
    for u in ctrls:
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        out.append(np.concatenate([md.qpos, md.qvel]))
    return np.array(out)


def _fastrl_trajectory(m, qpos, qvel, ctrls):
    def body(d, u):
        d = physics.step(m, d, u)
        return d, jnp.concatenate([d.qpos, d.qvel])

    d0 = physics.make_data(m, qpos=qpos, qvel=qvel)
    _, states = jax.jit(lambda d, c: jax.lax.scan(body, d, c))(d0, jnp.asarray(ctrls, d0.qpos.dtype))
    return np.asarray(states)


# Every model and integrator in float64 (the 1e-6 oracle); float32 (1e-3) with Euler in the
# default suite and with RK4 under the slow marker: the same code compiled again, ~40-80 s each.
TRAJECTORY_CASES = [
    pytest.param(
        precision,
        name,
        integrator,
        marks=[pytest.mark.slow] if (precision, integrator) == ("float32", "rk4") else [],
    )
    for precision in ("float64", "float32")
    for name in MODELS
    for integrator in ("euler", "rk4")
]


@pytest.mark.parametrize("precision,name,integrator", TRAJECTORY_CASES)
def test_trajectory_matches_mujoco(name, integrator, precision, request):
    if precision == "float64":
        request.getfixturevalue("x64")
    mj = mujoco.MjModel.from_xml_path(asset(name))
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4" else 0
    qpos, qvel, _ = random_state(mj, seed=7, qpos_scale=0.1, qvel_scale=0.5)
    rng = np.random.default_rng(11)
    ctrls = rng.uniform(-1, 1, (int(round(1.0 / mj.opt.timestep)), mj.nu))
    ref = _mujoco_trajectory(mj, qpos, qvel, ctrls)
    ours = _fastrl_trajectory(physics.model_from_mujoco(mj), qpos, qvel, ctrls)
    tol = 1e-3 if precision == "float32" else 1e-6
    assert np.all(np.isfinite(ours))
    assert _rel_err(ours, ref) < tol
