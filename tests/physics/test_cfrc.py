"""Contact forces (``cfrc_ext``) and the com-based observables Gymnasium reads, against MuJoCo C.

Gymnasium's Ant and Humanoid read ``cfrc_ext`` after ``mj_step`` followed by
``mj_rnePostConstraint``, and Humanoid also ``cinert``, ``cvel`` and ``qfrc_actuator``.
"""

from __future__ import annotations

import functools
import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics

ANT = str(pathlib.Path(physics.__file__).parents[1] / "assets" / "ant.xml")


def _path(model: str) -> str:
    if model == "fastrl":
        return ANT
    gymnasium = pytest.importorskip("gymnasium")
    return str(pathlib.Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / "ant.xml")


@functools.cache
def _ant(model: str, integrator: str):
    """MuJoCo's and fastrl's Ant (float64) and a jitted ``step -> (data, cfrc_ext)``, compiled
    once per module: compiling the step dominates these tests' time."""
    mj = mujoco.MjModel.from_xml_path(_path(model))
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4" else 0
    m = physics.model_from_mujoco(mj)

    def step(d):
        d = physics.step(m, d)
        return d, physics.cfrc_ext(m, d)

    return mj, m, jax.jit(step)


def _weight(mj) -> float:
    return float(mj.body_mass.sum() * np.linalg.norm(mj.opt.gravity))


def _data(m, md):
    """fastrl data at MuJoCo's state, warm start included (the solver's starting point).

    Copies: on CPU ``jnp.asarray`` may alias a numpy buffer, and MuJoCo overwrites its buffers in
    place while JAX's asynchronous dispatch may still be reading them.
    """
    qpos, qvel, ctrl, warm = (x.copy() for x in (md.qpos, md.qvel, md.ctrl, md.qacc_warmstart))
    return physics.make_data(m, qpos=qpos, qvel=qvel, ctrl=ctrl).replace(qacc_warmstart=jnp.asarray(warm))


def _gym_step(mj, md):
    """``mj_step`` then ``mj_rnePostConstraint``, as Gymnasium's ``MujocoEnv`` does."""
    mujoco.mj_step(mj, md)
    mujoco.mj_rnePostConstraint(mj, md)


CASES = [("fastrl", "euler"), ("gymnasium", "rk4")]


@pytest.mark.parametrize("model, integrator", CASES)
def test_observables_after_step_match_mujoco_from_identical_states(model, integrator, x64):
    """From each of MuJoCo's states along a drop onto the floor and a random-control walk, one
    step in each simulator: ``cfrc_ext``, ``cinert``, ``cvel`` and ``qfrc_actuator`` (what
    Gymnasium's Ant and Humanoid read after ``mj_step``) agree with MuJoCo's, in its layout.

    Both solvers converge to the unique minimiser of the same convex problem, so only their
    stopping rules separate them: measured 3e-13 N (Euler) and 5e-11 N (RK4) against contact
    forces up to 83 N at impacts; the bound is 1e-6 of the Ant's weight (8.9 N). For RK4 this
    pins the convention: after ``mj_step`` MuJoCo's data holds RK4's last stage, not the start
    state (whose ``cfrc_ext`` differs from it by up to 81 N here).
    """
    mj, m, step = _ant(model, integrator)
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(0)
    touched = False
    for _ in range(60):
        md.ctrl[:] = rng.uniform(-1, 1, mj.nu)
        d, cfrc = step(_data(m, md))
        _gym_step(mj, md)
        touched |= bool(np.abs(md.cfrc_ext[1:, 5]).max() > 1.0)
        np.testing.assert_allclose(cfrc, md.cfrc_ext, rtol=0, atol=1e-6 * _weight(mj))
        assert d.cinert.shape == (mj.nbody, 10) and d.cvel.shape == (mj.nbody, 6)
        for field in ("cinert", "cvel", "qfrc_actuator"):
            np.testing.assert_allclose(getattr(d, field), getattr(md, field), rtol=0, atol=1e-9)
    assert touched, "the Ant never touched the floor"


@pytest.mark.parametrize("model, integrator", CASES)
def test_cfrc_ext_free_running_tracks_mujoco(model, integrator, x64):
    """Both simulators run the same 40 random-control steps from the same state just above the
    floor, each on its own: ``cfrc_ext`` after every step stays within 1e-5 of the Ant's weight
    of MuJoCo's. Measured: 5e-12 N, with impacts up to 164 N; the trajectories drift apart only
    by the solvers' stopping rules, which contact transitions could amplify, hence the margin."""
    mj, m, step = _ant(model, integrator)
    md = mujoco.MjData(mj)
    md.qpos[2] = 0.6  # lower than the default 0.75: contacts start within the run
    d = _data(m, md)
    ctrls = np.random.default_rng(1).uniform(-1, 1, (40, mj.nu))
    worst, touched = 0.0, False
    for u in ctrls:
        md.ctrl[:] = u
        _gym_step(mj, md)
        d, cfrc = step(d.replace(ctrl=jnp.asarray(u)))
        touched |= bool(np.abs(md.cfrc_ext[1:, 5]).max() > 0.1 * _weight(mj))
        worst = max(worst, float(np.abs(np.asarray(cfrc) - md.cfrc_ext).max()))
    assert touched, "no contact during the run"
    assert worst < 1e-5 * _weight(mj), worst


def test_resting_contacts_carry_the_weight_with_no_net_torque(x64):
    """Settled on the floor with zero controls: the contact forces sum to the Ant's weight, straight
    up, with no net torque about its centre of mass (every body's torque is about that point)."""
    mj, m, step = _ant("fastrl", "euler")
    md = mujoco.MjData(mj)
    for _ in range(300):
        mujoco.mj_step(mj, md)
    _, cfrc = step(_data(m, md))  # Euler: the forces of the state the step starts from
    total = np.asarray(cfrc).sum(0)
    weight = _weight(mj)
    np.testing.assert_allclose(total[3:], [0, 0, weight], rtol=0, atol=1e-4 * weight)
    np.testing.assert_allclose(total[:3], 0, rtol=0, atol=1e-6 * weight)
