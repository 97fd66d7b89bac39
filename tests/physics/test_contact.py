"""Contacts, joint limits and the solver against MuJoCo C, for both integrators."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics

ANT = str(pathlib.Path(physics.__file__).parents[1] / "assets" / "ant.xml")
INTEGRATORS = ["euler", "rk4"]

FLOOR = '<geom name="floor" type="plane" size="5 5 .1"/>'
SHAPES = {
    "sphere": ("", '<geom type="sphere" size="0.1"/>'),
    "box": (' euler="10 20 5"', '<geom type="box" size="0.1 0.15 0.05"/>'),
    "capsule": (' euler="80 0 0"', '<geom type="capsule" size="0.05 0.2"/>'),
}
SCENES = {
    k: FLOOR + f'<body pos="0 0 0.5"{pose}><freejoint/>{geom}</body>' for k, (pose, geom) in SHAPES.items()
}


def _xml(body: str, integrator: str, timestep=0.002, extra="") -> str:
    integ = "RK4" if integrator == "rk4" else "Euler"
    return (
        f'<mujoco><option timestep="{timestep}" integrator="{integ}"/>'
        f"<worldbody>{body}</worldbody>{extra}</mujoco>"
    )


def _run_both(xml: str, steps: int, qvel=None, ctrl=None):
    """qpos trajectories of MuJoCo and fastrl (float64) from the same start."""
    mj = mujoco.MjModel.from_xml_string(xml)
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    qvel = np.zeros(mj.nv) if qvel is None else qvel
    ctrl = np.zeros(mj.nu) if ctrl is None else ctrl
    md.qvel[:], md.ctrl[:] = qvel, ctrl
    ref = []
    for _ in range(steps):
        mujoco.mj_step(mj, md)
        ref.append(md.qpos.copy())

    def body(d, _):
        d = physics.step(m, d, jnp.asarray(ctrl))
        return d, d.qpos

    d0 = physics.make_data(m, qvel=qvel)
    _, ours = jax.jit(lambda d: jax.lax.scan(body, d, None, length=steps))(d0)
    return np.array(ref), np.asarray(ours)


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_dropped_shapes_rest_like_mujoco_and_never_sink(scene, integrator, x64):
    """Dropped from 0.5 m: same bounce and rest pose; the rest height holds for 10 s."""
    steps = 5000  # 10 s at 2 ms
    ref, ours = _run_both(_xml(SCENES[scene], integrator), steps)
    assert np.max(np.abs(ours[:, 2] - ref[:, 2])) < 1e-3  # the whole fall, bounce and rest
    rest = ours[steps // 2 :, 2]
    assert abs(rest[-1] - ref[-1, 2]) < 1e-3
    assert rest.max() - rest.min() < 1e-4  # no sinking or creeping over the last 5 s
    assert ours[:, 2].min() > 0  # the body never passes through the floor


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_box_sliding_with_friction_stops_where_mujoco_does(integrator, x64):
    body = FLOOR.replace("/>", ' friction="0.5"/>') + (
        '<body pos="0 0 0.05"><freejoint/><geom type="box" size="0.1 0.1 0.05" friction="0.5"/></body>'
    )
    qvel = np.array([2.0, 0, 0, 0, 0, 0])
    ref, ours = _run_both(_xml(body, integrator), 1000, qvel=qvel)
    assert abs(ours[-1, 0] - ref[-1, 0]) < 0.02 * ref[-1, 0]
    # Coulomb friction: v^2 / (2 mu g) with mu = 0.5, minus the soft contact's slip.
    assert 0.3 < ours[-1, 0] < 0.45


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_joint_limit_holds_under_actuation(integrator, x64):
    body = (
        '<body pos="0 0 1"><joint name="h" type="hinge" axis="0 1 0" range="-30 45" limited="true"/>'
        '<geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.05" contype="0" conaffinity="0"/></body>'
    )
    extra = '<actuator><motor joint="h" gear="5"/></actuator>'
    ref, ours = _run_both(_xml(body, integrator, extra=extra), 1500, ctrl=np.ones(1))
    np.testing.assert_allclose(ours[:, 0], ref[:, 0], atol=1e-6)
    # Driven into its 45 degree stop: a soft-constraint overshoot on impact, then it holds.
    stop = np.deg2rad(45)
    assert np.max(ours[:, 0]) < stop + 0.06
    assert np.all(np.abs(ours[-500:, 0] - stop) < 0.005)


def _shipped_ant_settings() -> tuple[str, int]:
    """The integrator and solver iterations ``env=ant algo=ppo`` trains with."""
    from omegaconf import OmegaConf

    conf = OmegaConf.load(pathlib.Path(__file__).parents[2] / "conf" / "experiment" / "ant_ppo.yaml")
    return conf.env.integrator, conf.env.solver_iterations


# Both integrators at the default iteration count, and the settings the Ant is trained with.
ANT_CASES = [(i, None) for i in INTEGRATORS] + [_shipped_ant_settings()]


def _ant(integrator, iterations=None):
    mj = mujoco.MjModel.from_xml_path(ANT)
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4" else 0
    kw = {} if iterations is None else {"solver_iterations": iterations}
    return mj, physics.model_from_mujoco(mj, **kw)


@pytest.mark.parametrize("integrator, iterations", ANT_CASES)
def test_ant_settles_like_mujoco(integrator, iterations, x64):
    """Dropped from 0.75 m with zero controls: rest height within 2 mm, attitude 0.01 rad."""
    mj, m = _ant(integrator, iterations)
    md = mujoco.MjData(mj)
    for _ in range(300):
        mujoco.mj_step(mj, md)
    d = jax.jit(lambda d: jax.lax.fori_loop(0, 300, lambda _, d: physics.step(m, d), d))(physics.make_data(m))
    assert abs(float(d.qpos[2]) - md.qpos[2]) < 2e-3
    dq = np.zeros(3)
    mujoco.mju_subQuat(dq, np.asarray(d.qpos[3:7]), md.qpos[3:7])
    assert np.linalg.norm(dq) < 0.01
    assert float(d.qpos[2]) > 0.3  # standing on its legs


@pytest.mark.parametrize("integrator, iterations", ANT_CASES)
def test_ant_random_controls_track_mujoco(integrator, iterations, x64):
    """32 sequences of 20 random control steps (5 substeps each) from the settled pose:
    the median horizontal distance between fastrl's and MuJoCo's torso stays under 2 cm."""
    mj, m = _ant(integrator, iterations)
    md = mujoco.MjData(mj)
    for _ in range(300):
        mujoco.mj_step(mj, md)
    q0, v0, w0 = md.qpos.copy(), md.qvel.copy(), md.qacc_warmstart.copy()
    ctrls = np.random.default_rng(0).uniform(-1, 1, (32, 20, mj.nu))
    ref = []
    for seq in ctrls:
        md.qpos[:], md.qvel[:], md.qacc_warmstart[:] = q0, v0, w0
        for u in seq:
            md.ctrl[:] = u
            for _ in range(5):
                mujoco.mj_step(mj, md)
        ref.append(md.qpos[:2].copy())

    def rollout(seq):
        d = physics.make_data(m, qpos=q0, qvel=v0).replace(qacc_warmstart=jnp.asarray(w0))
        inner = lambda d, u: (jax.lax.fori_loop(0, 5, lambda _, d: physics.step(m, d, u), d), None)  # noqa: E731
        return jax.lax.scan(inner, d, seq)[0].qpos[:2]

    ours = np.asarray(jax.jit(jax.vmap(rollout))(jnp.asarray(ctrls)))
    err = np.linalg.norm(ours - np.array(ref), axis=1)
    assert np.median(err) < 0.02, np.round(err, 4)


@pytest.mark.parametrize("timestep, diverges", [(1e-5, False), (0.05, True)])
def test_divergence_guard_flags_and_stays_flagged(timestep, diverges):
    """A stiff spring (omega ~ 4e4 rad/s) under explicit RK4: stable at 1e-5 s, the guard stays
    silent; far past the stability limit at 0.05 s, the guard fires and never clears."""
    xml = (
        f'<mujoco><option timestep="{timestep}" integrator="RK4"/><worldbody><body>'
        '<joint type="hinge" axis="0 1 0" stiffness="1e6"/>'
        '<geom type="sphere" size="0.05" contype="0" conaffinity="0"/></body></worldbody></mujoco>'
    )
    m = physics.load_mjcf(xml)

    def body(d, _):
        d = physics.step(m, d)
        return d, d.diverged

    _, flags = jax.jit(lambda d: jax.lax.scan(body, d, None, length=60))(
        physics.make_data(m, qpos=np.array([0.1]))
    )
    flags = np.asarray(flags)
    assert flags[-1] == diverges
    if diverges:
        assert np.all(flags[np.argmax(flags) :])  # once set, it stays set
    else:
        assert not flags.any()


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_ant_random_actions_stay_finite(integrator):
    """32 Ants, 100 control steps of random actions (5 substeps each), float32: all finite."""
    m = physics.load_mjcf(ANT, integrator=integrator)
    qpos0 = np.array([0, 0, 0.75, 1, 0, 0, 0, 0, 1, 0, -1, 0, -1, 0, 1.0])
    data = jax.vmap(lambda _: physics.make_data(m, qpos=qpos0))(jnp.arange(32))
    ctrl = jax.random.uniform(jax.random.PRNGKey(0), (100, 32, m.nu), minval=-1, maxval=1)

    def control_step(d, u):
        return jax.lax.fori_loop(0, 5, lambda _, d: physics.step(m, d, u), d)

    out = jax.jit(lambda d, c: jax.lax.scan(lambda d, u: (jax.vmap(control_step)(d, u), None), d, c)[0])(
        data, ctrl
    )
    assert not bool(jnp.any(out.diverged))
    assert bool(jnp.all(jnp.isfinite(out.qpos))) and bool(jnp.all(jnp.isfinite(out.qvel)))
    assert float(jnp.min(out.qpos[:, 2])) > 0.0  # no torso through the floor


@pytest.mark.slow
@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_ant_batch_1024_random_actions_1000_control_steps_stay_finite(integrator):
    """The issue's stability bar: batch 1024, 1000 control steps, no non-finite state."""
    m = physics.load_mjcf(ANT, integrator=integrator)
    qpos0 = np.array([0, 0, 0.75, 1, 0, 0, 0, 0, 1, 0, -1, 0, -1, 0, 1.0])
    data = jax.vmap(lambda _: physics.make_data(m, qpos=qpos0))(jnp.arange(1024))

    def chunk(d, key):
        ctrl = jax.random.uniform(key, (100, 1024, m.nu), minval=-1, maxval=1)
        step5 = lambda d, u: jax.lax.fori_loop(0, 5, lambda _, d: physics.step(m, d, u), d)  # noqa: E731
        return jax.lax.scan(lambda d, u: (jax.vmap(step5)(d, u), None), d, ctrl)[0]

    run = jax.jit(chunk)
    for key in jax.random.split(jax.random.PRNGKey(1), 10):
        data = run(data, key)
    assert not bool(jnp.any(data.diverged))
    assert bool(jnp.all(jnp.isfinite(data.qpos)))
