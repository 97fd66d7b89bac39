"""MuJoCo's Newton solver as written (``linesearch="mujoco"``): truncated solves track MuJoCo C.

A scene with few solver iterations does not converge within a step, so where each line search
stops decides the trajectory. These compare float64 trajectories with MuJoCo C on scenes solved
with 1-3 iterations and a handful of line-search evaluations, across islands that merge and
split (bodies touching each other), both friction cones, friction loss, limits and equalities.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import island, solver
from tests.conftest import asset, random_state
from tests.physics.test_oracle import _fastrl_trajectory, _mujoco_trajectory, _rel_err

# Three trees: a free ball that falls onto a free box (their islands merge on contact) and an
# arm with a limit and friction loss, whose tip is welded to the world by an equality.
STACK = """
<mujoco><option timestep="0.005" iterations="{iterations}" ls_iterations="{ls}" cone="{cone}"/>
  <worldbody><geom type="plane" size="3 3 .1"/>
    <body pos="0 0 0.12"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
    <body pos="0.03 0.02 0.35"><freejoint/><geom type="sphere" size="0.07" condim="4"/></body>
    <body name="arm" pos="1 0 0.5">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="-0.5 0.5" frictionloss="0.2"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="tip" pos="0.3 0 0"><joint type="hinge" axis="1 0 0" damping="0.1"/>
        <geom type="sphere" size="0.04"/></body>
    </body>
  </worldbody>
  <equality><connect body1="tip" anchor="0 0 0" solref="0.05 1"/></equality>
  <actuator><motor joint="shoulder" gear="5"/></actuator>
</mujoco>"""


def _truncated(mj: mujoco.MjModel, iterations: int, ls: int) -> mujoco.MjModel:
    mj.opt.iterations, mj.opt.ls_iterations = iterations, ls
    return mj


def _compare(mj: mujoco.MjModel, seed: int, seconds: float = 1.0, trajectory: float = 0.2):
    """Worst relative error of (a) each step taken from MuJoCo's state and warm start along its
    trajectory (qacc and the next qvel) over ``seconds``, (b) the whole trajectory over
    ``trajectory`` seconds. A truncated solve is discontinuous in the state (a termination test
    flips), so rounding differences grow along a chaotic trajectory (a bouncing ball) until one
    flips a decision: (a) checks every step's algorithm, (b) that nothing else differs."""
    qpos, qvel, _ = random_state(mj, seed=seed, qpos_scale=0.1, qvel_scale=0.5)
    ctrls = np.random.default_rng(seed).uniform(-1, 1, (int(round(seconds / mj.opt.timestep)), mj.nu))
    m = physics.model_from_mujoco(mj, solver_iterations=int(mj.opt.iterations), linesearch="mujoco")
    short = ctrls[: int(round(trajectory / mj.opt.timestep))]
    ours = _fastrl_trajectory(m, qpos, qvel, short)
    assert np.all(np.isfinite(ours))
    whole = _rel_err(ours, _mujoco_trajectory(mj, qpos, qvel, short))
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:] = qpos, qvel
    step = jax.jit(physics.step)
    worst = 0.0
    for u in ctrls:
        md.ctrl[:] = u
        d = physics.make_data(m, qpos=md.qpos.copy(), qvel=md.qvel.copy(), ctrl=u)
        d = step(m, d.replace(qacc_warmstart=jnp.array(md.qacc_warmstart), time=jnp.array(md.time)))
        mujoco.mj_step(mj, md)
        scale = 1.0 + np.max(np.abs(md.qacc))
        worst = max(worst, np.max(np.abs(np.asarray(d.qacc) - md.qacc)) / scale)
        worst = max(worst, np.max(np.abs(np.asarray(d.qvel) - md.qvel)) / (1.0 + np.max(np.abs(md.qvel))))
    return worst, whole


@pytest.mark.parametrize("cone", ["pyramidal", "elliptic"])
# one Newton iteration under the slow marker: 3 iterations exercise the same truncation (~35 s each)
@pytest.mark.parametrize("iterations,ls", [pytest.param(1, 3, marks=pytest.mark.slow), (3, 5)])
def test_stack_islands_track_mujoco(cone, iterations, ls, x64):
    mj = mujoco.MjModel.from_xml_string(STACK.format(iterations=iterations, ls=ls, cone=cone))
    steps, whole = _compare(mj, seed=3)
    assert steps < 1e-9 and whole < 1e-9


# the elliptic asset's pyramidal run under the slow marker: its elliptic run and the other
# assets' pyramidal runs cover both cones (~40 s each)
@pytest.mark.parametrize(
    "name,cone",
    [
        ("elliptic", 1),
        pytest.param("elliptic", 0, marks=pytest.mark.slow),
        ("friction_loss", 0),
        ("pairs", 0),
    ],
)
def test_assets_truncated_track_mujoco(name, cone, x64):
    mj = _truncated(mujoco.MjModel.from_xml_path(asset(name)), iterations=2, ls=4)
    mj.opt.cone = cone
    steps, whole = _compare(mj, seed=7)
    assert steps < 1e-9 and whole < 1e-9


def _mujoco_islands(md: mujoco.MjData) -> set[tuple[int, ...]]:
    return {
        tuple(sorted(md.map_idof2dof[md.island_idofadr[i] : md.island_idofadr[i] + md.island_nv[i]]))
        for i in range(md.nisland)
    }


def test_islands_merge_on_contact(x64):
    """fastrl's islands are MuJoCo's (mj_island) in every step of a fall: the ball and the box
    make one island while they touch, the arm its own, a body in the air none."""
    mj = mujoco.MjModel.from_xml_string(STACK.format(iterations=20, ls=20, cone="pyramidal"))
    m = physics.model_from_mujoco(mj, linesearch="mujoco")
    forward = jax.jit(physics.forward)
    islands = jax.jit(lambda d: island.islands(m, solver.make_rows(m, d), d.qM).dof)
    md = mujoco.MjData(mj)
    seen = set()
    for _ in range(150):
        mujoco.mj_step(mj, md)
        d = forward(m, physics.make_data(m, qpos=md.qpos.copy(), qvel=md.qvel.copy()))
        ours = {tuple(np.flatnonzero(row)) for row in np.asarray(islands(d)) if row.any()}
        mujoco.mj_forward(mj, md)
        assert ours == _mujoco_islands(md)
        seen |= ours
    assert tuple(range(12)) in seen and tuple(range(6)) in seen  # merged, and the box alone


def test_vmap_and_gradient(x64):
    """The line search's while_loop batches, and the solve stays differentiable."""
    mj = _truncated(mujoco.MjModel.from_xml_path(asset("pairs")), iterations=2, ls=4)
    m = physics.model_from_mujoco(mj, solver_iterations=2, linesearch="mujoco")
    states = [random_state(mj, seed=s, qpos_scale=0.1, qvel_scale=0.5) for s in (1, 2)]
    ones = [physics.make_data(m, qpos=qpos, qvel=qvel) for qpos, qvel, _ in states]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *ones)
    batched = jax.jit(jax.vmap(lambda d: physics.step(m, d)))(batch)
    for i, d in enumerate(ones):
        one = jax.jit(physics.step)(m, d)
        np.testing.assert_allclose(batched.qacc[i], one.qacc, rtol=1e-12, atol=1e-10)

    def loss(ctrl):
        d = physics.make_data(m, qpos=states[0][0], qvel=states[0][1])
        for _ in range(3):
            d = physics.step(m, d, ctrl)
        return jnp.sum(d.qpos**2)

    grad = jax.jit(jax.grad(loss))(jnp.ones(m.nu))
    assert np.all(np.isfinite(np.asarray(grad))) and np.any(np.asarray(grad) != 0)


def test_converged_solve_differentiates_as_the_solution_moves(x64):
    """The solve's derivative (one Newton step at its solution) is the solution's: reverse mode
    equals central differences of ``qacc`` in the controls and the velocities, with
    contacts (the ball resting on the box, an elliptic cone: the solver's most intricate Hessian),
    a friction-loss joint and an equality active."""
    mj = mujoco.MjModel.from_xml_string(STACK.format(iterations=100, ls=50, cone="elliptic"))
    mj.opt.tolerance = 1e-14
    md = mujoco.MjData(mj)
    for _ in range(100):  # the ball comes to rest on the box
        mujoco.mj_step(mj, md)
    m = physics.model_from_mujoco(mj)
    assert m.linesearch == "mujoco" and m.solver_iterations == 100

    def qacc(ctrl, qvel):
        d = physics.make_data(m, qpos=md.qpos.copy(), qvel=qvel, ctrl=ctrl)
        return physics.forward(m, d).qacc

    ctrl, qvel = jnp.asarray([0.3]), jnp.asarray(md.qvel)
    assert int(jax.jit(physics.forward)(m, physics.make_data(m, qpos=md.qpos.copy(), qvel=qvel)).ncon) > 0
    for arg, x in enumerate((ctrl, qvel)):
        reverse = np.asarray(jax.jit(jax.jacrev(qacc, argnums=arg))(ctrl, qvel))
        f = jax.jit(qacc)
        eps = 1e-6
        central = np.stack(
            [
                (f(*[(y.at[i].add(eps) if k == arg else y) for k, y in enumerate((ctrl, qvel))])
                 - f(*[(y.at[i].add(-eps) if k == arg else y) for k, y in enumerate((ctrl, qvel))]))
                / (2 * eps)
                for i in range(x.size)
            ],
            axis=1,
        )  # fmt: skip
        np.testing.assert_allclose(reverse, central, rtol=1e-5, atol=1e-5 * np.abs(central).max())
